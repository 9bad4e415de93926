"""The textualizer's tables (kept free of JAX) agree with craftax; its names come from
`env.craftax_names`, which `tests/test_craftax_names.py` checks."""

from craftax.craftax import constants as full
from craftax.craftax_classic import constants as classic

from env.variant import Variant
from textualizer import vocabulary as voc
from textualizer.render_grid import PLAYER, SYMBOLS, UNLIT


def test_views_and_directions_follow_craftax() -> None:
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
