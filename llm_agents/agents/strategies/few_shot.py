"""The few-shot agent (`few-shot`): the zero-shot agent whose every step message starts with k
demonstration steps of the expert.

Demonstrations come from a finished run of the `expert` agent (`--demos RUN_DIR`): its successful
episodes of training goals (`one`, `combo`), never of the goal being evaluated. Their observations
were rendered by that run, so the run must use the same renderer and variant as this one. For each
episode the agent takes the last k steps of the shortest successful expert episode of another
goal (the steps that reach its achievements), continuing with the next episode when k is larger.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.backends.base import ChatMessage
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    read_episodes,
    read_results,
    read_steps,
)
from prompts import render_template

if TYPE_CHECKING:
    from llm_agents.agents.registry import AgentSettings
    from llm_agents.agents.types import EpisodeStart

TRAINING_CATEGORIES = frozenset({"one", "combo"})
TEMPLATE = "few_shot"


class DemoStep(BaseModel):
    """One step of an expert episode as an LLM agent would have seen it."""

    model_config = ConfigDict(frozen=True)

    step: int
    """The episode step (0-based)."""
    observation: str
    """The observation text the expert's run rendered."""
    action: str
    """The expert's action."""


class Demonstration(BaseModel):
    """Consecutive steps of one successful expert episode."""

    model_config = ConfigDict(frozen=True)

    goal_id: str
    """The goal the expert played (never the evaluated one)."""
    instruction: str
    """The instruction text of that episode."""
    steps: tuple[DemoStep, ...]
    """The steps shown, in order."""


@dataclass(frozen=True)
class _DemoEpisode:
    goal_id: str
    instruction: str
    steps: tuple[DemoStep, ...]


def load_demonstrations(run_dir: str | Path, renderer: str, variant: str) -> list[_DemoEpisode]:
    """Successful training-goal episodes of an expert run, shortest first."""
    folder = Path(run_dir)
    results_path, episodes_path, steps_path = (
        folder / RESULTS_FILE,
        folder / EPISODES_FILE,
        folder / STEPS_FILE,
    )
    for path in (results_path, episodes_path, steps_path):
        if not path.is_file():
            raise UserError(
                f"demonstrations folder {folder} has no {path.name}: run the expert there"
            )
    config = read_results(results_path).config
    if config.get("agent") != "expert":
        raise UserError(f"{folder} is a run of the {config.get('agent')!r} agent, not the expert")
    for key, ours in (("renderer", renderer), ("variant", variant)):
        if config.get(key) != ours:
            raise UserError(
                f"demonstrations in {folder} use {key} {config.get(key)!r}, this run {ours!r}"
            )
    wanted = {
        e.episode_id: e
        for e in read_episodes(episodes_path)
        if e.success and e.category in TRAINING_CATEGORIES
    }
    steps: dict[str, list[DemoStep]] = {key: [] for key in wanted}
    for record in read_steps(steps_path, wanted):
        steps[record.episode_id].append(
            DemoStep(step=record.step, observation=record.observation, action=record.action_name)
        )
    ordered = sorted(wanted.values(), key=lambda e: (e.steps, e.episode_id))
    return [
        _DemoEpisode(
            e.goal_id, e.instruction, tuple(sorted(steps[e.episode_id], key=lambda s: s.step))
        )
        for e in ordered
        if steps[e.episode_id]
    ]


def pick_demonstrations(
    episodes: list[_DemoEpisode], goal_id: str, count: int
) -> list[Demonstration]:
    """`count` steps in all, from the shortest episodes of goals other than `goal_id`."""
    picked: list[Demonstration] = []
    left = count
    for episode in episodes:
        if left <= 0:
            break
        if episode.goal_id == goal_id:
            continue
        shown = episode.steps[-left:]
        picked.append(
            Demonstration(goal_id=episode.goal_id, instruction=episode.instruction, steps=shown)
        )
        left -= len(shown)
    return picked


class FewShotAgent(ZeroShotAgent):
    """Zero-shot with k expert demonstration steps (other training goals) before each step."""

    templates: ClassVar[tuple[str, ...]] = (*ZeroShotAgent.templates, TEMPLATE)
    # Its demonstrations answer in plain action names: no schema of its own.
    agent_name: ClassVar[str] = "few-shot"

    def __init__(
        self,
        *args: Any,
        demos: str | Path | list[_DemoEpisode] | None = None,
        steps: int = 8,
        **kwargs: Any,
    ):
        super().__init__(*args, **kwargs)
        if demos is None:
            raise UserError(
                "the few-shot agent needs demonstrations: pass demos=RUN_DIR of an expert run"
            )
        renderer = kwargs.get("renderer", "objects")
        self.demo_episodes = (
            demos
            if isinstance(demos, list)
            else load_demonstrations(
                demos, renderer if isinstance(renderer, str) else "", self.variant.value
            )
        )
        if not self.demo_episodes:
            raise UserError(f"{demos} holds no successful expert episode of a training goal")
        self.demo_steps = steps
        self._demos: dict[int, list[Demonstration]] = {}

    @classmethod
    def strategy_settings(cls, config: AgentSettings) -> dict[str, Any]:
        return {"demos": config.demos, "steps": config.few_shot_steps}

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        if start.goal is None:
            raise UserError("the few-shot agent needs the goal record to leave its own goal out")
        super().start_episode(slot, start)
        self._demos[slot] = pick_demonstrations(self.demo_episodes, start.goal.id, self.demo_steps)

    def end_episode(self, slot: int) -> None:
        super().end_episode(slot)
        self._demos.pop(slot, None)

    def demonstrations(self, slot: int) -> list[Demonstration]:
        """The demonstrations the slot's prompts carry."""
        return list(self._demos.get(slot, []))

    def messages_for(self, slot: int, observation_text: str) -> list[ChatMessage]:
        messages = super().messages_for(slot, observation_text)
        context = {
            "demonstrations": [d.model_dump() for d in self._demos.get(slot, [])],
            "step": messages[-1].content,
        }
        user = ChatMessage(
            role="user", content=render_template(TEMPLATE, context, self.templates_dir)
        )
        return [*messages[:-1], user]
