"""The records every strategy and the runner share: an episode's start, a step's prompt and the
decision read from the answer to it."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict

from llm_agents.agents.answers.parser import ParseResult
from llm_agents.backends.base import ChatMessage, ChoiceSet, ModelOutput
from llm_agents.run_data.readings import Grounding
from llm_agents.run_data.records import SkillRecord

if TYPE_CHECKING:
    from env.goals import AnyGoal


@dataclass(frozen=True)
class EpisodeStart:
    """What an agent is told when an episode begins in a slot."""

    instruction: str
    """The text the agent is asked to carry out (the goal's instruction or a paraphrase)."""
    plan: str | None = None
    """The plan `--plans` maps the instruction to, added to the step prompt; None: no plan."""
    goal: AnyGoal | None = None
    """The dataset record the instruction describes: read only by strategies that must know
    which goal is played (few-shot leaves it out of its demonstrations; the expert plays it)."""
    episode: str = ""
    """The episode's `episode_id` in the run (the same in every run of the schedule), from
    which `--choice-scoring letters` draws its orders."""


@dataclass(frozen=True)
class StepPrompt:
    """One slot's prompt for one step, waiting for the model's answer."""

    slot: int
    """The slot (episode in flight) the prompt is for."""
    observation: Any
    """The observation the prompt shows (the next step's outcome is read against it)."""
    messages: list[ChatMessage]
    """The conversation sent to the model."""
    text: str
    """The rendered observation."""
    choices: ChoiceSet | None = None
    """The options this prompt's answer must be one of, when they differ from the agent's
    (`skills --choice`: the skills valid now); None: the agent's `choices`."""
    options_shown: tuple[str, ...] | None = None
    """`--choice-scoring letters`: the options in the order the prompt letters them (the first
    under `A`); the answer is a label, mapped back through this order."""
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
    options_shown: tuple[str, ...] | None = None
    """`--choice-scoring letters`: the order the prompt lettered the options in (the prompt's
    `options_shown`)."""
    skills: tuple[SkillRecord, ...] = ()
    """`skills`: the decisions this step touched, as they stand after it is chosen: the one
    it closed (a skill that finished or failed on this observation), then the one it belongs
    to."""


def messages_hash(messages: Sequence[ChatMessage]) -> str:
    """sha256 over the messages' roles, contents and images (their PNGs' digests), stable across
    processes: of the UTF-8 of `json.dumps([[role, content, *image digests], ...],
    ensure_ascii=False)` (a text message hashes as before images existed), built a message at a
    time so that the system prompt every step repeats is encoded and hashed once (the hash's
    state after it is kept and copied)."""
    if not messages:
        return hashlib.sha256(b"[]").hexdigest()
    first, *rest = messages
    digest = _opened(first.role, first.content, _image_digests(first)).copy()
    for message in rest:
        digest.update(b", ")
        digest.update(_encoded(message.role, message.content, _image_digests(message)))
    digest.update(b"]")
    return digest.hexdigest()


def _image_digests(message: ChatMessage) -> tuple[str, ...]:
    return tuple(image.sha256 for image in message.images) if message.images else ()


@lru_cache(maxsize=64)
def _opened(role: str, content: str, images: tuple[str, ...]) -> Any:
    """The hash's state after `[` and a first message."""
    digest = hashlib.sha256(b"[")
    digest.update(_encoded(role, content, images))
    return digest


#: `json.dumps(..., ensure_ascii=False)`'s encoder, made once: `json.dumps` makes a new one at
#: every call given any option.
_JSON = json.JSONEncoder(ensure_ascii=False)


@lru_cache(maxsize=64)
def _encoded(role: str, content: str, images: tuple[str, ...]) -> bytes:
    return _JSON.encode([role, content, *images]).encode("utf-8")


#: `messages_hash` of no messages: the prompt of a step the model was not asked about.
NO_PROMPT_HASH = messages_hash([])
