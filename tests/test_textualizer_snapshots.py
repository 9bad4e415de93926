"""Rendered text of hand-built states, both variants: a reset state edited with numpy so the
expected text can be written down by hand."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from textualizer import observe, render

GRASS, WATER, STONE, TREE, PATH, DARKNESS = 2, 3, 4, 5, 7, 18
UP = 3


@pytest.fixture(scope="module")
def reset_state(any_env: Any) -> tuple[str, Any]:
    return _reset_game(any_env)


@pytest.fixture(scope="module")
def full_reset_state(full_env: Any) -> tuple[str, Any]:
    return _reset_game(full_env)


def _reset_game(compiled: Any) -> tuple[str, Any]:
    import jax

    from env import make_task

    no_goal = np.zeros(22, dtype=bool)
    episode = compiled.reset(jax.random.PRNGKey(0), make_task(no_goal, no_goal))
    return compiled.env.variant.value, jax.device_get(episode.game)


def _masked(mobs: Any) -> Any:
    return mobs.replace(mask=np.zeros_like(mobs.mask))


def _meadow(state: Any, variant: str) -> Any:
    """The player at the map centre facing up, on open grass with nothing around, all needs at
    9, nothing carried, at noon."""
    full = variant == "full"
    world = state.map[0] if full else state.map
    row, col = world.shape[0] // 2, world.shape[1] // 2
    world = world.copy()
    world[row - 6 : row + 7, col - 7 : col + 8] = GRASS
    inventory = state.inventory.replace(
        **{
            name: np.zeros_like(getattr(state.inventory, name))
            for name in state.inventory.__dataclass_fields__
        }
    )
    common = dict(
        player_position=np.array([row, col], dtype=np.int32),
        player_direction=np.int32(UP),
        player_health=state.player_health.dtype.type(9),
        player_food=np.int32(9),
        player_drink=np.int32(9),
        player_energy=np.int32(9),
        player_hunger=np.float32(0),
        player_thirst=np.float32(0),
        player_fatigue=np.float32(0),
        player_recover=np.float32(0),
        is_sleeping=np.bool_(False),
        inventory=inventory,
        light_level=np.float32(1.0),
        achievements=np.zeros_like(state.achievements),
        timestep=np.int32(0),
    )
    if not full:
        return state.replace(
            map=world,
            zombies=_masked(state.zombies),
            cows=_masked(state.cows),
            skeletons=_masked(state.skeletons),
            arrows=_masked(state.arrows),
            **common,
        )
    maps = state.map.copy()
    maps[0] = world
    items = state.item_map.copy()
    items[0, row - 6 : row + 7, col - 7 : col + 8] = 0
    return state.replace(
        map=maps,
        item_map=items,
        light_map=np.ones_like(state.light_map),
        player_level=np.int32(0),
        player_mana=np.int32(9),
        player_xp=np.int32(0),
        player_dexterity=np.int32(1),
        player_strength=np.int32(1),
        player_intelligence=np.int32(1),
        is_resting=np.bool_(False),
        learned_spells=np.zeros_like(state.learned_spells),
        melee_mobs=_masked(state.melee_mobs),
        passive_mobs=_masked(state.passive_mobs),
        ranged_mobs=_masked(state.ranged_mobs),
        mob_projectiles=_masked(state.mob_projectiles),
        player_projectiles=_masked(state.player_projectiles),
        **common,
    )


def _with_tree_and_zombie(state: Any, variant: str) -> Any:
    """A tree right in front (up) and two more up-left; a zombie 2 right, 1 down."""
    full = variant == "full"
    row, col = (int(v) for v in state.player_position)
    maps = state.map.copy()
    world = maps[0] if full else maps
    world[row - 1, col] = TREE
    world[row - 2, col - 3] = TREE
    world[row, col - 2] = WATER
    group = state.melee_mobs if full else state.zombies
    position, mask, health = group.position.copy(), group.mask.copy(), group.health.copy()
    slot = (0, 0) if full else (0,)
    position[slot] = (row + 1, col + 2)
    mask[slot] = True
    health[slot] = 5
    mobs = group.replace(position=position, mask=mask, health=health)
    if full:
        mobs = mobs.replace(type_id=np.zeros_like(group.type_id))
        return state.replace(map=maps, melee_mobs=mobs)
    return state.replace(map=maps, zombies=mobs)


CLASSIC_OBJECTS = """\
You: at x=32 y=31; facing up: tree.
Health 9/9, food 9/9, drink 9/9, energy 9/9; day (light 1.00).
Inventory: nothing; tools: none.
In view (9x7, offsets (dx,dy): dx right, dy up; grass not listed):
tree: (0,1) 1 N; (-3,2)
water: (-2,0) 2 W
zombie: (2,-1) 3 SE hp 5"""

CLASSIC_GRID = """\
View 9x7: dx -4..+4 left to right, dy +3..-3 top to bottom.
+3 . . . . . . . . .
+2 . t . . . . . . .
+1 . . . . t . . . .
 0 . . ~ . @ . . . .
-1 . . . . . . Z . .
-2 . . . . . . . . .
-3 . . . . . . . . .
Legend: @ you (facing up), . grass, t tree, ~ water, Z zombie"""

FULL_OBJECTS = """\
You: at x=24 y=23, floor 0 (overworld, ladder down open); facing up: tree.
Health 9/9, food 9/9, drink 9/9, energy 9/9, mana 9/9; day (light 1.00).
XP 0; dexterity 1, strength 1, intelligence 1.
Inventory: nothing; tools: none.
In view (11x9, offsets (dx,dy): dx right, dy up; grass not listed):
tree: (0,1) 1 N; (-3,2)
water: (-2,0) 2 W
zombie: (2,-1) 3 SE hp 5"""


def test_tree_in_front_and_a_zombie(reset_state: tuple[str, Any]) -> None:
    variant, state = reset_state
    obs = observe(_with_tree_and_zombie(_meadow(state, variant), variant), variant)
    assert render(obs, "objects") == (FULL_OBJECTS if variant == "full" else CLASSIC_OBJECTS)
    if variant == "classic":
        assert render(obs, "grid") == CLASSIC_GRID
    table = render(obs, "table").splitlines()
    assert "tree 0, 1" in table and "agent 0, 0" in table and "water -2, 0" in table
    # The creature's line comes right before its cell's block line, as in the baseline.
    assert table[table.index("mob zombie on 2, -1") + 1] == "grass 2, -1"
    assert "Direction: 3;" in table[-2] and "Sleeping: False;" in table[-2]
    assert table[-3].startswith("Inventory: Wood: 0; Stone: 0;")


def test_night_and_inventory(reset_state: tuple[str, Any]) -> None:
    variant, state = reset_state
    state = _meadow(state, variant)
    inventory = state.inventory.replace(wood=np.int32(3), sapling=np.int32(1))
    if variant == "full":
        inventory = inventory.replace(pickaxe=np.int32(2), sword=np.int32(1))
        state = state.replace(sword_enchantment=np.int32(1))
    else:
        inventory = inventory.replace(
            stone_pickaxe=np.int32(1), wood_pickaxe=np.int32(1), wood_sword=np.int32(1)
        )
    achievements = state.achievements.copy()
    achievements[[0, 3]] = True
    state = state.replace(
        inventory=inventory,
        light_level=np.float32(0.2),
        is_sleeping=np.bool_(True),
        achievements=achievements,
    )
    lines = render(observe(state, variant), "objects").splitlines()
    mana = ", mana 9/9" if variant == "full" else ""
    assert (
        lines[1]
        == f"Health 9/9, food 9/9, drink 9/9, energy 9/9{mana}; sleeping; night (light 0.20)."
    )
    tools = (
        "stone_pickaxe, wood_sword (fire)"
        if variant == "full"
        else "stone_pickaxe, wood_pickaxe, wood_sword"
    )
    assert f"Inventory: wood 3, sapling 1; tools: {tools}." in lines
    assert lines[-2] == "only background"
    assert lines[-1] == "Achieved so far: COLLECT_WOOD, COLLECT_SAPLING."


def test_dark_floor(full_reset_state: tuple[str, Any]) -> None:
    """Full Craftax floor 1 (Classic has no floors): only the tiles the light map reaches are described."""
    variant, state = full_reset_state
    state = _meadow(state, variant)
    row, col = (int(v) for v in state.player_position)
    maps, light, items = state.map.copy(), np.zeros_like(state.light_map), state.item_map.copy()
    maps[1, row - 6 : row + 7, col - 7 : col + 8] = PATH
    maps[1, row, col + 1] = STONE
    maps[1, row + 3, col] = STONE  # unlit: must not appear
    light[1, row - 1 : row + 2, col - 1 : col + 3] = 1.0  # a 4x3 lit patch around the player
    items[1, row - 6 : row + 7, col - 7 : col + 8] = 0
    items[1, row - 1, col + 2] = 3  # ladder up
    monsters = state.monsters_killed.copy()
    monsters[1] = 0
    state = state.replace(
        map=maps,
        light_map=light,
        item_map=items,
        player_level=np.int32(1),
        monsters_killed=monsters,
    )
    obs = observe(state, variant)
    text = render(obs, "objects")
    assert (
        text.splitlines()[0]
        == "You: at x=24 y=23, floor 1 (dungeon, ladder down closed); facing up: path."
    )
    assert text.splitlines()[-3:] == [
        "stone: (1,0) 1 E",
        "ladder_up: (2,1) 3 NE",
        "unlit (unknown) tiles: 87 of 99 (NW 19, SW 19, NE 18, SE 18, W 4, N 3, S 3, E 3)",
    ]
    assert "night" not in text and "day" not in text
    grid = render(obs, "grid").splitlines()
    assert grid[4] == "+1 - - - - _ _ _ < - - -"
    assert grid[5] == " 0 - - - - _ @ s _ - - -"
    assert grid[-1] == "Legend: @ you (facing up), - unlit, _ path, < ladder_up, s stone"
