"""The field's achievement scores of a set of episodes, beside CrafText's success rate: the
Crafter score, BALROG's progression and craftaxlm's log-weighted score, with the per-achievement
unlock table they all come from.

Every score is over one achievement list, named by the variant: Crafter's 22 (Craftax-Classic,
the list BALROG and the Crafter paper score) or full Craftax's 67 (its own list, labelled so, not
comparable with a Crafter table). Only whether an episode unlocked an achievement counts, never
how often, as in all three.

- Crafter score (Hafner 2021): s_i = % of episodes unlocking achievement i;
  S = exp(mean_i ln(1 + s_i)) - 1.
- BALROG progression: per episode the share of the list unlocked, x100; over episodes the mean
  and the standard error as balrog/utils.py computes it: the population standard deviation
  (divided by n, not n - 1) over sqrt(n), 0 for a single episode, both on the shares and scaled
  x100 last. The episodes are summed in the order given, as BALROG sums its files in the order
  it lists them: a different order can move the last bits.
- craftaxlm score: mean_i log2(1 + P_i), P_i the same unlock percentage as s_i (so 0 when
  nothing is unlocked, log2(101) ~ 6.66 when everything always is).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Collection, Sequence
from typing import Literal

from pydantic import BaseModel, Field

from env.craftax_names import CLASSIC_ACHIEVEMENTS, FULL_ACHIEVEMENTS
from env.goals import ALL_CATEGORIES
from llm_agents.run_data.records import EpisodeRecord

__all__ = [
    "ACHIEVEMENT_LISTS",
    "LIST_LABELS",
    "AchievementList",
    "EpisodeScores",
    "RunScores",
    "Scores",
    "achievement_list_of",
    "craftaxlm_score",
    "crafter_score",
    "progression",
    "score_episodes",
    "score_run",
]

AchievementList = Literal["classic", "full"]
"""Which achievement list the scores are over: the variant's own."""
ACHIEVEMENT_LISTS: dict[str, tuple[str, ...]] = {
    "classic": CLASSIC_ACHIEVEMENTS,
    "full": FULL_ACHIEVEMENTS,
}
LIST_LABELS: dict[str, str] = {
    "classic": "Crafter's 22 achievements (Craftax-Classic)",
    "full": "full Craftax's 67 achievements (not comparable with Crafter tables)",
}


def crafter_score(unlock_percent: Sequence[float]) -> float:
    """Hafner's Crafter score of per-achievement unlock percentages (0-100)."""
    return math.exp(math.fsum(math.log1p(s) for s in unlock_percent) / len(unlock_percent)) - 1


def craftaxlm_score(unlock_percent: Sequence[float]) -> float:
    """craftaxlm's score: the mean of log2(1 + P_i) over per-achievement unlock percentages."""
    return math.fsum(math.log2(1 + p) for p in unlock_percent) / len(unlock_percent)


def progression(shares: Sequence[float]) -> tuple[float, float]:
    """BALROG's (mean, standard error) of per-episode progression shares (0-1), both x100."""
    n = len(shares)
    mean = sum(shares) / n
    deviation = math.sqrt(sum((x - mean) ** 2 for x in shares) / n) if n > 1 else 0.0
    error = deviation / math.sqrt(n) if n > 1 else 0.0
    return 100 * mean, 100 * error


class EpisodeScores(BaseModel):
    """One episode's scores: a run of one episode."""

    unlocked: int = Field(ge=0)
    """Achievements of the list unlocked."""
    progression: float = Field(ge=0.0, le=100.0)
    """BALROG progression: unlocked / the list's length, x100."""
    crafter_score: float = Field(ge=0.0)
    """The Crafter score of this episode alone (every s_i is 0 or 100)."""
    craftaxlm_score: float = Field(ge=0.0)
    """The craftaxlm score of this episode alone."""


class Scores(BaseModel):
    """The three scores of a set of episodes, and the unlock table they come from."""

    achievement_list: AchievementList
    """Which list they are over (`classic`: Crafter's 22; `full`: full Craftax's 67)."""
    label: str
    """The list in words, for tables."""
    episodes: int = Field(ge=1)
    """Episodes scored."""
    progression: float = Field(ge=0.0, le=100.0)
    """BALROG progression: mean share of the list unlocked per episode, x100."""
    progression_stderr: float = Field(ge=0.0)
    """Its standard error as BALROG computes it (population std / sqrt(n), x100)."""
    crafter_score: float = Field(ge=0.0)
    """Hafner's Crafter score, exp(mean_i ln(1 + s_i)) - 1, s_i in %."""
    craftaxlm_score: float = Field(ge=0.0)
    """craftaxlm's mean_i log2(1 + P_i), P_i in %."""
    unlock_percent: dict[str, float]
    """Achievement (list order) -> % of episodes that unlocked it."""


class RunScores(BaseModel):
    """A run's scores overall, per goal category present and per episode."""

    overall: Scores
    by_category: dict[str, Scores]
    """Per category present, in the project's category order."""
    by_episode: dict[str, EpisodeScores]
    """Episode id -> its scores, in schedule order."""


def _unlocked(achievements: Collection[str], names: tuple[str, ...]) -> set[str]:
    # Records name achievements as Craftax's enum (COLLECT_WOOD); BALROG's files as Crafter
    # (collect_wood): one spelling for both.
    return {name.upper() for name in achievements} & _NAME_SETS[names]


_NAME_SETS: dict[tuple[str, ...], frozenset[str]] = {
    names: frozenset(names) for names in ACHIEVEMENT_LISTS.values()
}


def score_episodes(
    unlocked: Sequence[Collection[str]], achievement_list: AchievementList = "classic"
) -> Scores:
    """The scores of episodes given as the achievement names each unlocked (either spelling:
    `COLLECT_WOOD` or `collect_wood`), summed in the order given; names off the list are
    ignored."""
    if not unlocked:
        raise ValueError("no episodes to score")
    names = ACHIEVEMENT_LISTS[achievement_list]
    sets = [_unlocked(episode, names) for episode in unlocked]
    counts = Counter(name for unlocked_set in sets for name in unlocked_set)
    percent = {name: 100 * counts[name] / len(sets) for name in names}
    mean, error = progression([len(s) / len(names) for s in sets])
    rates = list(percent.values())
    return Scores(
        achievement_list=achievement_list,
        label=LIST_LABELS[achievement_list],
        episodes=len(sets),
        progression=mean,
        progression_stderr=error,
        crafter_score=crafter_score(rates),
        craftaxlm_score=craftaxlm_score(rates),
        unlock_percent=percent,
    )


def achievement_list_of(variant: str | None) -> AchievementList:
    """The list a run of `variant` is scored over (runs recorded without one played full)."""
    return "classic" if variant == "classic" else "full"


def score_run(
    episodes: Sequence[EpisodeRecord], achievement_list: AchievementList = "classic"
) -> RunScores:
    """The scores of a run's finished episodes, from their records alone."""
    by_category: dict[str, list[EpisodeRecord]] = defaultdict(list)
    for episode in episodes:
        by_category[episode.category].append(episode)

    def of(group: Sequence[EpisodeRecord]) -> Scores:
        return score_episodes([e.achievements for e in group], achievement_list)

    names = ACHIEVEMENT_LISTS[achievement_list]

    def alone(episode: EpisodeRecord) -> EpisodeScores:
        # One episode's s_i are each 0 or 100, so both means reduce to the unlocked share: the
        # closed forms keep a save of a long run from scoring every episode as a run.
        unlocked = len(_unlocked(episode.achievements, names))
        share = unlocked / len(names)
        return EpisodeScores(
            unlocked=unlocked,
            progression=100 * share,
            crafter_score=math.exp(share * math.log1p(100)) - 1,
            craftaxlm_score=share * math.log2(101),
        )

    return RunScores(
        overall=of(episodes),
        by_category={c: of(by_category[c]) for c in ALL_CATEGORIES if c in by_category},
        by_episode={
            e.episode_id: alone(e) for e in sorted(episodes, key=lambda e: e.episode_index)
        },
    )
