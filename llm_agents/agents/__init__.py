"""Agent strategies by name: `zero-shot`, `cot`, `few-shot`, the scripted `expert`, `guided` (the
model reads the goal, the expert plays it) and `noop`.

Like the backends, the registry (`registry.AGENTS`) maps a name to `"module:Class"` and
imports lazily. Every agent plays many episodes (slots) at once, each stepping on its own, and
follows the `Agent` protocol; the runner builds one per run with `build_agent(config)`.
"""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

from env.errors import UserError
from llm_agents.agents.registry import AGENTS
from llm_agents.backends.base import ChoiceSet, ModelAPI, ModelOutput

if TYPE_CHECKING:
    from env.goals import AnyGoal
    from llm_agents.agents.registry import AgentSettings
    from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt

__all__ = ["AGENTS", "Agent", "NoModel", "agent_class", "build_agent"]


@runtime_checkable
class Agent(Protocol):
    """What the runner needs of an agent: episodes begin and end per slot; each step of a slot
    is a prompt built from its observation (`prepare`), the model's answer to it, and the
    decision read from that answer (`decide`)."""

    needs_model: ClassVar[bool]
    """False for agents that never call the model (the runner then opens none)."""
    templates: ClassVar[tuple[str, ...]]
    """The prompt templates the agent renders: a run's identity hashes these, so editing one
    another agent renders never strands this agent's partial runs."""
    fallback_id: int
    """The action id a slot without a decision gets."""
    choices: ChoiceSet | None
    """The action names answers are constrained to, with their rule; None: free text."""

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin an episode in `slot`, forgetting the slot's previous one."""

    def end_episode(self, slot: int) -> None: ...

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """Build what the agent would send for an episode of `instruction` (and `plan`, `goal`)
        through the path a run builds it with, so a broken template fails before any work."""

    def prepare(self, slot: int, observation: Any) -> StepPrompt: ...

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision: ...


def agent_class(name: str) -> type[Agent]:
    """The class registered under `name`, imported on first use."""
    if name not in AGENTS:
        close = difflib.get_close_matches(name, AGENTS, n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        raise UserError(f"unknown agent {name!r}{hint} (agents: {', '.join(AGENTS)})")
    module_name, _, class_name = AGENTS[name].partition(":")
    cls: type[Agent] = getattr(importlib.import_module(module_name), class_name)
    return cls


def build_agent(config: AgentSettings) -> Agent:
    """The agent `config.agent` names, set up from the run's config."""
    cls: Any = agent_class(config.agent)
    agent: Agent = cls.from_config(config)
    return agent


class NoModel(ModelAPI):
    """The model handed to the runner for agents that need none: calling it is a bug."""

    backend_name = "none"

    def __init__(self) -> None:
        super().__init__("none")

    def _generate(
        self, conversations: Sequence[Any], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        """An empty answer per conversation: an agent without a model decides by itself."""
        return [ModelOutput(text="") for _ in conversations]

    def info(self) -> dict[str, str]:
        return {"backend": "none"}
