"""Run metrics: success rates with Wilson intervals, terminations, invalid actions, cost, and
which actions were chosen.

Success rates come with Wilson score intervals rather than normal-approximation ones because
runs are small and rates near 0 are common, where the normal interval collapses to a point or
leaves [0, 1].

A rate pooled over goals is clustered: the episodes (or texts) of one goal (its ~6 phrasings,
its worlds) share the goal's difficulty, so they are not independent trials, and a Wilson
interval over them would be too narrow (under the Medium paper protocol one goal counts 50
times). `clustered_rate` is the one place that corrects for it, by the design effect: the
variance of the pooled rate (a ratio estimator) computed from the per-goal residuals
(`sum_g (s_g - p m_g)^2 / n^2`, the cluster-robust "sandwich" variance) over the binomial one
`p (1 - p) / n` gives `deff`, and the interval is the Wilson interval at the effective size
`n / deff` (Korn and Graubard's interval for a proportion from a clustered sample, 1998).
Without the usual `G / (G - 1)` small-sample factor, so that a run of one episode per goal gets
exactly the plain Wilson interval; as Korn and Graubard do, `deff` is at least 1, and 1 when
every trial succeeded or none did (the residuals are then all zero and say nothing), as it is
for one goal alone (its trials are independent worlds). If all of one goal's trials agree and
goals are of equal size, the effective size is the number of goals: each counts once.
Deterministic, no resampling: the same records always give the same interval.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, defaultdict
from collections.abc import Hashable, Iterable, Mapping, Sequence
from typing import Any

from pydantic import BaseModel, Field, computed_field

from env.errors import UserError
from env.goals import ALL_CATEGORIES, SCENARIO_CLASSES
from env.termination import TERMINATIONS
from llm_agents.run_data.records import NOT_STARTED, SKILL_STAGE, EpisodeRecord, StepRecord

__all__ = [
    "CLUSTERED_LABEL",
    "DOMINANT_SHARE",
    "WILSON_LABEL",
    "ActionHistogram",
    "SuccessRate",
    "Summary",
    "Understanding",
    "action_counts",
    "action_histogram",
    "clustered_rate",
    "goal_cluster",
    "goal_key",
    "summarize",
    "wilson_interval",
]

#: How a plain interval is described wherever it is shown.
WILSON_LABEL = "95% Wilson interval"
#: How a clustered interval is described wherever it is shown (see the module docstring).
CLUSTERED_LABEL = "95% Wilson interval clustered by goal (design effect; g=goals)"
#: A run whose commonest action takes more than this share of its steps is flagged.
DOMINANT_SHARE = 0.8


def _wilson(p: float, trials: float, z: float) -> tuple[float, float]:
    z2_n = z * z / trials
    centre = (p + z2_n / 2) / (1 + z2_n)
    half_width = z / (1 + z2_n) * math.sqrt(p * (1 - p) / trials + z2_n / (4 * trials))
    # At p = 0 (p = 1) the bound is exactly 0 (1) in theory; rounding leaves a hair off it.
    low = 0.0 if p == 0 else max(0.0, centre - half_width)
    high = 1.0 if p == 1 else min(1.0, centre + half_width)
    return low, high


def _z(confidence: float) -> float:
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    return statistics.NormalDist().inv_cdf(0.5 + confidence / 2)


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion of `successes` out of `trials`."""
    if trials <= 0:
        raise ValueError(f"trials must be positive, got {trials}")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must lie in [0, {trials}], got {successes}")
    return _wilson(successes / trials, trials, _z(confidence))


class SuccessRate(BaseModel):
    """Successes out of trials (episodes, texts or atoms), with a 95% Wilson interval: plain
    (independent trials), or clustered by goal when `clusters` is set (see the module
    docstring)."""

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
    clusters: int | None = Field(None, ge=1)
    """Goals the trials come from, when the interval is clustered by goal; None: a plain
    Wilson interval over independent trials (rates recorded before clustering, or one goal's)."""
    design_effect: float | None = Field(None, ge=1.0)
    """The variance inflation the clustered interval used (`trials / design_effect` is its
    effective size); None for a plain interval."""

    @classmethod
    def of(cls, successes: int, episodes: int) -> SuccessRate:
        low, high = wilson_interval(successes, episodes)
        return cls(
            successes=successes, episodes=episodes, rate=successes / episodes, low=low, high=high
        )

    # Written to results.json (ignored on reading), so a reader of the file sees which it is.
    @computed_field  # type: ignore[prop-decorator]
    @property
    def label(self) -> str:
        """What kind of interval this is, for the line under a table."""
        return CLUSTERED_LABEL if self.clusters is not None else WILSON_LABEL

    def cell(self) -> str:
        """`rate [low, high] n=trials`, with `g=goals` for a clustered interval."""
        goals = f" g={self.clusters}" if self.clusters is not None else ""
        return f"{self.rate:.2f} [{self.low:.2f}, {self.high:.2f}] n={self.episodes}{goals}"


def clustered_rate(
    clusters: Mapping[Any, tuple[int, int]] | Iterable[tuple[Hashable, int, int]],
    confidence: float = 0.95,
) -> SuccessRate:
    """The pooled rate of per-goal (successes, trials), its Wilson interval at the design
    effect's effective size (the module docstring says how); the one clustered interval of the
    project. `clusters`: goal -> (successes, trials), or (goal, successes, trials) triples (a
    goal given twice adds up)."""
    totals: dict[Hashable, list[int]] = defaultdict(lambda: [0, 0])
    items = (
        clusters.items() if isinstance(clusters, Mapping) else ((k, (s, m)) for k, s, m in clusters)
    )
    for key, (hits, trials) in items:
        if not 0 <= hits <= trials:
            raise ValueError(f"successes must lie in [0, {trials}], got {hits}")
        totals[key][0] += hits
        totals[key][1] += trials
    sizes = [(hits, trials) for hits, trials in totals.values() if trials]
    n = sum(trials for _, trials in sizes)
    if n <= 0:
        raise ValueError("no trials to rate")
    successes = sum(hits for hits, _ in sizes)
    p = successes / n
    deff = 1.0
    if 0 < p < 1:
        clustered = sum((hits - p * trials) ** 2 for hits, trials in sizes) / (n * n)
        deff = max(1.0, clustered / (p * (1 - p) / n))
    low, high = _wilson(p, n / deff, _z(confidence))
    return SuccessRate(
        successes=successes,
        episodes=n,
        rate=p,
        low=low,
        high=high,
        clusters=len(sizes),
        design_effect=deff,
    )


def goal_cluster(episode: EpisodeRecord) -> tuple[str, str]:
    """The goal an episode's outcome is clustered by: its goal set and goal id (ids repeat
    across splits for different goals)."""
    return (episode.category, episode.goal_id)


def _clustered_success(episodes: Iterable[EpisodeRecord]) -> SuccessRate:
    return clustered_rate((goal_cluster(e), int(e.success), 1) for e in episodes)


class ActionHistogram(BaseModel):
    """How often each action (the expert's and guided agents': each primitive action its skills
    chose) was taken over some steps, and the share of the commonest."""

    counts: dict[str, int]
    """Action name -> steps, commonest first (ties by name)."""
    steps: int = Field(ge=0)
    """Steps counted."""
    commonest: str | None
    """The most frequent action; None without steps."""
    commonest_share: float = Field(ge=0.0, le=1.0)
    """Its share of the steps (0 without steps)."""

    @property
    def dominated(self) -> bool:
        """Whether one action takes more than `DOMINANT_SHARE` of the steps."""
        return self.commonest_share > DOMINANT_SHARE


def action_histogram(counts: Mapping[str, int]) -> ActionHistogram:
    """The histogram of `counts` (action name -> steps)."""
    ordered = dict(sorted(((a, c) for a, c in counts.items() if c), key=lambda i: (-i[1], i[0])))
    steps = sum(ordered.values())
    commonest = next(iter(ordered), None)
    return ActionHistogram(
        counts=ordered,
        steps=steps,
        commonest=commonest,
        commonest_share=ordered[commonest] / steps if commonest is not None else 0.0,
    )


def action_counts(steps: Iterable[StepRecord]) -> dict[str, Counter[str]]:
    """Episode id -> action name -> steps, from step records (`store.read_steps`); for the
    `skills` agent, skill -> decisions (the steps a chosen skill carries on count nothing)."""
    counts: dict[str, Counter[str]] = defaultdict(Counter)
    for step in steps:
        if step.skill is not None:
            counts[step.episode_id][step.skill] += 1
        elif step.parse_stage != SKILL_STAGE:
            counts[step.episode_id][step.action_name] += 1
    return dict(counts)


class Understanding(BaseModel):
    """How the goals an agent read before playing (`guided`) compare with the dataset's, and
    what its success owed to reading them right."""

    grounded: SuccessRate
    """Distinct instruction texts read exactly right, out of every text with a grounding (a
    text is read once, however many worlds play it), clustered by goal. Summaries written
    before: per episode, plain Wilson."""
    not_started: int = Field(ge=0)
    """Episodes that could not start: the answer was not a well-formed goal."""
    success_when_right: SuccessRate | None
    """Success of the episodes whose goal was read right, clustered by goal; None without any."""
    success_when_wrong: SuccessRate | None
    """Success of the episodes played on a wrong (but well-formed) goal, clustered by goal;
    None without any."""
    by_category: dict[str, SuccessRate] = {}
    """`grounded` per goal category present (`one`, `combo`, ...; Medium's and Hard's splits),
    to set beside `Summary.by_category`. Summaries written before: empty."""
    by_scenario: dict[str, SuccessRate] = {}
    """`grounded` per scenario class present (`Achievements`, `Conditional`, ...), to set beside
    success per scenario class (`scenario_success`). Summaries written before: empty."""
    scenario_success: dict[str, SuccessRate] = {}
    """Success of the grounded episodes per scenario class, over every goal set, clustered by
    goal. Summaries written before: empty."""


def understanding(episodes: Sequence[EpisodeRecord]) -> Understanding | None:
    """Understanding over the episodes that carry a grounding; None when none does."""
    grounded = [e for e in episodes if e.grounding is not None]
    if not grounded:
        return None
    # One reading per text: guided grounds each text once and plays it in every world.
    texts: dict[tuple[tuple[str, str], str], bool] = {}
    groups: dict[tuple[tuple[str, str], str], tuple[str, str]] = {}
    for e in grounded:
        key = (goal_cluster(e), e.instruction)
        texts.setdefault(key, bool(e.grounding_correct))
        groups.setdefault(key, (e.category, e.scenario_class))

    def read_in(part: int, value: str) -> SuccessRate:
        """`grounded` over the texts whose (category, scenario class)[part] is `value`."""
        return clustered_rate(
            (goal, int(ok), 1)
            for (goal, text), ok in texts.items()
            if groups[goal, text][part] == value
        )

    right = [e for e in grounded if e.grounding_correct]
    wrong = [e for e in grounded if not e.grounding_correct and e.termination != NOT_STARTED]
    categories = dict.fromkeys(category for category, _ in groups.values())
    scenarios = dict.fromkeys(scenario for _, scenario in groups.values())
    return Understanding(
        by_category={category: read_in(0, category) for category in categories},
        by_scenario={scenario: read_in(1, scenario) for scenario in scenarios},
        scenario_success={
            scenario: _clustered_success(e for e in grounded if e.scenario_class == scenario)
            for scenario in scenarios
        },
        grounded=clustered_rate((goal, int(ok), 1) for (goal, _), ok in texts.items()),
        not_started=sum(e.termination == NOT_STARTED for e in grounded),
        success_when_right=_clustered_success(right) if right else None,
        success_when_wrong=_clustered_success(wrong) if wrong else None,
    )


class Summary(BaseModel):
    """Metrics over a set of finished episodes."""

    overall: SuccessRate
    """Success over every episode, clustered by goal."""
    by_category: dict[str, SuccessRate]
    """Success per goal category present (`one`, `combo`, `new_objects`, `paraphrased`),
    clustered by goal."""
    by_scenario: dict[str, dict[str, SuccessRate]] = {}
    """Success per scenario class present, then per category present (the paper's Table 2:
    `Build` -> `train` -> rate), clustered by goal."""
    by_goal: dict[str, SuccessRate]
    """Success per goal, keyed `category/goal_id` as episode ids begin: an id alone may name
    different goals in different splits (Medium's `INSTRUCTION_STONE_4` is a square in train, a
    line in the paraphrased split). Plain Wilson: one goal's worlds are independent."""
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
    computed_prompt_share: float | None = Field(None, ge=0.0, le=1.0)
    """Share of the prompt tokens the backend computed, the rest reused from its prefix cache;
    None when some episode's backend did not say (or its record predates the count)."""
    understanding: Understanding | None = None
    """The goals read before playing against the dataset's (`guided`); None for other agents."""
    model_calls_per_episode: float | None = None
    """Mean prompts sent to the model per episode; None when some episode's record predates
    the count."""
    actions: ActionHistogram | None = None
    """The actions taken over every step of these episodes; None when the steps were not at
    hand (no step log, or a summary written before histograms)."""


def _success_rates(groups: dict[str, list[EpisodeRecord]]) -> dict[str, SuccessRate]:
    return {key: _clustered_success(episodes) for key, episodes in groups.items()}


def goal_key(episode: EpisodeRecord) -> str:
    """The key of an episode's goal among a run's (`Summary.by_goal`): its category and id."""
    return f"{episode.category}/{episode.goal_id}"


def computed_share(episodes: Sequence[EpisodeRecord]) -> float | None:
    """Computed prompt tokens over all prompt tokens (`Summary.computed_prompt_share`)."""
    computed = [episode.computed_prompt_tokens for episode in episodes]
    prompt = sum(episode.prompt_tokens for episode in episodes)
    if not prompt or any(count is None for count in computed):
        return None
    return min(1.0, sum(count or 0 for count in computed) / prompt)


def summarize(
    episodes: Sequence[EpisodeRecord], actions: Mapping[str, Mapping[str, int]] | None = None
) -> Summary:
    """Metrics over `episodes`, with the histogram of the actions they took when `actions`
    (episode id -> action -> steps, `action_counts`) is given; raises `UserError` when there
    are no episodes."""
    if not episodes:
        raise UserError("no finished episodes to summarize")
    by_category: dict[str, list[EpisodeRecord]] = defaultdict(list)
    by_scenario: dict[str, dict[str, list[EpisodeRecord]]] = defaultdict(lambda: defaultdict(list))
    by_goal: dict[str, list[bool]] = defaultdict(list)
    for episode in episodes:
        by_category[episode.category].append(episode)
        by_scenario[episode.scenario_class][episode.category].append(episode)
        by_goal[goal_key(episode)].append(episode.success)
    terminations = Counter(episode.termination for episode in episodes)
    success_steps = [episode.steps for episode in episodes if episode.success]
    total_steps = sum(episode.steps for episode in episodes)

    def per_step(total: int) -> float:
        return total / total_steps if total_steps else 0.0

    pooled: Counter[str] = Counter()
    if actions is not None:
        for episode in episodes:
            pooled.update(actions.get(episode.episode_id, {}))
    return Summary(
        overall=_clustered_success(episodes),
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
        by_goal={
            goal: SuccessRate.of(sum(outcomes), len(outcomes))
            for goal, outcomes in sorted(by_goal.items())
        },
        terminations={reason: terminations[reason] for reason in TERMINATIONS}
        | ({NOT_STARTED: terminations[NOT_STARTED]} if terminations[NOT_STARTED] else {}),
        invalid_action_rate=per_step(sum(episode.invalid_actions for episode in episodes)),
        steps_to_success_mean=statistics.fmean(success_steps) if success_steps else None,
        steps_to_success_median=statistics.median(success_steps) if success_steps else None,
        prompt_tokens_per_step=per_step(sum(episode.prompt_tokens for episode in episodes)),
        completion_tokens_per_step=per_step(sum(episode.completion_tokens for episode in episodes)),
        computed_prompt_share=computed_share(episodes),
        understanding=understanding(episodes),
        model_calls_per_episode=statistics.fmean(calls)
        if (calls := [e.model_calls for e in episodes if e.model_calls is not None])
        and len(calls) == len(episodes)
        else None,
        actions=action_histogram(pooled) if actions is not None else None,
    )
