"""The one interface every LLM backend implements.

A backend takes a batch of chat conversations and returns one `ModelOutput` per conversation,
in order. Backends never raise for a single bad generation: they return an output with
`finish_reason="error"` and the error text, so one failure never loses the rest of a batch.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any, Literal, Self

from pydantic import BaseModel, ConfigDict, Field

Role = Literal["system", "user", "assistant"]
FinishReason = Literal["stop", "length", "choice", "error"]


class ChatMessage(BaseModel):
    """One message of a chat conversation."""

    model_config = ConfigDict(frozen=True)

    role: Role
    """Who speaks: `system`, `user` or `assistant`."""
    content: str
    """The message text."""


Conversation = Sequence[ChatMessage]


class GenerateConfig(BaseModel):
    """Generation parameters shared by all backends."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    max_tokens: int = Field(256, ge=1)
    """Most tokens generated for the answer (thinking included unless `reasoning_budget` is set)."""
    temperature: float = Field(0.0, ge=0.0)
    """Sampling temperature; 0 means greedy decoding."""
    top_p: float = Field(1.0, gt=0.0, le=1.0)
    """Nucleus sampling mass."""
    sampling_seed: int | None = 0
    """Sampling seed where the backend supports one; None leaves it to the backend."""
    stop: list[str] = Field(default_factory=list)
    """Strings that end generation."""
    reasoning_budget: int | None = Field(None, ge=1)
    """Tokens a reasoning model may spend thinking before it must answer; None: no separate budget."""
    timeout_s: float = Field(120.0, gt=0)
    """Seconds one request may take before it counts as failed (HTTP backends)."""
    max_concurrency: int = Field(16, ge=1)
    """Requests in flight at once (HTTP backends)."""
    max_retries: int = Field(6, ge=0)
    """Retries of a transient failure (HTTP backends), after the first attempt."""


class ModelOutput(BaseModel):
    """What a backend returns for one conversation."""

    text: str
    """The answer, with any reasoning removed."""
    reasoning: str | None = None
    """The model's reasoning (thinking) text, kept for logs; never parsed as the answer."""
    prompt_tokens: int = 0
    """Tokens in the prompt."""
    completion_tokens: int = 0
    """Tokens generated, reasoning included."""
    latency_s: float = 0.0
    """Wall time spent on this conversation (for a batch: the batch's time)."""
    finish_reason: FinishReason = "stop"
    """`stop`: natural end; `length`: hit max_tokens; `choice`: picked from the given choices; `error`: failed."""
    followups: int = 0
    """Extra requests made for this answer (e.g. an "answer only" follow-up after truncated thinking)."""
    cached: bool = False
    """True when the answer came from the response cache."""
    error: str | None = None
    """Why the generation failed, when finish_reason is `error`."""


class ModelAPI(abc.ABC):
    """Base class of every backend. Subclasses are registered in `llm_agents.backends`."""

    #: The registry name, e.g. "hf"; set by each subclass.
    backend_name: str = ""
    #: How the runner should feed the backend. True: many concurrent one-conversation
    #: `generate` calls (up to `max_concurrency`, from threads), for servers that batch requests
    #: themselves. False: one call at a time with every conversation that is ready, for
    #: in-process engines that batch what they are given.
    concurrent_requests: bool = False

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        self.model_name = model_name
        self.config = config or GenerateConfig()
        self.options = options

    @abc.abstractmethod
    def generate(
        self,
        conversations: Sequence[Conversation],
        choices: Sequence[str] | None = None,
    ) -> list[ModelOutput]:
        """Answer every conversation; with `choices`, each answer is exactly one of them."""

    def probe(self) -> None:
        """Check with one cheap request that the model answers; raise `UserError` naming why not."""
        output = self.generate([[ChatMessage(role="user", content="Answer with one word: OK")]])[0]
        if output.finish_reason == "error":
            from env.errors import UserError

            raise UserError(f"model {self.model_name!r} does not answer: {output.error}")

    def info(self) -> dict[str, str]:
        """Backend, model and library versions, recorded in results."""
        return {"backend": self.backend_name, "model": self.model_name}

    def close(self) -> None:
        """Release resources (processes, GPU memory, connections)."""
        return None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
