"""What Medium goals need from the observation text: placed tables, furnaces, stones, plants and
water, each at its exact offset from the player (up = +dy, right = +dx, as the localization
checker's sides are), so a goal such as "a table two tiles right of the water" can be checked
from the text alone."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from env.craftax_names import CLASSIC_BLOCKS
from textualizer import observe, render

#: (block, rows down, columns right) from the player, on a freshly reset Classic world.
PLACED = {
    "CRAFTING_TABLE": [(0, 2)],
    "FURNACE": [(-3, 0), (-3, 1)],
    "STONE": [(1, -1)],
    "PLANT": [(2, 2)],
    "WATER": [(-1, -3)],
}


def world_holding_them(classic_env: Any) -> Any:
    env = classic_env.env
    _, state = env.craftax.reset_env(jax.random.PRNGKey(7), env.params)
    state = jax.device_get(state)
    world = np.array(state.map)
    row, column = (int(value) for value in state.player_position)
    # Everything else in view becomes grass, so only the placed blocks are listed.
    world[row - 4 : row + 5, column - 5 : column + 6] = CLASSIC_BLOCKS.index("GRASS")
    for block, cells in PLACED.items():
        for down, right in cells:
            world[row + down, column + right] = CLASSIC_BLOCKS.index(block)
    return state.replace(map=world)


def test_placed_blocks_are_listed_at_their_offsets(classic_env: Any) -> None:
    observation = observe(world_holding_them(classic_env), "classic")
    expected = {
        block.lower(): sorted((right, -down) for down, right in cells)
        for block, cells in PLACED.items()
    }
    seen = {name: sorted(offsets) for name, offsets in observation.blocks.items()}
    assert {name: seen.get(name) for name in expected} == expected

    text = render(observation, "objects")
    assert "crafting_table: (2,0)" in text
    assert "furnace: (0,3)" in text and "(1,3)" in text
    assert "stone: (-1,-1)" in text
    assert "plant: (2,-2)" in text
    assert "water: (-3,1)" in text
