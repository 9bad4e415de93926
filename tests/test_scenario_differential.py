"""Our JAX checkers against the official CrafText checker code (1c518ae), run unmodified.

Every goal of every Medium and Hard split is scored on every step of biased-random Craftax
trajectories (a stocked inventory, mostly moves and placing actions, so tables, furnaces, stones
and plants really end up near each other and resources are spent; the same steps again with
squares stamped near the player, which random play never completes) by both: the official
per-scenario checker on the official `GameData.from_state(previous, new, action)` with the target
the official dataset module builds, and `env.scenario_checker.goal_met` with our encoding of the
goal we parsed.

Game-over steps are scored too, where the official wrapper checks the world its auto-reset env
starts (`GameData.from_state(previous, new world)`): states of the same trajectories, the
player killed, and the world craftax's auto-reset step draws from our step's key. Our checker
must score (previous, new world) as the official one does, and our env's own step on that state
(which makes the world itself) must report the official verdict (`goal_in_new_world`) for a
goal of every kind and split met there and one not met.
"""

from __future__ import annotations

import functools
import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from env.craftext_env import EpisodeState, make_task
from env.dataset import load_dataset
from env.goals import GOAL_KINDS
from env.scenario_checker import goal_met
from env.scenario_tasks import encode_goals
from env.termination import Termination
from env.variant import Variant

pytestmark = pytest.mark.slow

STEPS = 120
TRAJECTORIES = 3
#: Game-over steps taken from each trajectory's states (each generates two worlds).
DEATHS = 4
# Official `Scenarios` index -> the official checker function's module and name.
_OFFICIAL_CHECKERS = {
    0: ("achivments", "checker_acvievments", "achievements"),
    1: ("conditional", "checker_conditional_placement", "conditional_placing"),
    2: ("relevant", "cheker_localization", "Localization_placing"),
    3: ("building_line", "checker_line", "building_line"),
    4: ("building_square", "checker_square", "building_square"),
    5: ("building_star", "checker_star", "building_star"),
}
_SPLIT_MODULES = {
    "medium_train": ("instructions", "medium"),
    "medium_test_paraphrased": ("test", "medium_test_parafrased"),
    "medium_test_other_params": ("test", "medium_test_other_paramets"),
    "hard_train": ("instructions", "hard"),
}


@pytest.fixture(scope="module")
def official(official_repository: Path) -> Iterator[Any]:
    sys.path.insert(0, str(official_repository))
    try:
        yield importlib
    finally:
        sys.path.remove(str(official_repository))


@pytest.fixture(scope="module", autouse=True)
def _cached_for_this_module_only() -> Iterator[None]:
    """The trajectories and compiled functions below are cached for the test, then freed: full
    Craftax's trajectories alone hold over a GB, which the worker would otherwise keep."""
    yield
    for cached in (_craftax_step, _trajectories, _our_checker, _new_world):
        cached.cache_clear()
    _SCORERS.clear()


_SCORERS: dict[tuple[Any, Any], Any] = {}


def _official_scorer(checker: Any, game_data: Any) -> Any:
    """The official checker over a trajectory, compiled once per checker: the goal's target
    state is an argument (a pytree of arrays), not a constant, so goals share the compile."""
    key = (checker, game_data)
    if key not in _SCORERS:
        _SCORERS[key] = jax.jit(
            jax.vmap(
                lambda p, n, a, target: checker(game_data.from_state(p, n, a), target),
                in_axes=(0, 0, 0, None),
            )
        )
    return _SCORERS[key]


@functools.cache
def _craftax_step(variant: Variant) -> tuple[Any, Any]:
    """(reset, compiled step) of raw Craftax: one trace per variant, not one per trajectory."""
    from craftax.craftax_env import make_craftax_env_from_name

    env = make_craftax_env_from_name(variant.craftax_name, auto_reset=False)
    params = env.default_params
    return (
        jax.jit(lambda key: env.reset_env(key, params)[1]),
        jax.jit(lambda key, s, a: env.step_env(key, s, a, params)),
    )


@functools.cache
def _trajectories(variant: Variant) -> list[tuple[Any, Any, np.ndarray]]:
    """Every trajectory a variant's splits are scored on: `TRAJECTORIES` biased-random ones,
    then the same with squares stamped (`_with_squares`). The Medium splits share them."""
    plain = [_trajectory(variant, seed) for seed in range(TRAJECTORIES)]
    return plain + [
        (*_with_squares(previous, new, variant, seed), actions)
        for seed, (previous, new, actions) in enumerate(plain)
    ]


@functools.cache
def _our_checker(variant: Variant) -> Any:
    """`goal_met` over a trajectory, one goal's encoding broadcast over its steps."""
    return jax.jit(
        jax.vmap(
            lambda p, n, kind, req, forb, par: goal_met(p, n, kind, req, forb, par, variant),
            in_axes=(0, 0, None, None, None, None),
        )
    )


def _trajectory(variant: Variant, seed: int) -> tuple[Any, Any, np.ndarray]:
    """(previous states, new states, actions) of one biased-random episode, stacked by step."""
    reset, step = _craftax_step(variant)
    rng = np.random.default_rng(seed)
    state = reset(jax.random.PRNGKey(seed))
    inventory = state.inventory.replace(
        wood=jnp.int32(9), stone=jnp.int32(9), sapling=jnp.int32(9), coal=jnp.int32(3)
    )
    state = state.replace(inventory=inventory)
    names = variant.action_names
    placing = [
        names.index(n) for n in ("PLACE_TABLE", "PLACE_FURNACE", "PLACE_STONE", "PLACE_PLANT")
    ]
    moves = [names.index(n) for n in ("LEFT", "RIGHT", "UP", "DOWN")]
    previous, new, actions = [], [], []
    for index in range(STEPS):
        pick = rng.random()
        action = int(
            rng.choice(placing)
            if pick < 0.45
            else rng.choice(moves)
            if pick < 0.9
            else rng.integers(len(names))
        )
        _, after, _, done, _ = step(jax.random.PRNGKey(seed * 1000 + index), state, action)
        if bool(done):
            break
        if rng.random() < 0.1:
            # Restock now and then, to a random level, so counts rise as well as fall and the
            # spending that follows crosses the conditional goals' thresholds (1 to 5).
            level = lambda: jnp.int32(rng.integers(1, 7))  # noqa: E731
            after = after.replace(
                inventory=after.inventory.replace(wood=level(), stone=level(), sapling=level())
            )
        previous.append(state)
        new.append(after)
        actions.append(action)
        state = after
    stack = lambda states: jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)  # noqa: E731
    return stack(previous), stack(new), np.asarray(actions, np.int32)


class _GameEnds:
    """A Craftax env whose step always ends the game, for craftax's own auto-reset step
    (`EnvironmentAutoReset.step`) to run over: what that returns is the new world the official
    wrapper checks, drawn from the step's key as craftax draws it, without compiling the game's
    step once more."""

    def __init__(self, variant: Variant):
        from craftax.craftax_env import make_craftax_env_from_name

        self.craftax = make_craftax_env_from_name(variant.craftax_name, auto_reset=False)

    def step_env(self, key: Any, state: Any, action: Any, params: Any) -> Any:
        return self.craftax.get_obs(state), state, jnp.float32(0), jnp.bool_(True), {}

    def reset_env(self, key: Any, params: Any) -> Any:
        return self.craftax.reset_env(key, params)


@functools.cache
def _new_world(variant: Variant) -> Any:
    from craftax.environment_base.environment_bases import EnvironmentAutoReset

    ends = _GameEnds(variant)
    params = ends.craftax.default_params
    return jax.jit(lambda key, state: EnvironmentAutoReset.step(ends, key, state, 0, params)[1])


def _deaths(
    variant: Variant, previous: Any, actions: np.ndarray, seed: int
) -> tuple[Any, Any, np.ndarray, list[tuple[jax.Array, int]]]:
    """`DEATHS` game-over steps from the trajectory's states: the player killed (health and
    recovery at 0, so the step cannot heal them), and the world Craftax's auto-reset env starts
    when a step with the key our env would draw there, `fold_in(episode key, step)`, ends the
    game. Returns the states before the step, the new worlds, the actions, and each death's
    (episode key, step)."""
    dying, worlds, taken, keys = [], [], [], []
    for index in np.linspace(0, len(actions) - 1, DEATHS).astype(int):
        state = jax.tree.map(lambda leaf, index=index: leaf[index], previous)
        state = state.replace(
            player_health=state.player_health * 0, player_recover=state.player_recover * 0
        )
        episode = jnp.asarray(np.array([seed, 0xDEAD], np.uint32))
        dying.append(state)
        worlds.append(_new_world(variant)(jax.random.fold_in(episode, index), state))
        taken.append(int(actions[index]))
        keys.append((episode, int(index)))
    stack = lambda states: jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)  # noqa: E731
    return stack(dying), stack(worlds), np.asarray(taken, np.int32), keys


_SQUARE_BLOCKS = ("CRAFTING_TABLE", "FURNACE", "STONE", "PLANT")


def _with_squares(
    previous: Any, new: Any, variant: Variant, seed: int, share: float = 1 / 3
) -> tuple[Any, Any]:
    """The steps with a filled square of a placeable block stamped near the player on a third
    of them, its border cleared to grass (one border cell left as the block now and then):
    placing whole squares is too rare in random play for the square checks to ever succeed. The
    square stands before and after the step, as built blocks do, so the conditional checks,
    which want the blocks placed the step before the item's count falls, see them too."""
    from craftax.craftax.constants import BlockType as FullBlock
    from craftax.craftax_classic.constants import BlockType as ClassicBlock

    blocks = ClassicBlock if variant is Variant.CLASSIC else FullBlock
    rng = np.random.default_rng(seed)
    before, after = np.array(previous.map), np.array(new.map)
    overworlds = [maps if variant is Variant.CLASSIC else maps[:, 0] for maps in (before, after)]
    positions = np.asarray(new.player_position)
    size = overworlds[0].shape[-1]
    for step in range(len(positions)):
        if rng.random() > share:
            continue
        side = int(rng.integers(2, 5))
        block = blocks[_SQUARE_BLOCKS[rng.integers(len(_SQUARE_BLOCKS))]].value
        row, column = np.clip(positions[step] + rng.integers(-6, 5, 2), 1, size - side - 1)
        stray = int(rng.integers(side)) if rng.random() < 0.25 else None
        for overworld in overworlds:
            overworld[step, row - 1 : row + side + 1, column - 1 : column + side + 1] = (
                blocks.GRASS.value
            )
            overworld[step, row : row + side, column : column + side] = block
            if stray is not None:
                overworld[step, row - 1, column + stray] = block
    return previous.replace(map=jnp.asarray(before)), new.replace(map=jnp.asarray(after))


def test_every_medium_and_hard_goal_scores_like_the_official_checker(
    official: Any, official_repository: Path, classic_env: Any, full_env: Any
) -> None:
    dataset = load_dataset(official_repository)
    # split/kind (and "game over") -> [pairs, official successes, disagreements]
    report: dict[str, list[int]] = {}
    disagreements: list[str] = []
    deaths: dict[Variant, list[Any]] = {}
    # (split, kind, official verdict) -> a goal's task, the state it died in, (episode key, step)
    env_checks: dict[tuple[str, str, bool], tuple[Any, Any, tuple[jax.Array, int]]] = {}
    for split, (module_name, variable) in _SPLIT_MODULES.items():
        variant = Variant.FULL if split.startswith("hard") else Variant.CLASSIC
        states_module = official.import_module(
            "craftext.environment.states.state"
            if variant is Variant.FULL
            else "craftext.environment.states.state_classic"
        )
        game_data = (
            states_module.GameData if variant is Variant.FULL else states_module.GameDataClassic
        )
        module = official.import_module(f"craftext.dataset.scenarious.SMALL.{module_name}")
        entries = getattr(module, variable)
        goals = dataset.split(split)
        assert [goal.id for goal in goals] == list(entries)
        tasks = encode_goals(goals, variant)
        trajectories = _trajectories(variant)
        if variant not in deaths:
            found = [
                _deaths(variant, previous, actions, seed)
                for seed, (previous, _, actions) in enumerate(trajectories)
            ]
            # New worlds hold no square either: the same deaths with one stamped around the new
            # spawn (and in the map before, as built blocks stand), for the checkers only (our
            # env makes its own world). Every death, a few times over: a square must match a
            # goal's block and size.
            stamped = [
                (*_with_squares(dying, worlds, variant, 100 * copy + seed, share=1), actions, None)
                for copy in range(3)
                for seed, (dying, worlds, actions, _) in enumerate(found)
            ]
            deaths[variant] = found + stamped
        ours = _our_checker(variant)
        for row, goal in enumerate(goals):
            entry = entries[goal.id]
            checker_id = int(entry["scenario_checker"])
            file, function, field = _OFFICIAL_CHECKERS[checker_id]
            checker = getattr(
                official.import_module(f"craftext.environment.scenarious.checkers.{file}"), function
            )
            target = getattr(entry["arguments"], field)
            theirs = _official_scorer(checker, game_data)
            counts = report.setdefault(f"{split}/{goal.kind}", [0, 0, 0])
            for previous, new, actions in trajectories:
                expected = np.asarray(theirs(previous, new, jnp.asarray(actions), target))
                got = np.asarray(
                    ours(
                        previous,
                        new,
                        jnp.int32(tasks.kind[row]),
                        jnp.asarray(tasks.required[row]),
                        jnp.asarray(tasks.forbidden[row]),
                        jnp.asarray(tasks.params[row]),
                    )
                )
                counts[0] += len(expected)
                counts[1] += int(np.sum(expected))
                differ = int(np.sum(expected != got))
                counts[2] += differ
                if differ:
                    disagreements.append(f"{split} {goal.id}: {differ} steps")
            game_over = report.setdefault(f"{split}/{goal.kind} game over", [0, 0, 0])
            task = make_task(
                tasks.required[row], tasks.forbidden[row], tasks.kind[row], tasks.params[row]
            )
            for dying, worlds, actions, keys in deaths[variant]:
                expected = np.asarray(theirs(dying, worlds, jnp.asarray(actions), target))
                got = np.asarray(
                    ours(dying, worlds, task.kind, task.required, task.forbidden, task.params)
                )
                game_over[0] += len(expected)
                game_over[1] += int(np.sum(expected))
                differ = int(np.sum(expected != got))
                game_over[2] += differ
                if differ:
                    disagreements.append(f"{split} {goal.id}: {differ} game-over steps")
                for death, verdict in enumerate(expected):
                    if keys is not None and (split, goal.kind, bool(verdict)) not in env_checks:
                        state = jax.tree.map(lambda leaf, d=death: leaf[d], dying)
                        env_checks[split, goal.kind, bool(verdict)] = (task, state, keys[death])
    print("\nsteps scored by both, official successes among them, disagreements:")
    for name, (pairs, successes, differ) in report.items():
        print(f"  {name}: {pairs} pairs, {successes} successes, {differ} disagreements")
    totals = [sum(counts[i] for counts in report.values()) for i in range(3)]
    print(f"  all: {totals[0]} pairs, {totals[1]} successes, {totals[2]} disagreements")
    assert not disagreements, disagreements
    # The trajectories reach success for every kind of every split: agreeing only on "no" would
    # prove little. In the new world too, for every kind a new world can meet (nothing is
    # unlocked there, so no achievements goal).
    assert {name.split("/")[1] for name in report} == set(GOAL_KINDS) | {
        f"{kind} game over" for kind in GOAL_KINDS
    }, report
    assert all(
        successes
        for name, (_, successes, _) in report.items()
        if name != f"{name.split('/')[0]}/achievements game over"
    ), report
    # The env's own step on those game-over steps says what the official wrapper says.
    print(f"  the env's step on {len(env_checks)} of them (a goal of each split and kind)")
    for (split, kind, verdict), (task, dying, (episode, step)) in env_checks.items():
        compiled = full_env if split.startswith("hard") else classic_env
        state = EpisodeState(
            game=dying,
            task=task,
            episode_key=episode,
            steps=jnp.int32(step),
            termination=jnp.int32(Termination.RUNNING),
        )
        _, info = compiled.step(state, jnp.int32(0))
        assert bool(info.done), (split, kind)
        assert bool(info.goal_in_new_world) == verdict, (split, kind, verdict)
