"""The project's one retry policy for transient failures of remote calls (tenacity).

A call is retried only when it raises `TransientError`: rate limits (429), server errors (5xx),
timeouts, dropped connections, garbled responses. Anything else fails at once. Waits grow
exponentially with random jitter, so that many clients hitting one overloaded server spread out;
a server's `Retry-After` is honoured as a lower bound on the wait, capped so that one bad header
cannot stall a run for hours. A failure that took its server out of a pool of several
(`endpoints.py`) while another is still in is retried there at once: the wait is for a server to
recover, and the next attempt does not go to that server.
"""

from __future__ import annotations

import email.utils
import logging
import random
import time

from pydantic import BaseModel, ConfigDict, Field
from tenacity import (
    AsyncRetrying,
    RetryCallState,
    retry_if_exception_type,
    stop_after_attempt,
)

from llm_agents.backends.base import GenerateConfig

logger = logging.getLogger(__name__)

#: Statuses worth retrying: request timeout, rate limit, and every server error.
TRANSIENT_STATUSES = frozenset({408, 429}) | frozenset(range(500, 600))


class RetryWaits(BaseModel):
    """How long to wait between attempts: backend options (the openai backend's inherit them)."""

    model_config = ConfigDict(extra="forbid")

    backoff_initial_s: float = Field(1.0, ge=0.0)
    """Wait before the first retry, doubled for each further one (before jitter)."""
    backoff_max_s: float = Field(60.0, ge=0.0)
    """Longest exponential wait, before jitter."""
    jitter_s: float = Field(1.0, ge=0.0)
    """Up to this many random seconds added to each exponential wait."""
    retry_after_max_s: float = Field(300.0, ge=0.0)
    """Longest wait a server's `Retry-After` may impose."""


class RetryPolicy(RetryWaits):
    """How often and how patiently a transient failure is retried (the limits have no defaults
    here: `GenerateConfig` declares them)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_retries: int = Field(ge=0)
    """Retries after the first attempt; 0 tries once."""
    attempt_timeout_s: float = Field(gt=0.0)
    """Longest one attempt may take, start to last byte."""

    @classmethod
    def for_generation(cls, config: GenerateConfig, waits: RetryWaits) -> RetryPolicy:
        """The policy a generation asks for: its limits (`max_retries`, `timeout_s`) always come
        from the `GenerateConfig`, only the waits between attempts from the backend's options."""
        return cls(
            max_retries=config.max_retries,
            attempt_timeout_s=config.timeout_s,
            **waits.model_dump(include=set(RetryWaits.model_fields)),
        )


class TransientError(Exception):
    """A failure that may pass if the same request is sent again."""

    def __init__(
        self, message: str, *, status: int | None = None, retry_after_s: float | None = None
    ):
        super().__init__(message)
        self.status = status
        """HTTP status, when the server answered at all."""
        self.retry_after_s = retry_after_s
        """The server's `Retry-After`, in seconds from now, when it sent one."""
        self.failover = False
        """Set when the failed server was taken out of its pool and another can take the retry
        now: the retry does not wait (it still counts as one)."""


def is_transient_status(status: int) -> bool:
    """Whether an HTTP status is worth retrying."""
    return status in TRANSIENT_STATUSES


def parse_retry_after(value: str | None, now: float | None = None) -> float | None:
    """Seconds to wait from a `Retry-After` header (delay seconds or an HTTP date); None if absent or unreadable."""
    if value is None or not value.strip():
        return None
    value = value.strip()
    try:
        seconds = float(value)
    except ValueError:
        try:
            when = email.utils.parsedate_to_datetime(value)
        except (TypeError, ValueError):
            return None
        seconds = when.timestamp() - (time.time() if now is None else now)
    if seconds != seconds:  # NaN never compares; a server sending it gets no say
        return None
    return max(0.0, seconds)


def backoff_wait(policy: RetryPolicy, attempt: int, retry_after_s: float | None = None) -> float:
    """Seconds to wait after failed attempt number `attempt` (1-based)."""
    exponential = min(policy.backoff_max_s, policy.backoff_initial_s * 2 ** (attempt - 1))
    wait = exponential + random.uniform(0.0, policy.jitter_s)
    if retry_after_s is not None:
        wait = max(wait, min(retry_after_s, policy.retry_after_max_s))
    return wait


def async_retrying(policy: RetryPolicy, description: str = "request") -> AsyncRetrying:
    """A tenacity controller for `async for attempt in ...` loops following the policy.

    When retries run out it raises `tenacity.RetryError`, whose `last_attempt` carries the attempt
    number and the final `TransientError`; a non-transient exception propagates unchanged.
    """

    def wait(state: RetryCallState) -> float:
        error = state.outcome.exception() if state.outcome else None
        if isinstance(error, TransientError) and error.failover:
            return 0.0
        retry_after = error.retry_after_s if isinstance(error, TransientError) else None
        return backoff_wait(policy, state.attempt_number, retry_after)

    def log_retry(state: RetryCallState) -> None:
        error = state.outcome.exception() if state.outcome else None
        sleep = state.next_action.sleep if state.next_action else 0.0
        logger.warning(
            "%s failed (attempt %d of %d): %s; retrying in %.2f s",
            description,
            state.attempt_number,
            policy.max_retries + 1,
            error,
            sleep,
        )

    return AsyncRetrying(
        retry=retry_if_exception_type(TransientError),
        stop=stop_after_attempt(policy.max_retries + 1),
        wait=wait,
        before_sleep=log_retry,
    )
