"""The success checkers of every CrafText scenario, in JAX, one `lax.switch` over the goal kinds.

Each checker reproduces what the official one at 1c518ae computes, quirks included, because
published success rates were scored with them (the named rule `official`; docs/protocols/paper.md):

- The official wrapper passes `[new state, previous state]`, so the checkers' `states[0]` is the
  state after the step. Conditional placing reads them the other way round: it succeeds when the
  collected count falls from at least `count` to below it on this step (it is spent) while the
  previous map holds at least `place_count` of the block; a `count` of 0 never succeeds.
- Full Craftax: every map check reads the overworld (`map[0]`), whatever the player's floor.
- Localization: both blocks within 5 tiles (Chebyshev) of the player, the placed block
  `distance` tiles right/left/up/down of the target.
- Line and square: a 21x21 window around the player, placed as `dynamic_slice` does: a negative
  start counts from the map's far end, then the start is clamped inside the map. Sizes past 4 are
  checked as 4 (the official `lax.switch` clamps). A line of 2 succeeds when the window has no
  such block at all (straight) or exactly 3 (diagonal); lines of 3 and 4 need exactly that many
  blocks in the window, in a row. Squares need their border clear of the block. Neighbour cells
  past the window's edge wrap (negative indices) or clamp (past the end), as JAX indexing does.
- Star: the official call passes its arguments out of order, so the cross's arm length is the
  cross-type code (0 straight, 1 diagonal, 2 combined) and the search radius is the goal's size:
  a "straight" star always succeeds, a "diagonal" one when one such block is within `size` of
  the player, a "combined" one on a 3-block corner.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from env.achievements import NUM_ACHIEVEMENTS
from env.checker import goal_reached
from env.checker_geometry import (
    LOCAL,
    LOCAL_RADIUS,
    REACH,
    STAR_FILTER,
    WINDOW,
    WINDOW_RADIUS,
    square_offsets,
)
from env.scenario_tasks import CLASSIC_INVENTORY_SLOTS, INVENTORY_SLOTS, KIND_INDEX
from env.variant import Variant


def overworld(game: Any, variant: Variant) -> jax.Array:
    """The block map the official checkers read."""
    return game.map if variant is Variant.CLASSIC else game.map[0]


def inventory(game: Any, variant: Variant) -> jax.Array:
    slots = CLASSIC_INVENTORY_SLOTS if variant is Variant.CLASSIC else INVENTORY_SLOTS
    return jnp.stack([jnp.asarray(getattr(game.inventory, slot), jnp.int32) for slot in slots])


def _conditional_placing(
    previous: Any, game: Any, params: jax.Array, variant: Variant
) -> jax.Array:
    slot, count, block, place_count = params[0], params[1], params[2], params[3]
    had = inventory(previous, variant)[slot] >= count
    has = inventory(game, variant)[slot] >= count
    standing = jnp.sum(overworld(previous, variant) == block) >= place_count
    return had & ~has & standing


def _localization(game: Any, params: jax.Array, variant: Variant) -> jax.Array:
    placed, target, side, distance = params[0], params[1], params[2], params[3]
    padded = jnp.pad(overworld(game, variant), LOCAL_RADIUS, constant_values=-1)
    row, column = game.player_position[0], game.player_position[1]
    local = jax.lax.dynamic_slice(padded, (row, column), (LOCAL, LOCAL))
    # side codes: 0 right (+column), 1 left, 2 up (-row), 3 down
    d_row = jnp.where(side == 2, -distance, jnp.where(side == 3, distance, 0))
    d_column = jnp.where(side == 0, distance, jnp.where(side == 1, -distance, 0))
    placed_around = jnp.pad(local == placed, LOCAL_RADIUS, constant_values=False)
    placed_at_offset = jax.lax.dynamic_slice(
        placed_around, (LOCAL_RADIUS + d_row, LOCAL_RADIUS + d_column), (LOCAL, LOCAL)
    )
    return jnp.any((local == target) & placed_at_offset)


def _window(game: Any, block: jax.Array, variant: Variant) -> jax.Array:
    """0/1 of `block` in the 21x21 window around the player (start clamped inside the map)."""
    row, column = game.player_position[0], game.player_position[1]
    found = (overworld(game, variant) == block).astype(jnp.int32)
    return jax.lax.dynamic_slice(
        found, (row - WINDOW_RADIUS, column - WINDOW_RADIUS), (WINDOW, WINDOW)
    )


def _extended(window: jax.Array) -> jax.Array:
    """The window with `REACH` extra cells on every side holding what JAX indexing reads there:
    a negative index wraps once to the far end, an index past the end clamps to the last cell."""

    def extend(array: jax.Array, axis: int) -> jax.Array:
        size = array.shape[axis]
        wrapped = jax.lax.slice_in_dim(array, size - REACH, size, axis=axis)
        last = jax.lax.slice_in_dim(array, size - 1, size, axis=axis)
        clamped = jnp.repeat(last, REACH, axis=axis)
        return jnp.concatenate([wrapped, array, clamped], axis=axis)

    return extend(extend(window, 0), 1)


def _all_at(extended: jax.Array, offsets: list[tuple[int, int]], value: int) -> jax.Array:
    """(21, 21): whether the window holds `value` at each center plus every one of `offsets`.

    Static slices of the extended window, and-ed one by one, rather than a gather per offset
    stacked: XLA fuses them, which made the line and square checks a small part of the step."""
    held = [
        extended[REACH + dr : REACH + dr + WINDOW, REACH + dc : REACH + dc + WINDOW] == value
        for dr, dc in offsets
    ]
    return functools.reduce(jnp.logical_and, held)


def _line_found(
    window: jax.Array, extended: jax.Array, length: int, diagonal: jax.Array
) -> jax.Array:
    # A line of 2 is looked for as two empty cells (the official check compares with 0).
    wanted = 0 if length == 2 else 1
    total = jnp.sum(window)
    straight_total = 0 if length == 2 else length
    diagonal_total = 3 if length == 2 else length
    runs = {
        "down": [(k, 0) for k in range(length)],
        "right": [(0, k) for k in range(length)],
        "down_right": [(k, k) for k in range(length)],
        "down_left": [(k, -k) for k in range(length)],
    }
    complete = {name: _all_at(extended, offs, wanted) for name, offs in runs.items()}
    straight = (total == straight_total) & jnp.any(complete["down"] | complete["right"])
    slanted = (total == diagonal_total) & jnp.any(complete["down_right"] | complete["down_left"])
    return jnp.where(diagonal, slanted, straight)


def _line(game: Any, params: jax.Array, variant: Variant) -> jax.Array:
    window = _window(game, params[0], variant)
    diagonal = params[2] != 0
    extended = _extended(window)
    found = jnp.stack([_line_found(window, extended, length, diagonal) for length in (2, 3, 4)])
    return found[jnp.clip(params[1] - 2, 0, 2)]


def _square(game: Any, params: jax.Array, variant: Variant) -> jax.Array:
    extended = _extended(_window(game, params[0], variant))
    found = []
    for side in (2, 3, 4):
        filled, ring = square_offsets(side)
        solid = _all_at(extended, filled, 1)
        clear = _all_at(extended, ring, 0)
        found.append(jnp.any(solid & clear))
    return jnp.stack(found)[jnp.clip(params[1] - 2, 0, 2)]


def _star(game: Any, params: jax.Array, variant: Variant) -> jax.Array:
    block, radius, arm = params[0], params[1], params[2]
    row, column = game.player_position[0], game.player_position[1]
    padded = jnp.pad(overworld(game, variant), WINDOW_RADIUS, constant_values=-1)
    around = jax.lax.dynamic_slice(padded, (row, column), (WINDOW, WINDOW))
    offsets = jnp.arange(WINDOW) - WINDOW_RADIUS
    near = jnp.abs(offsets) <= radius
    found = (jnp.where(near[:, None] & near[None, :], around, -1) == block).astype(jnp.int32)
    centre = STAR_FILTER // 2
    first = centre - arm // 2
    taps = jnp.arange(STAR_FILTER)
    in_arm = (taps >= first) & (taps < first + arm)
    outputs = WINDOW - STAR_FILTER + 1

    def shifted(dr: int, dc: int) -> jax.Array:
        return found[dr : dr + outputs, dc : dc + outputs]

    across = sum(in_arm[k] * shifted(centre, k) for k in range(STAR_FILTER))
    down = sum(in_arm[k] * shifted(k, centre) for k in range(STAR_FILTER))
    main = sum(in_arm[k] * shifted(k, k) for k in range(STAR_FILTER))
    anti = sum(
        (in_arm[k] & in_arm[STAR_FILTER - 1 - k]) * shifted(k, STAR_FILTER - 1 - k)
        for k in range(STAR_FILTER)
    )
    straight = (across == arm) & (down == arm)
    diagonal = (main == arm) & (anti == arm)
    return jnp.any(straight | diagonal)


def goal_met(
    previous: Any,
    game: Any,
    kind: jax.Array,
    required: jax.Array,
    forbidden: jax.Array,
    params: jax.Array,
    variant: Variant,
) -> jax.Array:
    """Whether one episode's goal is met after a step from `previous` to `game` (one episode;
    vmap it for a batch, where every kind is computed and the episode's own is selected)."""
    branches = [
        lambda: goal_reached(game.achievements[:NUM_ACHIEVEMENTS], required, forbidden),
        lambda: _conditional_placing(previous, game, params, variant),
        lambda: _localization(game, params, variant),
        lambda: _line(game, params, variant),
        lambda: _square(game, params, variant),
        lambda: _star(game, params, variant),
    ]
    return jax.lax.switch(kind, branches)


TRACE_FIELDS = ("row", "column", "held", "standing")
"""What `checker_trace` reports of a state, in order."""


def checker_trace(game: Any, kind: jax.Array, params: jax.Array, variant: Variant) -> jax.Array:
    """int32 (4,): the player's map row and column, the inventory count a conditional-placing
    goal tracks (0 for other kinds), and how many blocks of the goal's block stand on the map
    the checker reads (the placed block of a placing goal, the built block of a line, square or
    star; 0 for achievements goals). A replay records it per state, so a report can show what
    the checker looked at without keeping every state."""
    conditional = kind == KIND_INDEX["conditional_placing"]
    slot = jnp.where(conditional, params[0], 0)
    block = jnp.where(conditional, params[2], params[0])
    held = jnp.where(conditional, inventory(game, variant)[slot], 0)
    standing = jnp.where(
        kind == KIND_INDEX["achievements"], 0, jnp.sum(overworld(game, variant) == block)
    )
    position = jnp.asarray(game.player_position, jnp.int32)
    return jnp.stack([position[0], position[1], held, standing.astype(jnp.int32)]).astype(jnp.int32)
