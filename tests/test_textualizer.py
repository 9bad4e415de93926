"""The textualizer against real Craftax states: coordinates, ground truth, JSON, errors.

States come from the session's raw craftax env (one instance per variant, see conftest), stepped
in a batch by one jitted function per variant. Snapshot tests on hand-built states live in
`test_textualizer_snapshots.py`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel

from env.errors import UserError
from textualizer import RENDERERS, Observation, observe, observe_batch, render

BATCH = 64
ROUNDS = 32  # BATCH * ROUNDS = 2048 states per variant
STEPS_PER_ROUND = 3
MOVES = {"LEFT": 1, "RIGHT": 2, "UP": 3, "DOWN": 4}
MOVE_SHIFT = {"LEFT": (-1, 0), "RIGHT": (1, 0), "UP": (0, 1), "DOWN": (0, -1)}
"""How the player's (x, y) changes on a successful move, as docs/observation.md states."""

# Blocks that stay put while the player only walks (plants grow, so they are left out).
FIXED_BLOCKS = {
    "tree",
    "stone",
    "water",
    "coal",
    "iron",
    "diamond",
    "sand",
    "grass",
    "lava",
    "path",
}


@dataclass
class Batched:
    """Jitted batched reset/step of one raw craftax env."""

    reset: Any
    step: Any
    num_actions: int


@cache
def _batched(craftax_env: Any, params: Any, num_actions: int) -> Batched:
    import jax

    def reset(keys: Any) -> Any:
        return jax.vmap(lambda key: craftax_env.reset_env(key, params)[1])(keys)

    def step(keys: Any, states: Any, actions: Any) -> Any:
        def one(key: Any, state: Any, action: Any) -> Any:
            return craftax_env.step_env(key, state, action, params)[1]

        return jax.vmap(one)(keys, states, actions)

    return Batched(reset=jax.jit(reset), step=jax.jit(step), num_actions=num_actions)


def _pull(states: Any) -> Any:
    import jax

    return jax.device_get(states)


@pytest.fixture(scope="module")
def batched(any_env: Any) -> tuple[str, Batched]:
    env = any_env.env
    return env.variant.value, _batched(env.craftax, env.params, env.num_actions)


# --- coordinates ------------------------------------------------------------------------


def _fixed_blocks(obs: Observation) -> dict[tuple[int, int], str]:
    return {
        offset: name
        for name, offsets in obs.blocks.items()
        if name in FIXED_BLOCKS
        for offset in offsets
    }


def test_walking_shifts_offsets_as_documented(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    rng = np.random.default_rng(0)
    states = fns.reset(jax.random.split(jax.random.PRNGKey(7), BATCH))
    before = observe_batch(_pull(states), variant)
    moved_count = blocked_count = 0
    for step in range(12):
        names = rng.choice(list(MOVES), size=BATCH)
        actions = np.array([MOVES[n] for n in names], dtype=np.int32)
        keys = jax.random.split(jax.random.PRNGKey(100 + step), BATCH)
        states = fns.step(keys, states, actions)
        after = observe_batch(_pull(states), variant)
        for name, old, new in zip(names, before, after, strict=True):
            assert new.facing == name.lower()
            shift = (new.position.x - old.position.x, new.position.y - old.position.y)
            if shift == (0, 0):
                blocked_count += 1
                # A refused move leaves the view where it was.
                assert _fixed_blocks(new) == _fixed_blocks(old)
                continue
            moved_count += 1
            assert shift == MOVE_SHIFT[name]
            old_blocks, new_blocks = _fixed_blocks(old), _fixed_blocks(new)
            half_x, half_y = new.view_size[0] // 2, new.view_size[1] // 2
            # A fixed block seen at offset o is now at o - shift, and the new view holds nothing
            # else that was inside the old one.
            expected = {
                (dx - shift[0], dy - shift[1]): kind
                for (dx, dy), kind in old_blocks.items()
                if abs(dx - shift[0]) <= half_x and abs(dy - shift[1]) <= half_y
            }
            overlap = {
                offset: kind
                for offset, kind in new_blocks.items()
                if abs(offset[0] + shift[0]) <= half_x and abs(offset[1] + shift[1]) <= half_y
            }
            assert overlap == expected
        before = after
    assert moved_count > 100 and blocked_count > 0


def test_facing_block_is_the_block_at_the_facing_offset(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    states = fns.reset(jax.random.split(jax.random.PRNGKey(3), BATCH))
    steps = {"left": (-1, 0), "right": (1, 0), "up": (0, 1), "down": (0, -1)}
    for obs in observe_batch(_pull(states), variant):
        assert obs.facing_block == obs.block_at(*steps[obs.facing])


# --- ground truth -----------------------------------------------------------------------

MOB_GROUPS_FULL = (
    (
        "melee_mobs",
        (
            "zombie",
            "gnome_warrior",
            "orc_soldier",
            "lizard",
            "knight",
            "troll",
            "pigman",
            "frost_troll",
        ),
    ),
    ("passive_mobs", ("cow", "bat", "snail")),
    (
        "ranged_mobs",
        (
            "skeleton",
            "gnome_archer",
            "orc_mage",
            "kobold",
            "knight_archer",
            "deep_thing",
            "fire_elemental",
            "ice_elemental",
        ),
    ),
    (
        "mob_projectiles",
        ("arrow", "dagger", "fireball", "iceball", "arrow", "slimeball", "fireball", "iceball"),
    ),
    (
        "player_projectiles",
        tuple(
            f"player_{n}"
            for n in (
                "arrow",
                "dagger",
                "fireball",
                "iceball",
                "arrow",
                "slimeball",
                "fireball",
                "iceball",
            )
        ),
    ),
)
MOB_GROUPS_CLASSIC = (
    ("zombies", "zombie"),
    ("cows", "cow"),
    ("skeletons", "skeleton"),
    ("arrows", "arrow"),
)
MOB_KINDS = {name for _, names in MOB_GROUPS_FULL for name in names}


def _reference(
    state: Any, variant: str
) -> tuple[
    set[tuple[str, int, int]],
    set[tuple[str, int, int, Any]],
    set[tuple[int, int]],
    set[tuple[str, int, int]],
]:
    """Visible blocks, mobs, unlit tiles and items, computed cell by cell from craftax's own
    constants: a slow, obvious re-statement of what the player sees."""
    if variant == "full":
        from craftax.craftax.constants import OBS_DIM, BlockType, ItemType
    else:
        from craftax.craftax_classic.constants import OBS_DIM, BlockType
    level = int(state.player_level) if variant == "full" else None
    world = state.map[level] if level is not None else state.map
    light = state.light_map[level] if level is not None else np.ones_like(world, dtype=float)
    row, col = (int(v) for v in state.player_position)
    blocks, unlit, items = set(), set(), set()
    lit_cells = set()
    for r in range(row - OBS_DIM[0] // 2, row + OBS_DIM[0] // 2 + 1):
        for c in range(col - OBS_DIM[1] // 2, col + OBS_DIM[1] // 2 + 1):
            inside = 0 <= r < world.shape[0] and 0 <= c < world.shape[1]
            dx, dy = c - col, row - r
            if not (inside and light[r, c] > 0.05) and variant == "full":
                unlit.add((dx, dy))
                continue
            lit_cells.add((r, c))
            name = BlockType(int(world[r, c])).name.lower() if inside else "out_of_bounds"
            blocks.add((name, dx, dy))
            if level is not None and int(state.item_map[level, r, c]) != 0:
                items.add((ItemType(int(state.item_map[level, r, c])).name.lower(), dx, dy))
    mobs = set()
    groups = MOB_GROUPS_FULL if variant == "full" else [(g, (n,)) for g, n in MOB_GROUPS_CLASSIC]
    for group, names in groups:
        data = getattr(state, group)
        count = data.mask.shape[-1]
        for i in range(count):
            index = (level, i) if level is not None else (i,)
            if not data.mask[index]:
                continue
            r, c = (int(v) for v in data.position[index])
            if (r, c) not in lit_cells:
                continue
            kind = names[int(data.type_id[index])] if variant == "full" else names[0]
            has_health = "projectile" not in group and group != "arrows"
            health = round(float(data.health[index]), 2) if has_health else None
            mobs.add((kind, c - col, row - r, health))
    return blocks, mobs, unlit, items


_OFFSET = re.compile(r"\((-?\d+),(-?\d+)\)")


def _parse_objects(text: str) -> tuple[set[tuple[str, int, int]], list[tuple[str, int, int]]]:
    """Every (kind, dx, dy) the `objects` text states, read back: blocks and items as a set,
    creatures as a sorted list (two cows may share nothing but their kind)."""
    body = text.split("):\n", 1)[1].splitlines()
    blocks: set[tuple[str, int, int]] = set()
    mobs: list[tuple[str, int, int]] = []
    for line in body:
        kind, _, rest = line.partition(":")
        kind = kind.split(" (")[0]
        if (
            kind in ("map edge", "unlit (unknown) tiles", "Achieved so far")
            or line == "only background"
        ):
            continue
        if "rows dy" in rest:
            rows = rest.split("; rows ")[1]
            for row in rows.split("; "):
                dy_text, runs = row.removeprefix("dy ").split(": dx ")
                for run in runs.split(", "):
                    low, _, high = run.partition("..")
                    for dx in range(int(low), int(high or low) + 1):
                        blocks.add((kind, dx, int(dy_text)))
            continue
        offsets = [(kind, int(dx), int(dy)) for dx, dy in _OFFSET.findall(rest)]
        if " hp " in rest or kind in MOB_KINDS:
            mobs += offsets
        else:
            blocks |= set(offsets)
    return blocks, sorted(mobs)


def _vary_full_states(states: Any, rng: np.random.Generator) -> Any:
    """Move half the episodes to random floors (with their darkness), sprinkle mobs and torches
    near the player there, and set random times of day, so every floor and light case occurs."""
    n = states.player_level.shape[0]
    level = np.where(rng.random(n) < 0.5, rng.integers(1, 9, n), states.player_level)
    player = states.player_position
    position = np.clip(player + rng.integers(-3, 4, (n, 2)), 0, 47)
    melee = states.melee_mobs
    idx = np.arange(n)
    mob_position = melee.position.copy()
    mob_position[idx, level, 0] = position
    mask = melee.mask.copy()
    mask[idx, level, 0] = True
    type_id = melee.type_id.copy()
    type_id[idx, level, 0] = rng.integers(0, 8, n)
    item_map = states.item_map.copy()
    torch_at = np.clip(player + rng.integers(-4, 5, (n, 2)), 0, 47)
    item_map[idx, level, torch_at[:, 0], torch_at[:, 1]] = 1
    return states.replace(
        player_level=level.astype(np.int32),
        melee_mobs=melee.replace(position=mob_position, mask=mask, type_id=type_id),
        item_map=item_map,
        light_level=rng.random(n).astype(np.float32),
    )


@pytest.mark.slow
def test_observation_matches_reference_on_random_states(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    rng = np.random.default_rng(1)
    states = fns.reset(jax.random.split(jax.random.PRNGKey(11), BATCH))
    seen_mobs = seen_unlit = seen_items = checked = 0
    floors: set[int] = set()
    for round_index in range(ROUNDS):
        for step in range(STEPS_PER_ROUND):
            keys = jax.random.split(jax.random.PRNGKey(1000 * round_index + step), BATCH)
            actions = rng.integers(0, fns.num_actions, BATCH).astype(np.int32)
            states = fns.step(keys, states, actions)
        host = _pull(states)
        if variant == "full":
            host = _vary_full_states(host, rng)
            floors |= set(host.player_level.tolist())
        for index, obs in enumerate(observe_batch(host, variant)):
            one = jax.tree_util.tree_map(lambda leaf, i=index: leaf[i], host)
            blocks, mobs, unlit, items = _reference(one, variant)
            got_blocks = {
                (name, dx, dy) for name, offsets in obs.blocks.items() for dx, dy in offsets
            }
            got_mobs = {(m.kind, m.dx, m.dy, m.health) for m in obs.mobs}
            got_items = {
                (name, dx, dy) for name, offsets in obs.items.items() for dx, dy in offsets
            }
            assert got_blocks == blocks
            assert got_mobs == mobs and len(obs.mobs) == len(got_mobs)
            assert set(obs.unlit) == unlit and len(obs.unlit) == len(unlit)
            assert got_items == items
            listed_blocks, listed_mobs = _parse_objects(render(obs, "objects"))
            background = {"grass", "sand", "path", "fire_grass", "ice_grass", "out_of_bounds"}
            assert listed_blocks == {b for b in blocks | items if b[0] not in background}
            assert listed_mobs == sorted((kind, dx, dy) for kind, dx, dy, _ in mobs)
            seen_mobs += len(mobs)
            seen_unlit += bool(unlit)
            seen_items += len(items)
            checked += 1
    assert checked >= 2000
    assert seen_mobs > 100
    if variant == "full":
        assert floors == set(range(9)) and seen_unlit > 100 and seen_items > 100


# --- serialisation and errors -----------------------------------------------------------


def test_observation_round_trips_through_json(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    states = fns.reset(jax.random.split(jax.random.PRNGKey(5), BATCH))
    for obs in observe_batch(_pull(states), variant):
        validated = Observation.model_validate(json.loads(obs.model_dump_json()))
        # Observations are built unvalidated (`env.trusted`): they must hold exactly what
        # validation gives, down to each value's type (an int where a float is due would
        # change the text).
        assert validated == obs
        assert _types(validated) == _types(obs)


def _types(value: Any) -> Any:
    """The value's shape with each leaf replaced by its type."""
    if isinstance(value, BaseModel):
        return (type(value), {name: _types(item) for name, item in value.__dict__.items()})
    if isinstance(value, dict):
        return (dict, [(type(key), _types(item)) for key, item in value.items()])
    if isinstance(value, list | tuple):
        return (type(value), [_types(item) for item in value])
    return type(value)


def test_observe_batch_equals_observe_per_episode(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    host = _pull(fns.reset(jax.random.split(jax.random.PRNGKey(9), BATCH)))
    batch = observe_batch(host, variant)
    for index in (0, BATCH - 1):
        assert (
            observe(jax.tree_util.tree_map(lambda leaf, i=index: leaf[i], host), variant)
            == batch[index]
        )
    assert batch[0].blocks != batch[-1].blocks  # the episodes really differ
    # The play loop observes the slots whose answers came, in any order.
    assert observe_batch(host, variant, indices=[BATCH - 1, 0, 5]) == [
        batch[-1],
        batch[0],
        batch[5],
    ]


def test_user_mistakes_raise_user_error(batched: tuple[str, Batched]) -> None:
    import jax

    variant, fns = batched
    host = _pull(fns.reset(jax.random.split(jax.random.PRNGKey(9), BATCH)))
    obs = observe_batch(host, variant)[0]
    with pytest.raises(UserError, match=r"'fancy'.*objects, grid, table"):
        render(obs, "fancy")
    with pytest.raises(UserError, match="observe_batch"):
        observe(host, variant)
    other = "classic" if variant == "full" else "full"
    with pytest.raises(UserError, match=f"variant is '{other}'"):
        observe_batch(host, other)
    with pytest.raises(UserError, match="'medium'"):
        observe_batch(host, "medium")
    assert RENDERERS == ("objects", "grid", "table")
