"""Which episode runs next: the run's schedule in its fixed order, and the queue episodes are
taken from."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from env.dataset import Instruction
from env.goals import Category, run_category

if TYPE_CHECKING:
    from llm_agents.evaluation.config import EvalConfig


@dataclass(frozen=True)
class ScheduledEpisode:
    """One episode of the run's schedule."""

    index: int
    instruction: Instruction
    repeat: int
    plan: str | None

    @property
    def category(self) -> Category:
        return run_category(self.instruction.goal)

    @property
    def episode_id(self) -> str:
        return (
            f"{self.category}/{self.instruction.goal.id}/{self.instruction.variant}/{self.repeat}"
        )


def build_schedule(
    config: EvalConfig, instructions: Sequence[Instruction], plans: dict[str, str] | None
) -> list[ScheduledEpisode]:
    """Every (instruction, repeat) of the run in a fixed order, cut to `config.limit`.

    The order interleaves categories and puts original instructions before paraphrases, so a
    run cut short by `limit` still samples every category and goal.
    """
    rank_in_category: dict[tuple[str, str], int] = {}
    goals_seen: Counter[str] = Counter()
    keyed = []
    for instruction in instructions:
        category = run_category(instruction.goal)
        goal_key = (category, instruction.goal.id)
        if goal_key not in rank_in_category:
            rank_in_category[goal_key] = goals_seen[category]
            goals_seen[category] += 1
        for repeat in range(config.episodes_per_instruction):
            order = (
                repeat,
                instruction.variant,
                rank_in_category[goal_key],
                config.categories.index(category),
            )
            keyed.append((order, instruction, repeat))
    keyed.sort(key=lambda item: item[0])
    if config.limit:
        keyed = keyed[: config.limit]
    return [
        ScheduledEpisode(
            index=index,
            instruction=instruction,
            repeat=repeat,
            plan=(plans or {}).get(instruction.text),
        )
        for index, (_, instruction, repeat) in enumerate(keyed)
    ]


class EpisodeQueue:
    """The episodes still to play, taken in schedule order."""

    def __init__(self, pending: Sequence[ScheduledEpisode]):
        # Reversed, so the next episode pops off the end.
        self._stack = list(reversed(pending))

    def take(self, count: int) -> list[ScheduledEpisode]:
        """Up to `count` episodes, the earliest first."""
        return [self._stack.pop() for _ in range(min(count, len(self._stack)))]

    def put_back(self, specs: Sequence[ScheduledEpisode]) -> None:
        """Episodes taken but not played: they are taken again first, in schedule order."""
        self._stack.extend(sorted(specs, key=lambda spec: spec.index, reverse=True))
