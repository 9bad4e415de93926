"""The agent protocol, version `AGENT_PROTOCOL_VERSION`: what the runner asks of an agent, and
everything an agent written outside this package needs to import (docs/writing-an-agent.md
walks through writing one).

An agent class declares the protocol version it was written for (`protocol_version`); the
runner refuses a class written for another. The version changes whenever a change here would
break an agent written for the one before: a method added, removed or called differently, a
record's field removed or its meaning changed. Adding an optional field to a record does not
change it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar, Protocol, Self, runtime_checkable

from llm_agents.agents.answers.actions import action_id, action_names
from llm_agents.agents.answers.parser import ParseResult, parse_action
from llm_agents.agents.registry import AgentSettings
from llm_agents.agents.types import (
    NO_PROMPT_HASH,
    Decision,
    EpisodeStart,
    StepPrompt,
    messages_hash,
)
from llm_agents.backends.base import ChatMessage, ChoiceSet, ModelOutput

if TYPE_CHECKING:
    from env.goals import AnyGoal

__all__ = [
    "AGENT_PROTOCOL_VERSION",
    "NO_PROMPT_HASH",
    "Agent",
    "AgentSettings",
    "ChatMessage",
    "ChoiceSet",
    "Decision",
    "EpisodeStart",
    "ModelOutput",
    "ParseResult",
    "StepPrompt",
    "action_id",
    "action_names",
    "messages_hash",
    "parse_action",
]

#: The version of the protocol below. 1: the protocol as first published.
AGENT_PROTOCOL_VERSION = 1


@runtime_checkable
class Agent(Protocol):
    """What the runner needs of an agent: episodes begin and end per slot; each step of a slot
    is a prompt built from its observation (`prepare`), the model's answer to it, and the
    decision read from that answer (`decide`)."""

    protocol_version: ClassVar[int]
    """The `AGENT_PROTOCOL_VERSION` the class was written for."""
    needs_model: ClassVar[bool]
    """False for agents that never call the model (the runner then opens none)."""
    templates: ClassVar[tuple[str, ...]]
    """The packaged prompt templates the agent renders: a run's identity hashes these, so
    editing one another agent renders never strands this agent's partial runs."""
    fallback_id: int
    """The action id a slot without a decision gets."""
    choices: ChoiceSet | None
    """The action names answers are constrained to, with their rule; None: free text."""

    @classmethod
    def from_config(cls, config: AgentSettings) -> Self:
        """The agent a run of `config` plays with (built once per run, and once more to check
        its templates before anything is written)."""

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin an episode in `slot`, forgetting the slot's previous one."""

    def end_episode(self, slot: int) -> None:
        """The episode in `slot` ended: forget what the slot held for it."""

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """Build what the agent would send for an episode of `instruction` (and `plan`, `goal`)
        through the path a run builds it with, so a broken template fails before any work."""

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        """The prompt for this step of the slot's episode, built from `observation` (a
        `textualizer.Observation`); the runner sends its messages to the model."""

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        """The action read from the model's `output` to `prompt`, with what is needed to audit
        it (an unreadable answer plays the fallback action, `fallback_used`)."""


#: The members a class must have to be an agent; `fallback_id` and `choices` are set on the
#: built agent (`from_config`), so a class need not declare them.
CLASS_MEMBERS = (
    "protocol_version",
    "needs_model",
    "templates",
    "from_config",
    "start_episode",
    "end_episode",
    "check_templates",
    "prepare",
    "decide",
)
INSTANCE_MEMBERS = ("fallback_id", "choices")
