"""Our success checker against the official CrafText rule, re-implemented here from its
description, over generated achievement sequences, under both success rules.

The official EASY rule (AIRI-Institute/CrafText at 1c518ae): after every step the wrapper checks
the goal (every required achievement unlocked, no forbidden one) on the state the Craftax env
returned. That env resets itself when the game ends, so on the game-over step the checked state
is a fresh one with nothing unlocked: a goal completed on that step is not a success. The loop's
own step cap is no game end. `game_over_counts` is the same rule checked on the state before the
reset.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from env import (
    ACHIEVEMENTS,
    NUM_ACHIEVEMENTS,
    CrafTextEnv,
    EnvConfig,
    Termination,
    Variant,
    shared_env,
)
from env.checker import goal_reached, scored_success
from env.rules import SUCCESS_RULES

NOOP = 0
MAX_STEPS = 6


def official_outcome(
    new_per_step: list[frozenset[str]],
    required: frozenset[str],
    forbidden: frozenset[str],
    game_over_step: int | None,
    max_steps: int,
    rule: str,
) -> tuple[str, int, bool]:
    """(termination, steps, goal met on the game-over step) of one episode, by the rule."""
    unlocked: set[str] = set()
    for step, new in enumerate(new_per_step[:max_steps], start=1):
        unlocked |= new
        game_over = step == game_over_step
        met = required <= unlocked and not forbidden & unlocked
        # The official wrapper sees the auto-reset state on the game-over step.
        checked = set() if game_over and rule == "official" else unlocked
        if required <= checked and not forbidden & checked:
            return "success", step, met and game_over
        if game_over:
            return "death", step, met
        if step == max_steps:
            return "timeout", step, False
    raise AssertionError("sequences are generated to end by the step cap")


_NAMES = st.sampled_from(ACHIEVEMENTS)


@st.composite
def episodes(draw: Any) -> tuple[list[frozenset[str]], frozenset[str], frozenset[str], int | None]:
    """A goal and a sequence of unlocks, often completing the goal, sometimes as the player dies."""
    required = frozenset(draw(st.lists(_NAMES, min_size=1, max_size=3)))
    forbidden = frozenset(draw(st.lists(_NAMES, max_size=2))) - required
    steps = [frozenset(draw(st.lists(_NAMES, max_size=2))) for _ in range(MAX_STEPS)]
    if draw(st.booleans()):
        # Complete the goal on a chosen step, the interesting case.
        at = draw(st.integers(0, MAX_STEPS - 1))
        steps[at] = steps[at] | required
    game_over_step = draw(st.one_of(st.none(), st.integers(1, MAX_STEPS)))
    if game_over_step is not None and draw(st.booleans()):
        # The goal is completed on the very step the game ends.
        steps[game_over_step - 1] = steps[game_over_step - 1] | required
        steps = [s - required if i < game_over_step - 1 else s for i, s in enumerate(steps)]
    return steps, required, forbidden, game_over_step


def _mask(names: frozenset[str]) -> np.ndarray:
    mask = np.zeros(NUM_ACHIEVEMENTS, bool)
    mask[[ACHIEVEMENTS.index(name) for name in names]] = True
    return mask


def our_checker_outcome(
    new_per_step: list[frozenset[str]],
    required: frozenset[str],
    forbidden: frozenset[str],
    game_over_step: int | None,
    rule: Any,
) -> tuple[str, int, bool]:
    """The same episode through our `scored_success`, stepping until success or game over."""
    unlocked = np.zeros(NUM_ACHIEVEMENTS, bool)
    for step, new in enumerate(new_per_step, start=1):
        unlocked = unlocked | _mask(new)
        ended = step == game_over_step
        reached, in_new_world = (
            goal_reached(
                jnp.asarray(checked), jnp.asarray(_mask(required)), jnp.asarray(_mask(forbidden))
            )
            for checked in (unlocked, np.zeros(NUM_ACHIEVEMENTS, bool))
        )
        success = scored_success(reached, in_new_world, jnp.asarray(ended), rule)
        at_game_over = bool(reached) and ended
        if bool(success):
            return "success", step, at_game_over
        if ended:
            return "death", step, at_game_over
        if step == MAX_STEPS:
            return "timeout", step, False
    raise AssertionError("unreachable")


@pytest.mark.parametrize("rule", SUCCESS_RULES)
@settings(max_examples=300, deadline=None)
@given(episode=episodes())
def test_our_checker_scores_like_the_official_rule(rule: str, episode: Any) -> None:
    steps, required, forbidden, game_over_step = episode
    assert our_checker_outcome(steps, required, forbidden, game_over_step, rule) == (
        official_outcome(steps, required, forbidden, game_over_step, MAX_STEPS, rule)
    )


def test_the_rules_differ_exactly_on_the_game_over_step() -> None:
    wake_up = frozenset({"WAKE_UP"})
    # "Please wake up.": a zombie's blow wakes the sleeping player and kills them in one step.
    steps = [frozenset()] * 2 + [wake_up] + [frozenset()] * 3
    assert official_outcome(steps, wake_up, frozenset(), 3, MAX_STEPS, "official") == (
        "death",
        3,
        True,
    )
    assert official_outcome(steps, wake_up, frozenset(), 3, MAX_STEPS, "game_over_counts") == (
        "success",
        3,
        True,
    )
    # A step earlier, both rules agree.
    earlier = [frozenset(), wake_up, *[frozenset()] * 4]
    for rule in SUCCESS_RULES:
        assert official_outcome(earlier, wake_up, frozenset(), 3, MAX_STEPS, rule) == (
            "success",
            2,
            False,
        )


# --- the same, through the real env: unlocks and death injected into Craftax states ------------


@pytest.fixture(scope="module")
def envs() -> dict[str, Any]:
    built = {}
    for rule in SUCCESS_RULES:
        env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS, success_rule=rule))
        built[rule] = (env, jax.jit(env.step_from_episode_key))
    return built


def env_outcome(env: CrafTextEnv, step: Any, episode: Any) -> tuple[str, int, bool]:
    steps, required, forbidden, game_over_step = episode
    state = env.jitted_reset(jnp.asarray(np.array([0, 7], np.uint32)), _task(required, forbidden))
    for index, new in enumerate(steps, start=1):
        game = state.game
        achievements = np.asarray(game.achievements).copy()
        achievements[:NUM_ACHIEVEMENTS] |= _mask(new)
        game = game.replace(achievements=jnp.asarray(achievements))
        if index == game_over_step:
            game = game.replace(player_health=game.player_health * 0)
        state, info = step(state.replace(game=game), jnp.int32(NOOP))
        if bool(info.done):
            return Termination(int(info.termination)).label, index, bool(info.goal_at_game_over)
    raise AssertionError("the step cap ends every episode")


def _task(required: frozenset[str], forbidden: frozenset[str]) -> Any:
    from env import make_task

    return make_task(_mask(required), _mask(forbidden))


@pytest.mark.slow
@pytest.mark.parametrize("rule", SUCCESS_RULES)
@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(episode=episodes())
def test_the_env_scores_like_the_official_rule(
    rule: str, episode: Any, envs: dict[str, Any]
) -> None:
    env, step = envs[rule]
    assert env_outcome(env, step, episode) == official_outcome(*episode, MAX_STEPS, rule)
