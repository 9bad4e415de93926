"""Whole episodes that end in game over, scored by the official CrafText wrapper (1c518ae, run
unmodified through `benchmarks.official_wrapper`) and by our env under the `official` rule.

The recorded case (`../shared/data/gameover_case.jsonl`: a Medium localization-placing episode
whose player dies at step 277) is replayed step by step beside the real wrapper and its real
auto-reset inner env: the worlds both check and the verdicts agree at every step.

Each world's player is killed on purpose (health and recovery set to 0) at a chosen step, in
Craftax's default parameters, after a stocked inventory and random play: on that step the
official wrapper checks the goal on the world Craftax's auto-reset env starts. Every goal of
Medium's train split (achievements, conditional placing, localization, line, square) and of
Hard's (star too) must end the same way in both, at the same step, and official successes must
fall on game-over steps for every kind a fresh world can meet, so the case is exercised, not only agreed on as "no".
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.official_wrapper import (
    Harness,
    compare,
    official_modules,
    read_case,
    replay_case,
    world_keys,
)
from env.goals import GOAL_KINDS
from env.termination import Termination
from env.variant import Variant

STEPS = 24
#: The step (0-based) before which each world's player is killed.
KILLS = (0, 9, 20)


def _stocked(game: Any) -> Any:
    """A start with items to place and spend, so conditional goals can be met as the game ends."""
    level = jnp.int32(9)
    return game.replace(
        inventory=game.inventory.replace(wood=level, stone=level, sapling=level, coal=level)
    )


# The kinds whose goals these worlds meet on the game-over step: never achievements (nothing is
# unlocked in a new world) nor squares (a fresh world holds no square of placed blocks;
# tests/test_scenario_differential stamps them into new worlds for the checkers); Hard's few
# localization goals find no fresh full-Craftax spawn that meets them here.
@pytest.mark.slow
@pytest.mark.parametrize(
    ("split", "variant", "kinds", "met_at_game_over"),
    [
        (
            "medium_train",
            Variant.CLASSIC,
            set(GOAL_KINDS) - {"build_star"},
            {"conditional_placing", "localization_placing", "build_line"},
        ),
        (
            "hard_train",
            Variant.FULL,
            set(GOAL_KINDS) - {"achievements"},
            {"conditional_placing", "build_line", "build_star"},
        ),
    ],
)
def test_game_over_steps_score_like_the_official_wrapper(
    official_repository: Path,
    split: str,
    variant: Variant,
    kinds: set[str],
    met_at_game_over: set[str],
) -> None:
    official = official_modules(official_repository)
    harness = Harness(official, variant, STEPS)
    keys = world_keys(len(KILLS), len(KILLS))
    rng = np.random.default_rng(len(split))
    actions = [rng.integers(variant.num_actions, size=STEPS) for _ in keys]
    starts = [_stocked(harness.start(key)) for key in keys]
    tallies, differences = compare(
        harness, official, official_repository, [split], keys, actions, starts, list(KILLS)
    )
    print({name: vars(tally) for name, tally in tallies.items()})
    assert not differences, differences
    assert {name.split("/")[1] for name in tallies} == kinds
    game_over = {name.split("/")[1] for name, t in tallies.items() if t.game_over_successes}
    assert game_over == met_at_game_over, tallies


CASE_GOAL = ("medium_train", "INSTRUCTION_PLACE_STONE_IRON_2_2")


@pytest.mark.slow
def test_the_recorded_game_over_case_agrees_at_every_step(
    official_repository: Path, shared_data: Path
) -> None:
    case = read_case(shared_data / "gameover_case.jsonl")
    steps = replay_case(
        official_modules(official_repository), official_repository, case, *CASE_GOAL
    )
    assert [step for step in steps if not step.agrees] == []
    *before, last = steps
    assert last.step == case.game_over_step
    assert last.game_over and not any(step.game_over for step in before)
    # The new world around its spawn has no stone two tiles above an iron: no success on either side.
    assert (last.official_ended, last.official_met, last.ours) == (True, False, Termination.DEATH)


@pytest.mark.slow
def test_stepping_the_game_with_the_whole_key_checks_another_new_world(
    official_repository: Path, shared_data: Path
) -> None:
    """How the case disagreed before: with the game stepped on the half of the key the wrapper's
    game steps with, the games agree until the game over, and then our env checks a world made
    from a key the wrapper never resets from, where the goal happens to be met."""
    case = read_case(shared_data / "gameover_case.jsonl")
    steps = replay_case(
        official_modules(official_repository), official_repository, case, *CASE_GOAL, "whole"
    )
    *before, last = steps
    assert all(step.agrees for step in before)
    assert last.step == case.game_over_step and last.game_over
    assert not last.games_equal
    assert (last.official_met, last.ours) == (False, Termination.SUCCESS)


@pytest.mark.parametrize("mistake", ["not the official tree", "not a case file"])
def test_a_mistake_in_the_arguments_is_one_line_and_exit_2(
    official_repository: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    mistake: str,
) -> None:
    from benchmarks.official_wrapper import main

    case = tmp_path / "case.jsonl"
    case.write_text('{"world_key": [1, 2]}\n')
    arguments = {
        "not the official tree": ["--dataset", str(tmp_path)],
        "not a case file": ["--dataset", str(official_repository), "--case", str(case)],
    }[mistake]
    with pytest.raises(SystemExit) as exited:
        main(arguments)
    assert exited.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert len(captured.err.splitlines()) == 1 and captured.err.startswith("error: ")
