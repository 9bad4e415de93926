"""Wilson intervals against scipy, and run summaries over episode lists with known counts."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import binomtest

from env.errors import UserError
from llm_agents.run_data.metrics import summarize, wilson_interval
from llm_agents.run_data.records import EpisodeRecord


def episode(
    index: int,
    *,
    category: str = "one",
    goal: str = "goal-a",
    success: bool = False,
    termination: str | None = None,
    steps: int = 10,
    invalid: int = 0,
    prompt_tokens: int = 0,
    completion_tokens: int = 0,
) -> EpisodeRecord:
    return EpisodeRecord.model_validate(
        {
            "episode_id": f"ep{index}",
            "goal_id": goal,
            "instruction": "collect wood",
            "instruction_variant": 1 if category == "paraphrased" else 0,
            "category": category,
            "seed": 100 + index,
            "episode_index": index,
            "success": success,
            "steps": steps,
            "termination": termination or ("success" if success else "timeout"),
            "episode_return": 1.0 if success else 0.0,
            "invalid_actions": invalid,
            "prompt_tokens": prompt_tokens,
            "completion_tokens": completion_tokens,
        }
    )


def scipy_wilson(k: int, n: int) -> tuple[float, float]:
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return ci.low, ci.high


@pytest.mark.parametrize(
    ("k", "n"),
    [(0, 1), (1, 1), (0, 10), (10, 10), (3, 10), (1, 100), (50, 100), (0, 500), (7, 23)],
)
def test_wilson_matches_scipy(k: int, n: int) -> None:
    assert wilson_interval(k, n) == pytest.approx(scipy_wilson(k, n), abs=1e-12)


@given(st.integers(1, 2000).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))))
def test_wilson_matches_scipy_everywhere(case: tuple[int, int]) -> None:
    k, n = case
    low, high = wilson_interval(k, n)
    assert (low, high) == pytest.approx(scipy_wilson(k, n), abs=1e-12)
    assert 0.0 <= low <= k / n <= high <= 1.0


def test_wilson_extremes_touch_the_bounds() -> None:
    assert wilson_interval(0, 7)[0] == 0.0
    assert wilson_interval(7, 7)[1] == 1.0
    assert wilson_interval(0, 7)[1] > 0.0
    assert wilson_interval(7, 7)[0] < 1.0


def test_wilson_narrows_with_more_trials_and_lower_confidence() -> None:
    low_small, high_small = wilson_interval(3, 10)
    low_big, high_big = wilson_interval(300, 1000)
    assert high_big - low_big < high_small - low_small
    low_90, high_90 = wilson_interval(3, 10, confidence=0.90)
    assert low_small < low_90 and high_90 < high_small


@pytest.mark.parametrize(("k", "n"), [(0, 0), (-1, 5), (6, 5)])
def test_wilson_rejects_impossible_counts(k: int, n: int) -> None:
    with pytest.raises(ValueError):
        wilson_interval(k, n)


def test_summary_counts_per_category_goal_and_termination() -> None:
    counter = itertools.count()
    episodes = [
        # one: 3 of 10 succeed, at 10, 20 and 60 steps.
        *(
            episode(next(counter), category="one", goal="wood", success=True, steps=s)
            for s in (10, 20, 60)
        ),
        *(
            episode(next(counter), category="one", goal="table", termination="death", steps=5)
            for _ in range(2)
        ),
        *(episode(next(counter), category="one", goal="table", steps=100) for _ in range(5)),
        # combo: 1 of 4.
        episode(next(counter), category="combo", goal="wood+table", success=True, steps=40),
        *(episode(next(counter), category="combo", goal="wood+table", steps=100) for _ in range(3)),
        # new_objects: 0 of 5.
        *(
            episode(
                next(counter), category="new_objects", goal="lava", termination="death", steps=7
            )
            for _ in range(5)
        ),
    ]
    summary = summarize(episodes)

    assert list(summary.by_category) == ["one", "combo", "new_objects"]
    expected = {"one": (3, 10), "combo": (1, 4), "new_objects": (0, 5)}
    for category, (k, n) in expected.items():
        rate = summary.by_category[category]
        assert (rate.successes, rate.episodes) == (k, n)
        assert rate.rate == pytest.approx(k / n)
        assert (rate.low, rate.high) == pytest.approx(scipy_wilson(k, n), abs=1e-12)
    assert (summary.overall.successes, summary.overall.episodes) == (4, 19)
    assert (summary.overall.low, summary.overall.high) == pytest.approx(scipy_wilson(4, 19))

    goals = {goal: (r.successes, r.episodes) for goal, r in summary.by_goal.items()}
    assert goals == {
        "one/wood": (3, 3),
        "one/table": (0, 7),
        "combo/wood+table": (1, 4),
        "new_objects/lava": (0, 5),
    }
    assert summary.terminations == {"success": 4, "death": 7, "timeout": 8}
    assert summary.steps_to_success_mean == pytest.approx(32.5)
    assert summary.steps_to_success_median == pytest.approx(30.0)


def test_goals_of_one_id_in_different_splits_are_counted_apart() -> None:
    # Medium's train and test splits both number their goals from 0, say.
    episodes = [
        episode(0, category="train", goal="0", success=True),
        episode(1, category="paraphrased", goal="0"),
        episode(2, category="paraphrased", goal="0"),
    ]
    rates = summarize(episodes).by_goal
    assert {key: (r.successes, r.episodes) for key, r in rates.items()} == {
        "train/0": (1, 1),
        "paraphrased/0": (0, 2),
    }


def test_summary_rates_are_per_step_over_the_whole_run() -> None:
    episodes = [
        episode(0, steps=10, invalid=5, prompt_tokens=1000, completion_tokens=100),
        episode(1, steps=30, invalid=1, prompt_tokens=3000, completion_tokens=700),
    ]
    summary = summarize(episodes)
    # Pooled over steps, not the mean of per-episode rates (which would be 0.2667).
    assert summary.invalid_action_rate == pytest.approx(6 / 40)
    assert summary.prompt_tokens_per_step == pytest.approx(100.0)
    assert summary.completion_tokens_per_step == pytest.approx(20.0)
    assert summary.steps_to_success_mean is None
    assert summary.steps_to_success_median is None
    assert summary.terminations == {"success": 0, "death": 0, "timeout": 2}


def test_summary_of_nothing_is_a_user_error() -> None:
    with pytest.raises(UserError, match="no finished episodes"):
        summarize([])
