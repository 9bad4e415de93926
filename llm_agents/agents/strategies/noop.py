"""The do-nothing agent (`--agent noop`): `NOOP` at every step, no model. Its run is the floor
a goal set's success sits on: what the official checkers grant an agent that never acts."""

from __future__ import annotations

from typing import Any, ClassVar

from env.goals import AnyGoal
from env.variant import Variant, as_variant
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.answers.parser import ParseResult
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION
from llm_agents.agents.registry import AgentSettings
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt, messages_hash
from llm_agents.backends.base import ModelOutput

__all__ = ["NoopAgent"]

_NOOP = "NOOP"


class NoopAgent:
    """Takes `NOOP` at every step of every episode."""

    protocol_version: ClassVar[int] = AGENT_PROTOCOL_VERSION
    needs_model: ClassVar[bool] = False
    templates: ClassVar[tuple[str, ...]] = ()
    choices: ClassVar[None] = None

    def __init__(self, variant: Variant | str = Variant.FULL):
        self.variant = as_variant(variant)
        self.fallback_id = action_id(_NOOP, self.variant)

    @classmethod
    def from_config(cls, config: AgentSettings) -> NoopAgent:
        return cls(config.variant)

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Nothing to remember: every step is the same."""

    def end_episode(self, slot: int) -> None:
        """Nothing to forget."""

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """No prompt: nothing to check."""

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        return StepPrompt(slot=slot, observation=observation, messages=[], text="")

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        return Decision(
            slot=prompt.slot,
            action=self.fallback_id,
            name=_NOOP,
            parse=ParseResult(action=self.fallback_id, name=_NOOP, stage="exact", raw=_NOOP),
            output=ModelOutput(text=_NOOP),
            observation_text="",
            prompt_hash=messages_hash([]),
            fallback_used=False,
        )
