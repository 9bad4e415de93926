"""The goals a run's table should also be read without: met by a do-nothing agent, or out of
reach (on the variant, or for the scripted expert), each with its numbers and reason.

`env.goal_status` plays the do-nothing worlds (cached) and derives what the variant rules out;
this module gathers both for the goals a run played, for `report --goal-status` and `view
--goal-status`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from pydantic import BaseModel, Field

from env.dataset import load_dataset
from env.goal_status import do_nothing_successes, goal_key, impossible_reason
from env.goals import AnyGoal, run_category
from env.rules import SuccessRule
from llm_agents.agents.expert.plan import expert_cannot
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.run_view import recorded_difficulty
from llm_agents.run_data.metrics import SuccessRate, clustered_rate
from llm_agents.run_data.records import EpisodeRecord

__all__ = [
    "DEFAULT_WORLDS",
    "EXPERT_PLAYED",
    "GoalFlags",
    "GoalStatus",
    "goal_status",
    "run_goal_status",
]

#: Seeded worlds per goal the do-nothing agent plays by default.
DEFAULT_WORLDS = 8
#: Agents whose moves are the scripted expert's: a goal it cannot spend for is out of their reach.
EXPERT_PLAYED = ("expert", "guided")


class GoalFlags(BaseModel):
    """One goal: how often doing nothing meets it, and why it may be out of reach."""

    key: str
    """`split/id`."""
    category: str
    """The goal set a run counts it in."""
    goal_id: str
    scenario_class: str
    do_nothing: int = Field(ge=0)
    """Worlds (of `GoalStatus.worlds`) in which an agent taking only `NOOP` met it."""
    impossible: str | None = None
    """Why no agent can meet it on the variant; None when nothing rules it out."""
    expert_cannot: str | None = None
    """Why the scripted expert (and the agents it plays for) cannot; None when it can try."""

    @property
    def trivial(self) -> bool:
        """Met by doing nothing in at least one world."""
        return self.do_nothing > 0

    def left_out(self, expert: bool) -> str | None:
        """Why the goal is left out of the "without" table (`expert`: the run's moves are the
        scripted expert's); None when it stays."""
        if self.impossible:
            return f"impossible: {self.impossible}"
        if expert and self.expert_cannot:
            return self.expert_cannot
        if self.trivial:
            return "met by doing nothing"
        return None


class GoalStatus(BaseModel):
    """The flags of a set of goals, and how the do-nothing worlds were played."""

    variant: str
    max_steps: int
    success_rule: SuccessRule
    worlds: int = Field(ge=1)
    seed: int
    goals: dict[str, GoalFlags]
    """`category/goal_id` (as the run's episodes name goals) -> flags."""

    def flags(self, episode: EpisodeRecord) -> GoalFlags | None:
        return self.goals.get(f"{episode.category}/{episode.goal_id}")

    def kept(self, episodes: Iterable[EpisodeRecord], expert: bool) -> list[EpisodeRecord]:
        """The episodes whose goal is not left out."""
        return [e for e in episodes if not ((f := self.flags(e)) and f.left_out(expert))]

    def do_nothing_rate(self, flags: Sequence[GoalFlags]) -> SuccessRate | None:
        """The do-nothing agent's success over `flags`' goals (their worlds), clustered by goal."""
        if not flags:
            return None
        return clustered_rate({f.key: (f.do_nothing, self.worlds) for f in flags})


def goal_status(
    goals: Sequence[AnyGoal], config: EvalConfig, *, worlds: int = DEFAULT_WORLDS
) -> GoalStatus:
    """The flags of `goals` under a run's settings (variant, step cap, success rule, seed)."""
    # A recorded config is not validated again: the env's config holds its settings typed.
    env_config = config.env_config()
    variant = env_config.variant
    played = do_nothing_successes(goals, env_config, worlds=worlds, seed=config.seed)
    return GoalStatus(
        variant=variant.value,
        max_steps=env_config.max_steps,
        success_rule=env_config.success_rule,
        worlds=worlds,
        seed=config.seed,
        goals={
            f"{run_category(goal)}/{goal.id}": GoalFlags(
                key=goal_key(goal),
                category=run_category(goal),
                goal_id=goal.id,
                scenario_class=goal.scenario_class,
                do_nothing=played[goal_key(goal)],
                impossible=impossible_reason(goal, variant),
                expert_cannot=expert_cannot(goal),
            )
            for goal in goals
        },
    )


def run_goal_status(
    settings: dict[str, object],
    episodes: Sequence[EpisodeRecord],
    *,
    rule: SuccessRule | None = None,
    worlds: int = DEFAULT_WORLDS,
) -> GoalStatus:
    """The flags of the goals a run's `episodes` played, from the dataset it recorded (a
    `UserError` when it cannot be loaded), under `rule` (default: the run's)."""
    config = EvalConfig.recorded(settings)
    if rule is not None:
        config = config.model_copy(update={"success_rule": rule})
    difficulty = recorded_difficulty(settings)
    dataset = load_dataset(config.dataset)
    played = {(e.category, e.goal_id) for e in episodes}
    goals = [
        goal
        for goal in dataset.goals
        if goal.difficulty == difficulty and (run_category(goal), goal.id) in played
    ]
    return goal_status(goals, config, worlds=worlds)
