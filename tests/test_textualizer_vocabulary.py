"""The textualizer's name tables (kept free of JAX) agree with craftax's own enums."""

from craftax.craftax import constants as full
from craftax.craftax_classic import constants as classic

from env.variant import Variant
from textualizer import vocabulary as voc
from textualizer.render_grid import PLAYER, SYMBOLS, UNLIT


def test_block_and_item_names_follow_craftax_values() -> None:
    assert [b.name.lower() for b in full.BlockType] == list(voc.BLOCK_NAMES)
    assert [b.name.lower() for b in classic.BlockType] == list(
        voc.BLOCK_NAMES[: voc.NUM_CLASSIC_BLOCKS]
    )
    assert [i.name.lower() for i in full.ItemType] == list(voc.ITEM_NAMES)
    assert full.BlockType.OUT_OF_BOUNDS.value == voc.OUT_OF_BOUNDS


def test_achievement_names_follow_craftax_ids() -> None:
    assert {a.value: a.name for a in full.Achievement} == voc.FULL_ACHIEVEMENTS
    assert [a.name for a in classic.Achievement] == [voc.FULL_ACHIEVEMENTS[i] for i in range(22)]


def test_projectiles_views_and_directions_follow_craftax() -> None:
    assert [p.name.lower().rstrip("2") for p in full.ProjectileType] == list(voc.PROJECTILE_NAMES)
    assert voc.VIEW_SHAPE == {Variant.FULL: full.OBS_DIM, Variant.CLASSIC: classic.OBS_DIM}
    assert voc.MONSTERS_TO_OPEN_LADDER == full.MONSTERS_KILLED_TO_CLEAR_LEVEL
    for value, name in voc.DIRECTION_NAMES.items():
        assert full.Action(value).name.lower() == name
        row_step, col_step = (int(v) for v in full.DIRECTIONS[value])
        # craftax steps (row, col) with rows growing down; ours is (dx, dy) with dy growing up.
        assert voc.FACING_OFFSETS[name] == (col_step, -row_step)


def test_grid_symbols_are_distinct_and_cover_every_name() -> None:
    names = (
        set(voc.BLOCK_NAMES)
        | set(voc.ITEM_NAMES[1:4])
        | set(voc.MELEE_MOB_NAMES + voc.PASSIVE_MOB_NAMES + voc.RANGED_MOB_NAMES)
        | set(voc.PROJECTILE_NAMES)
        | {f"player_{name}" for name in voc.PROJECTILE_NAMES}
    )
    assert names <= set(SYMBOLS)
    symbols = [*SYMBOLS.values(), PLAYER, UNLIT]
    assert len(symbols) == len(set(symbols)) and all(len(s) == 1 for s in symbols)
