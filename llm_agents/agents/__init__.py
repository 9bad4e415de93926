"""Agent strategies by name: `zero-shot`, `cot`, `few-shot`, the scripted `expert`, `guided` (the
model reads the goal, the expert plays it), `noop` and `skills`; and agents from outside this
package, named `package.module:Class` or registered by an installed package under the
`craftext_llm.agents` entry-point group.

Like the backends, the names map to `"module:Class"` and import lazily (`loading`). Every agent
plays many episodes (slots) at once, each stepping on its own, and follows the versioned `Agent`
protocol (`protocol`); the runner builds one per run with `build_agent(config)`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from llm_agents.agents.loading import agent_class, build_agent
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION, Agent
from llm_agents.agents.registry import AGENTS
from llm_agents.backends.base import ChoiceSet, ModelAPI, ModelOutput

__all__ = [
    "AGENTS",
    "AGENT_PROTOCOL_VERSION",
    "Agent",
    "NoModel",
    "agent_class",
    "build_agent",
]


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
