"""The records every strategy and the runner share: a step's prompt and the decision read from
the answer to it."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from pydantic import BaseModel, ConfigDict

from llm_agents.agents.parser import ParseResult
from llm_agents.backends.base import ChatMessage, ModelOutput
from llm_agents.run_data.readings import Grounding


@dataclass(frozen=True)
class StepPrompt:
    """One slot's prompt for one step, waiting for the model's answer."""

    slot: int
    observation: Any
    """The observation the prompt shows (the next step's outcome is read against it)."""
    messages: list[ChatMessage]
    text: str
    """The rendered observation."""
    deferred: bool = False
    """The slot waits on another slot's request (the same question, asked once): it is sent
    nowhere, and the play loop prepares it again once that answer has been decided."""


class Decision(BaseModel):
    """The agent's choice for one slot at one step, with everything needed to audit it."""

    model_config = ConfigDict(frozen=True)

    slot: int
    """The slot (episode index in the batch)."""
    action: int
    """The action id sent to the environment."""
    name: str
    """The action's name."""
    parse: ParseResult
    """What the parser read from the model's answer."""
    output: ModelOutput
    """The model's output as the backend returned it."""
    observation_text: str
    """The rendered observation shown to the model."""
    prompt_hash: str
    """sha256 of the rendered messages (roles and contents) sent for this decision."""
    fallback_used: bool
    """True when the answer was unparseable and the fallback action was taken."""
    grounding: Grounding | None = None
    """Set on an episode's first decision by agents that read the instruction into a goal
    first (`guided`); an invalid one means the episode could not start."""


def messages_hash(messages: Sequence[ChatMessage]) -> str:
    """sha256 over the messages' roles and contents, stable across processes: of the UTF-8 of
    `json.dumps([[role, content], ...], ensure_ascii=False)`, built a message at a time so that
    the system prompt every step repeats is encoded once."""
    digest = hashlib.sha256(b"[")
    for index, message in enumerate(messages):
        if index:
            digest.update(b", ")
        digest.update(_encoded(message.role, message.content))
    digest.update(b"]")
    return digest.hexdigest()


@lru_cache(maxsize=64)
def _encoded(role: str, content: str) -> bytes:
    return json.dumps([role, content], ensure_ascii=False).encode("utf-8")
