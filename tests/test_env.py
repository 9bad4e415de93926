"""The CrafText env on real Craftax states: the checker's truth table, rewards, termination,
batched vs single stepping, determinism and slot refills, in both variants."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from env import (
    ACHIEVEMENT_IDS,
    NUM_ACHIEVEMENTS,
    EnvConfig,
    Termination,
    Variant,
    VectorEnv,
    episode_key,
    make_task,
    shared_env,
)
from env.checker import goal_reached

NOOP = 0


def masks(required: list[str], forbidden: list[str] = []) -> tuple[np.ndarray, np.ndarray]:  # noqa: B006
    req = np.zeros(NUM_ACHIEVEMENTS, bool)
    forb = np.zeros(NUM_ACHIEVEMENTS, bool)
    for name in required:
        req[ACHIEVEMENT_IDS[name]] = True
    for name in forbidden:
        forb[ACHIEVEMENT_IDS[name]] = True
    return req, forb


def with_achievements(state: Any, names: list[str]) -> Any:
    achievements = np.asarray(state.game.achievements).copy()
    for name in names:
        achievements[ACHIEVEMENT_IDS[name]] = True
    game = state.game.replace(achievements=jnp.asarray(achievements))
    return state.replace(game=game)


def key(i: int = 0) -> jax.Array:
    return jnp.asarray(episode_key(7, "test", 0, i))


@pytest.mark.parametrize(
    ("unlocked", "required", "forbidden", "success"),
    [
        ([], ["COLLECT_WOOD"], [], False),
        (["COLLECT_WOOD"], ["COLLECT_WOOD"], [], True),
        (["COLLECT_WOOD"], ["COLLECT_WOOD", "PLACE_TABLE"], [], False),
        (["PLACE_TABLE", "COLLECT_WOOD"], ["COLLECT_WOOD", "PLACE_TABLE"], [], True),
        (["COLLECT_WOOD", "EAT_COW"], ["COLLECT_WOOD"], ["EAT_COW"], False),
        (["COLLECT_WOOD"], ["COLLECT_WOOD"], ["EAT_COW"], True),
        (["COLLECT_WOOD", "COLLECT_SAPLING", "WAKE_UP"], ["COLLECT_WOOD"], [], True),
        (["MAKE_IRON_SWORD"], ["MAKE_IRON_SWORD"], ["COLLECT_DIAMOND"], True),
    ],
)
def test_checker_truth_table_on_real_states(
    any_env: Any, unlocked: list[str], required: list[str], forbidden: list[str], success: bool
) -> None:
    req, forb = masks(required, forbidden)
    state = any_env.reset(key(), make_task(req, forb))
    state = with_achievements(state, unlocked)
    _, info = any_env.step(state, jnp.int32(NOOP))
    assert (int(info.termination) == Termination.SUCCESS) == success
    assert bool(info.done) == success
    if success:
        craftax_part = float(info.craftax_reward) / 50.0
        assert float(info.reward) == pytest.approx(1.0 + craftax_part)
    else:
        assert float(info.reward) < 1.0


def test_goal_reached_matches_set_semantics() -> None:
    rng = np.random.default_rng(0)
    unlocked = rng.random((500, NUM_ACHIEVEMENTS)) < 0.3
    required = rng.random((500, NUM_ACHIEVEMENTS)) < 0.1
    forbidden = (rng.random((500, NUM_ACHIEVEMENTS)) < 0.1) & ~required
    got = np.asarray(
        goal_reached(jnp.asarray(unlocked), jnp.asarray(required), jnp.asarray(forbidden))
    )
    expected = [
        set(np.flatnonzero(r)) <= set(np.flatnonzero(u))
        and not (set(np.flatnonzero(f)) & set(np.flatnonzero(u)))
        for u, r, f in zip(unlocked, required, forbidden, strict=True)
    ]
    assert got.tolist() == expected
    assert 0 < sum(expected) < 500


def test_success_is_scored_once_and_the_finished_episode_is_masked(any_env: Any) -> None:
    req, forb = masks(["COLLECT_WOOD"])
    state = with_achievements(any_env.reset(key(), make_task(req, forb)), ["COLLECT_WOOD"])
    done_state, info = any_env.step(state, jnp.int32(NOOP))
    assert int(info.termination) == Termination.SUCCESS
    later = done_state
    for _ in range(3):
        later, later_info = any_env.step(later, jnp.int32(1))
        assert float(later_info.reward) == 0.0
        assert int(later_info.termination) == Termination.SUCCESS and bool(later_info.done)
        assert not np.asarray(later_info.new_achievements).any()
    assert int(later.steps) == int(done_state.steps) == 1


def test_death_ends_the_episode(any_env: Any) -> None:
    req, forb = masks(["COLLECT_DIAMOND"])
    state = any_env.reset(key(), make_task(req, forb))
    dying = state.replace(game=state.game.replace(player_health=state.game.player_health * 0))
    _, info = any_env.step(dying, jnp.int32(NOOP))
    assert bool(info.done)
    assert int(info.termination) == Termination.DEATH


def test_step_cap_times_out() -> None:
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=3))
    reset, step = env.jitted_reset, jax.jit(env.step_from_episode_key)
    req, forb = masks(["COLLECT_DIAMOND"])
    state = reset(key(), make_task(req, forb))
    terminations = []
    for _ in range(4):
        state, info = step(state, jnp.int32(NOOP))
        terminations.append(int(info.termination))
    assert terminations == [0, 0, Termination.TIMEOUT, Termination.TIMEOUT]
    assert int(state.steps) == 3


def _leaves_equal(a: Any, b: Any) -> bool:
    return all(
        np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


@pytest.mark.parametrize("variant", ["classic", "full"])
def test_batched_stepping_equals_single_episodes(
    variant: str, classic_env: Any, full_env: Any
) -> None:
    compiled = classic_env if variant == "classic" else full_env
    batch = 3
    steps = 12
    keys = np.stack([episode_key(1, "goal", 0, i) for i in range(batch)])
    req = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    req[:, ACHIEVEMENT_IDS["COLLECT_DIAMOND"]] = True
    forb = np.zeros_like(req)
    actions = np.random.default_rng(3).integers(0, compiled.env.num_actions, (steps, batch))

    vector = VectorEnv(compiled.env, batch)
    host = vector.reset(keys, req, forb)
    rewards = []
    for t in range(steps):
        host = vector.step(actions[t])
        rewards.append(host.reward)

    for i in range(batch):
        state = compiled.reset(jnp.asarray(keys[i]), make_task(req[i], forb[i]))
        single_rewards = []
        for t in range(steps):
            state, info = compiled.step(state, jnp.int32(actions[t, i]))
            single_rewards.append(float(info.reward))
        game_i = jax.tree.map(lambda x, i=i: x[i], host.game)
        assert _leaves_equal(jax.device_get(state.game), game_i)
        assert np.allclose([r[i] for r in rewards], single_rewards)
        assert int(host.steps[i]) == steps


def test_same_seed_same_world_and_trajectory(classic_env: Any) -> None:
    req, forb = masks(["COLLECT_DIAMOND"])
    task = make_task(req, forb)
    actions = np.random.default_rng(5).integers(0, 17, 20)

    def rollout(k: jax.Array) -> Any:
        state = classic_env.reset(k, task)
        for a in actions:
            state, _ = classic_env.step(state, jnp.int32(a))
        return jax.device_get(state.game)

    first = rollout(key(0))
    assert _leaves_equal(first, rollout(key(0)))
    other = rollout(key(1))
    assert not np.array_equal(np.asarray(first.map), np.asarray(other.map))


def test_episode_key_depends_on_every_component() -> None:
    base = episode_key(0, "COLLECT_WOOD", 0, 0)
    assert base.dtype == np.uint32 and base.shape == (2,)
    assert np.array_equal(base, episode_key(0, "COLLECT_WOOD", 0, 0))
    variants = [
        episode_key(1, "COLLECT_WOOD", 0, 0),
        episode_key(0, "PLACE_TABLE", 0, 0),
        episode_key(0, "COLLECT_WOOD", 1, 0),
        episode_key(0, "COLLECT_WOOD", 0, 1),
    ]
    assert all(not np.array_equal(base, v) for v in variants)


def test_every_slot_gets_the_world_of_its_own_key_whatever_the_batch_size(
    classic_env: Any,
) -> None:
    """Vectorised world generation gave slots past the eighth other worlds (XLA on CPU): an
    episode's world must not depend on how many episodes are in flight."""
    batch = 12
    keys = np.stack([episode_key(5, "goal", 0, i) for i in range(batch)])
    req, forb = masks(["COLLECT_WOOD"])
    vector = VectorEnv(classic_env.env, batch)
    host = vector.reset(keys, np.repeat(req[None], batch, 0), np.repeat(forb[None], batch, 0))
    for slot in range(batch):
        alone = classic_env.reset(jnp.asarray(keys[slot]), make_task(req, forb)).game
        assert _leaves_equal(
            jax.device_get(alone), jax.tree.map(lambda x, s=slot: x[s], host.game)
        ), f"slot {slot}"


@pytest.mark.parametrize("refilled", [[1], [0, 2]], ids=["one slot", "most slots"])
def test_refill_restarts_only_the_named_slots(classic_env: Any, refilled: list[int]) -> None:
    batch = 3
    keys = np.stack([episode_key(2, "goal", 0, i) for i in range(batch)])
    req = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    req[:, ACHIEVEMENT_IDS["COLLECT_DIAMOND"]] = True
    forb = np.zeros_like(req)
    vector = VectorEnv(classic_env.env, batch)
    vector.reset(keys, req, forb)
    for _ in range(5):
        before = vector.step(np.full(batch, 1))

    new_keys = np.stack([episode_key(2, "goal", 0, 99 + slot) for slot in refilled])
    new_req, new_forb = masks(["COLLECT_WOOD"])
    after = vector.refill(
        refilled,
        new_keys,
        np.repeat(new_req[None], len(refilled), 0),
        np.repeat(new_forb[None], len(refilled), 0),
    )

    kept = [slot for slot in range(batch) if slot not in refilled]
    assert after.steps.tolist() == [0 if slot in refilled else 5 for slot in range(batch)]
    for row, slot in enumerate(refilled):
        fresh = jax.device_get(
            classic_env.reset(jnp.asarray(new_keys[row]), make_task(new_req, new_forb)).game
        )
        assert _leaves_equal(fresh, jax.tree.map(lambda x, s=slot: x[s], after.game))
    for slot in kept:
        assert _leaves_equal(
            jax.tree.map(lambda x, s=slot: x[s], before.game),
            jax.tree.map(lambda x, s=slot: x[s], after.game),
        )
    # The refilled slots now play the new task: unlocking wood succeeds there only.
    game = after.game
    achievements = np.asarray(game.achievements).copy()
    achievements[:, ACHIEVEMENT_IDS["COLLECT_WOOD"]] = True
    vector._state = vector._require_state().replace(
        game=vector._require_state().game.replace(achievements=jnp.asarray(achievements))
    )
    stepped = vector.step(np.zeros(batch))
    assert stepped.termination.tolist() == [
        Termination.SUCCESS if slot in refilled else 0 for slot in range(batch)
    ]


def test_new_achievements_are_reported_on_the_unlocking_step_only(any_env: Any) -> None:
    from craftax.craftax_classic.constants import BlockType

    req, forb = masks(["COLLECT_DIAMOND"])
    state = any_env.reset(key(), make_task(req, forb))
    game = state.game
    facing = {1: (0, -1), 2: (0, 1), 3: (-1, 0), 4: (1, 0)}[int(game.player_direction)]
    target = np.asarray(game.player_position) + np.asarray(facing)
    world = np.asarray(game.map).copy()
    tree = BlockType.TREE.value
    if world.ndim == 3:  # full Craftax: one map per floor
        world[int(game.player_level), target[0], target[1]] = tree
    else:
        world[target[0], target[1]] = tree
    state = state.replace(game=game.replace(map=jnp.asarray(world)))
    do = 5
    wood = ACHIEVEMENT_IDS["COLLECT_WOOD"]
    state, info = any_env.step(state, jnp.int32(do))
    new = np.asarray(info.new_achievements)
    assert new[wood] and new.sum() == 1
    assert float(info.reward) > 0  # Craftax's achievement reward, divided by 50
    _, info = any_env.step(state, jnp.int32(do))
    assert not np.asarray(info.new_achievements)[wood]


@pytest.fixture(scope="module")
def official_env() -> Any:
    """Classic under the official success rule and world seeding."""
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, success_rule="official", world_key=1))
    return env, jax.jit(env.step_from_episode_key)


@pytest.mark.parametrize("dies", [True, False])
def test_a_goal_completed_as_the_game_ends_is_scored_by_the_rule(
    classic_env: Any, official_env: Any, dies: bool
) -> None:
    official, official_step = official_env
    req, forb = masks(["COLLECT_WOOD"])
    outcomes = {}
    for rule, reset, step in (
        ("game_over_counts", classic_env.reset, classic_env.step),
        ("official", official.jitted_reset, official_step),
    ):
        state = with_achievements(reset(key(), make_task(req, forb)), ["COLLECT_WOOD"])
        if dies:
            state = state.replace(
                game=state.game.replace(player_health=state.game.player_health * 0)
            )
        _, info = step(state, jnp.int32(NOOP))
        outcomes[rule] = (Termination(int(info.termination)), bool(info.goal_at_game_over))
        assert bool(info.done)
        assert (float(info.reward) >= 1.0) == (outcomes[rule][0] == Termination.SUCCESS)
    if dies:
        # Whatever the rule, the env reports that the goal was met on the game-over step.
        assert outcomes == {
            "game_over_counts": (Termination.SUCCESS, True),
            "official": (Termination.DEATH, True),
        }
    else:
        assert outcomes == {
            "game_over_counts": (Termination.SUCCESS, False),
            "official": (Termination.SUCCESS, False),
        }


@pytest.mark.parametrize("dies", [True, False])
def test_on_the_game_over_step_official_scores_the_goal_in_the_new_world(
    classic_env: Any, official_env: Any, dies: bool
) -> None:
    from env.goals import ConditionalPlacingGoal
    from env.scenario_tasks import encode_goals

    # "Collect a wood, then place stone": the wood held is never spent, but the official wrapper
    # checks the step from this state to the auto-reset world, whose inventory is empty: the
    # wood looks spent, and the map before the step has stone.
    goal = ConditionalPlacingGoal(
        id="C",
        split="medium_train",
        scenario="medium",
        instruction="t",
        paraphrases=(),
        collect="wood",
        collect_count=1,
        place="STONE",
        place_count=1,
    )
    encoded = encode_goals([goal], Variant.CLASSIC)
    task = make_task(encoded.required[0], encoded.forbidden[0], encoded.kind[0], encoded.params[0])
    official, official_step = official_env
    outcomes = {}
    for rule, reset, step in (
        ("game_over_counts", classic_env.reset, classic_env.step),
        ("official", official.jitted_reset, official_step),
    ):
        state = reset(key(), task)
        game = state.game.replace(inventory=state.game.inventory.replace(wood=jnp.int32(3)))
        if dies:
            game = game.replace(player_health=game.player_health * 0, player_recover=0.0)
        _, info = step(state.replace(game=game), jnp.int32(NOOP))
        outcomes[rule] = (
            Termination(int(info.termination)),
            bool(info.goal_at_game_over),
            bool(info.goal_in_new_world),
        )
        assert (float(info.reward) >= 1.0) == (outcomes[rule][0] == Termination.SUCCESS)
    if dies:
        # Either rule reports the new world's verdict; only `official` scores it.
        assert outcomes == {
            "game_over_counts": (Termination.DEATH, False, True),
            "official": (Termination.SUCCESS, False, True),
        }
    else:
        assert outcomes == {rule: (Termination.RUNNING, False, False) for rule in outcomes}


def test_a_batch_checks_the_new_world_only_in_its_stepped_rows_that_end_their_game(
    classic_env: Any,
) -> None:
    from env.goals import ConditionalPlacingGoal
    from env.scenario_tasks import encode_goals

    goal = ConditionalPlacingGoal(
        id="C",
        split="medium_train",
        scenario="medium",
        instruction="t",
        paraphrases=(),
        collect="wood",
        collect_count=1,
        place="STONE",
        place_count=1,
    )
    encoded = encode_goals([goal], Variant.CLASSIC)
    placing = make_task(
        encoded.required[0], encoded.forbidden[0], encoded.kind[0], encoded.params[0]
    )
    wood = make_task(*masks(["COLLECT_WOOD"]))

    def row(task: Any, dies: bool) -> Any:
        state = with_achievements(classic_env.reset(key(), task), ["COLLECT_WOOD"])
        game = state.game.replace(inventory=state.game.inventory.replace(wood=jnp.int32(3)))
        if dies:
            game = game.replace(player_health=game.player_health * 0, player_recover=0.0)
        return state.replace(game=game)

    # Dying placing goal, living one, dying one not stepped, dying achievements goal.
    rows = [row(placing, True), row(placing, False), row(placing, True), row(wood, True)]
    batch = jax.tree.map(lambda *leaves: jnp.stack(leaves), *rows)
    active = jnp.asarray([True, True, False, True])
    _, info = classic_env.env.batched_step(batch, jnp.zeros(4, jnp.int32), active)
    assert np.asarray(info.goal_in_new_world).tolist() == [True, False, False, False]
    assert np.asarray(info.goal_at_game_over).tolist() == [False, False, False, True]
    assert [Termination(int(t)) for t in np.asarray(info.termination)] == [
        Termination.DEATH,
        Termination.RUNNING,
        Termination.RUNNING,
        Termination.SUCCESS,
    ]


def test_official_world_seeding_gives_every_episode_the_world_of_prng_key_1(
    official_env: Any,
) -> None:
    env, _ = official_env
    req, forb = masks(["COLLECT_DIAMOND"])
    first = env.jitted_reset(key(0), make_task(req, forb))
    second = env.jitted_reset(key(1), make_task(req, forb))
    _, expected = env.craftax.reset_env(jax.random.PRNGKey(1), env.params)
    assert np.array_equal(np.asarray(first.game.map), np.asarray(expected.map))
    assert np.array_equal(np.asarray(second.game.map), np.asarray(expected.map))
    # The episode key still drives the steps.
    assert not np.array_equal(np.asarray(first.episode_key), np.asarray(second.episode_key))


def _staggered_schedule(batch: int, steps: int, seed: int) -> list[list[int]]:
    """Rounds of ready slots, each slot ready `steps` times: mostly a few slots per round (the
    grouped step of a large batch), now and then most of them (the masked step)."""
    rng = np.random.default_rng(seed)
    left = [steps] * batch
    rounds: list[list[int]] = []
    while any(left):
        pending = [slot for slot in range(batch) if left[slot]]
        size = len(pending) if len(rounds) % 5 == 4 else int(rng.integers(1, 4))
        ready = sorted(rng.choice(pending, size=min(size, len(pending)), replace=False).tolist())
        for slot in ready:
            left[slot] -= 1
        rounds.append(ready)
    return rounds


@pytest.mark.parametrize("batch", [3, 12])
def test_masked_step_freezes_inactive_slots_and_timing_never_changes_a_trajectory(
    classic_env: Any, batch: int
) -> None:
    steps = 6
    keys = np.stack([episode_key(4, "goal", 0, i) for i in range(batch)])
    req = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    req[:, ACHIEVEMENT_IDS["COLLECT_DIAMOND"]] = True
    forb = np.zeros_like(req)
    actions = np.random.default_rng(7).integers(0, classic_env.env.num_actions, (steps, batch))

    lockstep = VectorEnv(classic_env.env, batch)
    lockstep.reset(keys, req, forb)
    expected_reward = np.zeros(batch)
    expected_new = np.zeros((batch, NUM_ACHIEVEMENTS), int)
    for t in range(steps):
        expected = lockstep.step(actions[t])
        expected_reward += expected.reward
        expected_new += expected.new_achievements

    # The same actions per slot, but each slot stepped on its own schedule.
    staggered = VectorEnv(classic_env.env, batch)
    staggered.reset(keys, req, forb)
    taken = [0] * batch
    reward = np.zeros(batch)
    new = np.zeros((batch, NUM_ACHIEVEMENTS), int)
    for ready in _staggered_schedule(batch, steps, seed=batch):
        before = jax.device_get(staggered._require_state())
        active = np.zeros(batch, bool)
        step_actions = np.zeros(batch, np.int32)
        for slot in ready:
            active[slot] = True
            step_actions[slot] = actions[taken[slot], slot]
            taken[slot] += 1
        host = staggered.step(step_actions, active)
        reward += host.reward
        new += host.new_achievements
        after = jax.device_get(staggered._require_state())
        for slot in set(range(batch)) - set(ready):
            assert _leaves_equal(
                jax.tree.map(lambda x, s=slot: x[s], before),
                jax.tree.map(lambda x, s=slot: x[s], after),
            )
            assert host.reward[slot] == 0 and not host.new_achievements[slot].any()
    assert taken == [steps] * batch
    assert _leaves_equal(expected.game, host.game)
    assert host.steps.tolist() == expected.steps.tolist() == [steps] * batch
    assert np.allclose(reward, expected_reward) and np.array_equal(new, expected_new)


@pytest.mark.slow
def test_a_second_process_compiles_nothing(tmp_path: Path) -> None:
    """Every env function a run compiles is loaded from the persistent cache the next time."""
    child = """
import sys
import time
from collections import Counter
from jax import monitoring
events = Counter()
monitoring.register_event_listener(lambda name, **_: events.update([name]))
import numpy as np
from env import CrafTextEnv, EnvConfig, Variant, VectorEnv, episode_key
from env.achievements import NUM_ACHIEVEMENTS
vector = VectorEnv(CrafTextEnv(EnvConfig(variant=Variant.CLASSIC, max_steps=5)), 2)
keys = np.stack([episode_key(0, "g", 0, i) for i in range(2)])
required = np.zeros((2, NUM_ACHIEVEMENTS), bool)
vector.reset(keys, required, required)
vector.step(np.zeros(2, np.int32), np.array([True, False]))
vector.refill([0], keys[:1], required[:1], required[:1])
print(events["/jax/compilation_cache/cache_misses"], events["/jax/compilation_cache/cache_hits"])
"""
    environ = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path)}
    counts = []
    for _ in range(2):
        done = subprocess.run(
            [sys.executable, "-c", child], env=environ, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        counts.append([int(n) for n in done.stdout.split()])
    (first_misses, _), (second_misses, second_hits) = counts
    assert first_misses > 0
    assert second_misses == 0 and second_hits >= first_misses


def test_the_cache_is_never_read_or_written_while_another_process_holds_its_lock(
    tmp_path: Path,
) -> None:
    """A process compiling what another is writing waits for the whole entry: JAX writes an
    entry in place, and a half-written executable crashes the process that loads it."""
    from filelock import FileLock

    child = f"""
import time
import jax, jax.numpy as jnp
from pathlib import Path
from env.jax_cache import enable_compilation_cache
enable_compilation_cache(Path({str(tmp_path)!r}))
print(time.time(), flush=True)
jax.jit(lambda x: jnp.sin(x) * 3)(jnp.ones(3)).block_until_ready()
print(time.time(), flush=True)
"""
    hold_s = 3.0
    with FileLock(tmp_path / ".lockfile"):
        child_process = subprocess.Popen(
            [sys.executable, "-c", child], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert child_process.stdout is not None
        compile_started = float(child_process.stdout.readline())
        time.sleep(hold_s)
        released = time.time()
    out, err = child_process.communicate(timeout=120)
    assert child_process.returncode == 0, err
    compiled = float(out.split()[0])
    assert compile_started < released <= compiled
    assert list(tmp_path.glob("*-cache")), "the compiled function was not cached"


def test_a_cache_written_unbounded_still_takes_new_entries(tmp_path: Path) -> None:
    """Entries JAX wrote with no bound on the cache (earlier versions, or JAX alone) carry no
    access time, which a bounded cache reads before every write."""
    unbounded = f"""
import jax, jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", {str(tmp_path)!r})
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.jit(lambda x: x + 1)(jnp.ones(2)).block_until_ready()
"""
    bounded = f"""
import jax, jax.numpy as jnp
from pathlib import Path
from env.jax_cache import enable_compilation_cache
enable_compilation_cache(Path({str(tmp_path)!r}))
jax.jit(lambda x: x * 5 - 2)(jnp.ones(2)).block_until_ready()
"""
    entries = []
    for child in (unbounded, bounded):
        done = subprocess.run(
            [sys.executable, "-W", "error::UserWarning", "-c", child],
            capture_output=True,
            text=True,
        )
        assert done.returncode == 0, done.stderr
        entries.append({p.name for p in tmp_path.glob("jit__lambda-*-cache")})
    assert len(entries[0]) == 1 and len(entries[1]) == 2, entries


def test_an_env_keeps_the_cache_directory_the_caller_chose(tmp_path: Path) -> None:
    child = f"""
import jax
from env import CrafTextEnv, EnvConfig, Variant
from env.jax_cache import enable_compilation_cache
from pathlib import Path
enable_compilation_cache(Path({str(tmp_path)!r}))
CrafTextEnv(EnvConfig(variant=Variant.CLASSIC))
print(jax.config.jax_compilation_cache_dir)
"""
    environ = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    done = subprocess.run(
        [sys.executable, "-c", child], env=environ, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(tmp_path)


@pytest.mark.parametrize("jax_started_first", [False, True])
def test_the_env_keeps_jax_off_the_accelerator_by_default(jax_started_first: bool) -> None:
    """Before JAX starts, only its CPU client is allowed (no accelerator memory is claimed);
    after, the env's arrays still land on the CPU."""
    child = f"""
import jax, jax.numpy as jnp
if {jax_started_first}:
    jnp.zeros(1)
from env import CrafTextEnv, EnvConfig, Variant
env = CrafTextEnv(EnvConfig(variant=Variant.CLASSIC), compilation_cache=False)
print(jax.config.jax_platforms, jax.config.jax_default_device.platform, jnp.zeros(1).devices())
"""
    environ = {k: v for k, v in os.environ.items() if k != "JAX_PLATFORMS"}
    done = subprocess.run(
        [sys.executable, "-c", child], env=environ, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    platforms, default_device, placed = done.stdout.split(maxsplit=2)
    assert platforms == ("None" if jax_started_first else "cpu")
    assert default_device == "cpu"
    assert "CpuDevice" in placed


def test_a_batch_mixing_goal_kinds_scores_each_slot_by_its_own_checker(classic_env: Any) -> None:
    # The official line check of size 2 looks for two cells *without* the block: in a fresh
    # world with no furnace anywhere a straight "line of 2 furnaces" is met at once, a diagonal
    # one (it wants exactly 3 such blocks in the window) is not, nor is the EASY goal beside it.
    from env.goals import BuildLineGoal, Goal
    from env.scenario_tasks import encode_goals

    text = {"split": "medium_train", "scenario": "medium", "instruction": "x", "paraphrases": ()}
    goals = [
        Goal(id="A", category="one", required=("COLLECT_DIAMOND",), forbidden=(), **text),
        BuildLineGoal(id="S", block="FURNACE", size=2, diagonal=False, **text),
        BuildLineGoal(id="D", block="FURNACE", size=2, diagonal=True, **text),
    ]
    tasks = encode_goals(goals, Variant.CLASSIC)
    vector = VectorEnv(classic_env.env, len(goals))
    keys = np.stack([episode_key(3, "mixed", 0, i) for i in range(len(goals))])
    vector.reset(keys, tasks.required, tasks.forbidden, tasks.kind, tasks.params)
    stepped = vector.step(np.full(len(goals), NOOP))
    assert stepped.termination.tolist() == [0, Termination.SUCCESS, 0]
    assert stepped.reward[1] >= 1.0 and stepped.reward[0] < 1.0


def test_a_game_over_step_is_checked_in_the_world_its_key_makes_whatever_its_row(
    classic_env: Any,
) -> None:
    # Craftax's world generation vmapped on XLA:CPU makes other worlds in lanes 8 and up (about
    # a tenth of their blocks differ), and a localization goal is met or not around a new spawn
    # by its natural blocks: checked in vmapped worlds, a row's verdict would depend on its
    # place in the batch. The env checks each row in the world its key makes alone.
    from env.craftext_env import _step_keys
    from env.goals import LocalizationGoal
    from env.scenario_checker import goal_met
    from env.scenario_tasks import encode_goals

    goal = LocalizationGoal(
        id="L",
        split="medium_train",
        scenario="medium",
        instruction="t",
        paraphrases=(),
        place="STONE",
        target="TREE",
        side="right",
        distance=2,
    )
    encoded = encode_goals([goal], Variant.CLASSIC)
    task = make_task(encoded.required[0], encoded.forbidden[0], encoded.kind[0], encoded.params[0])
    env = classic_env.env
    rows = 16

    def dying(state: Any) -> Any:
        game = state.game
        return state.replace(
            game=game.replace(player_health=game.player_health * 0, player_recover=0.0)
        )

    batch = jax.tree.map(
        lambda *leaves: jnp.stack(leaves),
        *[dying(classic_env.reset(key(i), task)) for i in range(rows)],
    )
    _, info = env.batched_step(batch, jnp.zeros(rows, jnp.int32), jnp.ones(rows, bool))
    reset_keys = [jax.random.split(k)[1] for k in _step_keys(batch)]

    def verdicts(worlds: list[Any]) -> list[bool]:
        return [
            bool(
                goal_met(
                    jax.tree.map(lambda leaf, i=i: leaf[i], batch.game),
                    world,
                    task.kind,
                    task.required,
                    task.forbidden,
                    task.params,
                    Variant.CLASSIC,
                )
            )
            for i, world in enumerate(worlds)
        ]

    generate = jax.jit(lambda k: env.craftax.reset_env(k, env.params)[1])
    alone = verdicts([generate(k) for k in reset_keys])
    vmapped = jax.jit(jax.vmap(lambda k: env.craftax.reset_env(k, env.params)[1]))(
        jnp.stack(reset_keys)
    )
    in_lanes = verdicts([jax.tree.map(lambda leaf, i=i: leaf[i], vmapped) for i in range(rows)])
    assert np.asarray(info.goal_in_new_world).tolist() == alone
    assert any(alone)
    # The case is exercised: vmapped worlds would have given other verdicts here.
    assert in_lanes != alone


def test_a_step_spends_its_key_as_craftaxs_auto_reset_env(classic_env: Any) -> None:
    # The official wrapper's inner env is Craftax's auto-reset env: for the same key, the game
    # must be the one it returns, and a game over's new world the one it starts (the world the
    # official rule checks).
    from craftax.craftax_env import make_craftax_env_from_name

    from env.scenario_checker import overworld

    auto_reset = make_craftax_env_from_name(Variant.CLASSIC.craftax_name, auto_reset=True)
    params = classic_env.env.params
    craftax_step = jax.jit(lambda k, s, a: auto_reset.step(k, s, a, params)[1:4:2])
    state = classic_env.reset(key(), make_task(*masks(["COLLECT_WOOD"])))
    game = state.game
    actions = np.random.default_rng(0).integers(Variant.CLASSIC.num_actions, size=12)
    for t, action in enumerate(actions):
        step_key = jax.random.fold_in(state.episode_key, state.steps)
        game, _ = craftax_step(step_key, game, jnp.int32(action))
        state, _ = classic_env.step(state, jnp.int32(action))
        assert int(state.steps) == t + 1
        for ours, theirs in zip(jax.tree.leaves(state.game), jax.tree.leaves(game), strict=True):
            np.testing.assert_array_equal(np.asarray(ours), np.asarray(theirs))
    dead = state.game.replace(player_health=state.game.player_health * 0, player_recover=0.0)
    step_key = jax.random.fold_in(state.episode_key, state.steps)
    world, done = craftax_step(step_key, dead, jnp.int32(NOOP))
    assert bool(done)
    checked = classic_env.env.new_world(step_key)
    np.testing.assert_array_equal(overworld(checked, Variant.CLASSIC), world.map)
    np.testing.assert_array_equal(checked.player_position, world.player_position)
