"""Wilson intervals against scipy, and run summaries over episode lists with known counts."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import binomtest

from env.errors import UserError
from llm_agents.run_data.metrics import (
    action_counts,
    action_histogram,
    clustered_rate,
    summarize,
    wilson_interval,
)
from llm_agents.run_data.records import EpisodeRecord, StepRecord


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
    computed_prompt_tokens: int | None = None,
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
            "computed_prompt_tokens": computed_prompt_tokens,
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
    # One goal alone: its episodes are independent worlds, the plain Wilson interval.
    for category in ("combo", "new_objects"):
        rate = summary.by_category[category]
        assert rate.clusters == 1
        assert (rate.low, rate.high) == pytest.approx(scipy_wilson(rate.successes, rate.episodes))
    # `one` pools a goal met every time with one never met: wider than if episodes were free.
    one = summary.by_category["one"]
    assert one.clusters == 2 and one.design_effect is not None and one.design_effect > 1
    plain = scipy_wilson(3, 10)
    assert one.low < plain[0] and one.high > plain[1]
    assert (summary.overall.successes, summary.overall.episodes) == (4, 19)
    assert summary.overall.clusters == 4

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


def test_one_id_in_two_splits_is_two_goals() -> None:
    # Medium's INSTRUCTION_STONE_4 is a square in train and a line in the paraphrased split.
    episodes = [
        episode(0, category="train", goal="INSTRUCTION_STONE_4", success=True),
        episode(1, category="paraphrased", goal="INSTRUCTION_STONE_4"),
    ]
    rates = {goal: (r.successes, r.episodes) for goal, r in summarize(episodes).by_goal.items()}
    assert rates == {"paraphrased/INSTRUCTION_STONE_4": (0, 1), "train/INSTRUCTION_STONE_4": (1, 1)}


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


def test_the_computed_share_pools_prompt_tokens_and_needs_every_episodes_count() -> None:
    counted = [
        episode(0, prompt_tokens=1000, computed_prompt_tokens=100),
        episode(1, prompt_tokens=3000, computed_prompt_tokens=900),
    ]
    # Pooled over tokens (1000 of 4000), not the mean of per-episode shares (0.2).
    assert summarize(counted).computed_prompt_share == pytest.approx(0.25)
    # An episode whose backend did not say makes the share unknown, not smaller.
    assert summarize([*counted, episode(2, prompt_tokens=500)]).computed_prompt_share is None


def test_summary_of_nothing_is_a_user_error() -> None:
    with pytest.raises(UserError, match="no finished episodes"):
        summarize([])


@given(st.lists(st.booleans(), min_size=1, max_size=60))
def test_one_trial_per_goal_is_the_plain_wilson_interval(outcomes: list[bool]) -> None:
    rate = clustered_rate((f"goal{i}", int(ok), 1) for i, ok in enumerate(outcomes))
    assert (rate.low, rate.high) == pytest.approx(
        scipy_wilson(sum(outcomes), len(outcomes)), abs=1e-9
    )
    assert rate.clusters == len(outcomes)


@pytest.mark.parametrize(("met", "goals", "worlds"), [(3, 10, 50), (1, 4, 6), (7, 9, 2)])
def test_goals_met_all_or_nothing_count_once_each(met: int, goals: int, worlds: int) -> None:
    """Under the paper protocol a goal is played in 50 worlds; when each goal is met in all of
    them or in none, the run knows `goals` outcomes, not `goals * worlds`."""
    rate = clustered_rate({f"g{i}": (worlds if i < met else 0, worlds) for i in range(goals)})
    assert (rate.successes, rate.episodes) == (met * worlds, goals * worlds)
    assert rate.design_effect == pytest.approx(worlds)
    assert (rate.low, rate.high) == pytest.approx(scipy_wilson(met, goals), abs=1e-9)


def test_goals_alike_leave_the_interval_as_it_was() -> None:
    rate = clustered_rate({f"g{i}": (5, 10) for i in range(8)})
    assert rate.design_effect == 1.0
    assert (rate.low, rate.high) == pytest.approx(scipy_wilson(40, 80))


def test_the_same_goal_given_twice_adds_up_and_bad_counts_are_refused() -> None:
    twice = clustered_rate([("a", 1, 2), ("b", 0, 2), ("a", 1, 2)])
    once = clustered_rate({"a": (2, 4), "b": (0, 2)})
    assert twice == once
    with pytest.raises(ValueError):
        clustered_rate({"a": (3, 2)})
    with pytest.raises(ValueError):
        clustered_rate({})


def step(episode_id: str, action: str, index: int) -> StepRecord:
    return StepRecord(
        episode_id=episode_id,
        step=index,
        observation="",
        prompt_hash="",
        raw_output=action,
        action_name=action,
        action_id=0,
        parse_stage="choice",
        fallback_used=False,
        reward=0.0,
        done=False,
    )


def test_action_histograms_per_episode_and_pooled_over_the_run() -> None:
    steps = [
        *(step("ep0", "DO", i) for i in range(9)),
        step("ep0", "NOOP", 9),
        *(step("ep1", "LEFT", i) for i in range(3)),
        step("ep1", "DO", 3),
        step("elsewhere", "UP", 0),
    ]
    counts = action_counts(steps)
    assert counts["ep0"] == {"DO": 9, "NOOP": 1}
    first = action_histogram(counts["ep0"])
    assert (first.commonest, first.commonest_share, first.steps) == ("DO", 0.9, 10)
    assert first.dominated
    summary = summarize([episode(0), episode(1)], counts)
    assert summary.actions is not None
    assert summary.actions.counts == {"DO": 10, "LEFT": 3, "NOOP": 1}  # commonest first
    assert summary.actions.commonest_share == pytest.approx(10 / 14)
    assert not summary.actions.dominated
    assert summarize([episode(0)]).actions is None
    assert action_histogram({}).commonest is None
