"""Run metrics: success rates with Wilson intervals, terminations, invalid actions, cost.

Success rates come with Wilson score intervals rather than normal-approximation ones because
runs are small and rates near 0 are common, where the normal interval collapses to a point or
leaves [0, 1].
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, defaultdict
from collections.abc import Sequence

from pydantic import BaseModel, Field

from env.errors import UserError
from env.goals import ALL_CATEGORIES, SCENARIO_CLASSES
from env.termination import TERMINATIONS
from llm_agents.run_data.records import NOT_STARTED, EpisodeRecord

__all__ = ["SuccessRate", "Summary", "Understanding", "goal_key", "summarize", "wilson_interval"]


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion of `successes` out of `trials`."""
    if trials <= 0:
        raise ValueError(f"trials must be positive, got {trials}")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must lie in [0, {trials}], got {successes}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    z = statistics.NormalDist().inv_cdf(0.5 + confidence / 2)
    p = successes / trials
    z2_n = z * z / trials
    centre = (p + z2_n / 2) / (1 + z2_n)
    half_width = z / (1 + z2_n) * math.sqrt(p * (1 - p) / trials + z2_n / (4 * trials))
    # At k = 0 (k = n) the bound is exactly 0 (1) in theory; rounding leaves a hair off it.
    low = 0.0 if successes == 0 else max(0.0, centre - half_width)
    high = 1.0 if successes == trials else min(1.0, centre + half_width)
    return low, high


class SuccessRate(BaseModel):
    """Successes out of episodes, with a 95% Wilson interval."""

    successes: int = Field(ge=0)
    """Episodes whose goal was met."""
    episodes: int = Field(ge=1)
    """Episodes counted."""
    rate: float = Field(ge=0.0, le=1.0)
    """successes / episodes."""
    low: float = Field(ge=0.0, le=1.0)
    """Lower bound of the 95% Wilson interval."""
    high: float = Field(ge=0.0, le=1.0)
    """Upper bound of the 95% Wilson interval."""

    @classmethod
    def of(cls, successes: int, episodes: int) -> SuccessRate:
        low, high = wilson_interval(successes, episodes)
        return cls(
            successes=successes, episodes=episodes, rate=successes / episodes, low=low, high=high
        )


class Understanding(BaseModel):
    """How the goals an agent read before playing (`guided`) compare with the dataset's, and
    what its success owed to reading them right."""

    grounded: SuccessRate
    """Episodes whose goal was read exactly right, out of every episode with a grounding."""
    not_started: int = Field(ge=0)
    """Episodes that could not start: the answer was not a well-formed goal."""
    success_when_right: SuccessRate | None
    """Success of the episodes whose goal was read right; None without any."""
    success_when_wrong: SuccessRate | None
    """Success of the episodes played on a wrong (but well-formed) goal; None without any."""


def understanding(episodes: Sequence[EpisodeRecord]) -> Understanding | None:
    """Understanding over the episodes that carry a grounding; None when none does."""
    grounded = [e for e in episodes if e.grounding is not None]
    if not grounded:
        return None
    right = [e.success for e in grounded if e.grounding_correct]
    wrong = [
        e.success for e in grounded if not e.grounding_correct and e.termination != NOT_STARTED
    ]
    return Understanding(
        grounded=SuccessRate.of(len(right), len(grounded)),
        not_started=sum(e.termination == NOT_STARTED for e in grounded),
        success_when_right=SuccessRate.of(sum(right), len(right)) if right else None,
        success_when_wrong=SuccessRate.of(sum(wrong), len(wrong)) if wrong else None,
    )


class Summary(BaseModel):
    """Metrics over a set of finished episodes."""

    overall: SuccessRate
    """Success over every episode."""
    by_category: dict[str, SuccessRate]
    """Success per goal category present (`one`, `combo`, `new_objects`, `paraphrased`)."""
    by_scenario: dict[str, dict[str, SuccessRate]] = {}
    """Success per scenario class present, then per category present (the paper's Table 2:
    `Build` -> `train` -> rate)."""
    by_goal: dict[str, SuccessRate]
    """Success per goal, keyed `category/goal_id`: ids repeat across splits (a test split's
    goal can share its id with a training goal), and a category lies within one split."""
    terminations: dict[str, int]
    """Episodes per termination reason (`success`, `death`, `timeout`), zeros included, and
    `not_started` when some episode could not start."""
    invalid_action_rate: float = Field(ge=0.0, le=1.0)
    """Share of all steps whose action was the fallback because none could be parsed."""
    steps_to_success_mean: float | None
    """Mean steps of successful episodes; None without successes."""
    steps_to_success_median: float | None
    """Median steps of successful episodes; None without successes."""
    prompt_tokens_per_step: float = Field(ge=0.0)
    """Prompt tokens per agent step, over all episodes."""
    completion_tokens_per_step: float = Field(ge=0.0)
    """Generated tokens (reasoning included) per agent step, over all episodes."""
    understanding: Understanding | None = None
    """The goals read before playing against the dataset's (`guided`); None for other agents."""


def _success_rates(groups: dict[str, list[bool]]) -> dict[str, SuccessRate]:
    return {key: SuccessRate.of(sum(outcomes), len(outcomes)) for key, outcomes in groups.items()}


def goal_key(episode: EpisodeRecord) -> str:
    """The key of an episode's goal among a run's (`Summary.by_goal`): its category and id."""
    return f"{episode.category}/{episode.goal_id}"


def summarize(episodes: Sequence[EpisodeRecord]) -> Summary:
    """Metrics over `episodes`; raises `UserError` when there are none."""
    if not episodes:
        raise UserError("no finished episodes to summarize")
    by_category: dict[str, list[bool]] = defaultdict(list)
    by_scenario: dict[str, dict[str, list[bool]]] = defaultdict(lambda: defaultdict(list))
    by_goal: dict[str, list[bool]] = defaultdict(list)
    for episode in episodes:
        by_category[episode.category].append(episode.success)
        by_scenario[episode.scenario_class][episode.category].append(episode.success)
        by_goal[goal_key(episode)].append(episode.success)
    terminations = Counter(episode.termination for episode in episodes)
    success_steps = [episode.steps for episode in episodes if episode.success]
    total_steps = sum(episode.steps for episode in episodes)

    def per_step(total: int) -> float:
        return total / total_steps if total_steps else 0.0

    return Summary(
        overall=SuccessRate.of(len(success_steps), len(episodes)),
        by_category=_success_rates(
            {
                category: by_category[category]
                for category in ALL_CATEGORIES
                if category in by_category
            }
        ),
        by_scenario={
            scenario: _success_rates(
                {c: per_category[c] for c in ALL_CATEGORIES if c in per_category}
            )
            for scenario in SCENARIO_CLASSES
            if (per_category := by_scenario.get(scenario))
        },
        by_goal=_success_rates(dict(sorted(by_goal.items()))),
        terminations={reason: terminations[reason] for reason in TERMINATIONS}
        | ({NOT_STARTED: terminations[NOT_STARTED]} if terminations[NOT_STARTED] else {}),
        invalid_action_rate=per_step(sum(episode.invalid_actions for episode in episodes)),
        steps_to_success_mean=statistics.fmean(success_steps) if success_steps else None,
        steps_to_success_median=statistics.median(success_steps) if success_steps else None,
        prompt_tokens_per_step=per_step(sum(episode.prompt_tokens for episode in episodes)),
        completion_tokens_per_step=per_step(sum(episode.completion_tokens for episode in episodes)),
        understanding=understanding(episodes),
    )
