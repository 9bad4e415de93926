"""Backend for any OpenAI-compatible chat server: vLLM's `vllm serve`, or a hosted provider.

Spec: `openai:<model>@<base url>`, e.g. `openai:HuggingFaceTB/SmolLM2-135M-Instruct@http://127.0.0.1:8000/v1`;
without `@url` the base URL comes from `OPENAI_BASE_URL`. The API key is read from an environment
variable (`OPENAI_API_KEY` unless `api_key_env` names another) and is scrubbed from every error
and log line. Requests run concurrently (at most `max_concurrency` in flight) on an event loop
inside the synchronous `generate`; transient failures are retried by the policy in `retry.py`.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import os
import time
from collections.abc import Sequence
from typing import Any

# The backend registry turns a missing httpx into an install hint for the `openai` extra.
import httpx
from pydantic import BaseModel, ConfigDict, Field, SecretStr, ValidationError
from tenacity import RetryError

from env.errors import UserError
from llm_agents.backends.base import (
    Conversation,
    GenerateConfig,
    ModelAPI,
    ModelOutput,
)
from llm_agents.backends.reasoning import generate_with_followup, with_reasoning_split
from llm_agents.backends.retry import (
    RetryPolicy,
    TransientError,
    async_retrying,
    is_transient_status,
    parse_retry_after,
)

DEFAULT_API_KEY_ENV = "OPENAI_API_KEY"
#: How much of a server's error body is kept in an error message.
ERROR_BODY_CHARS = 300


class OpenAIOptions(BaseModel):
    """Options of the openai backend (keyword arguments of `get_model`)."""

    model_config = ConfigDict(extra="forbid")

    base_url: str | None = None
    """Server root up to `/v1`; None reads `OPENAI_BASE_URL`."""
    api_key_env: str = DEFAULT_API_KEY_ENV
    """Environment variable holding the API key; when the default one is unset no key is sent (local servers)."""
    backoff_initial_s: float = Field(1.0, ge=0.0)
    """Wait before the first retry, doubled for each further one."""
    backoff_max_s: float = Field(60.0, ge=0.0)
    """Longest exponential wait between retries."""
    jitter_s: float = Field(1.0, ge=0.0)
    """Up to this many random seconds added to each wait."""
    retry_after_max_s: float = Field(300.0, ge=0.0)
    """Longest wait a server's `Retry-After` may impose."""
    structured_choice: bool = True
    """Constrain choice answers with the server's structured outputs; off, or after the server rejects it, choices are answered in free text."""
    extra_body: dict[str, Any] = Field(default_factory=dict)
    """Extra JSON fields merged into every request (server-specific sampling options)."""


class RequestFailed(Exception):
    """A request that failed for good, with a message fit for `ModelOutput.error`."""


class OpenAIModel(ModelAPI):
    """Chat completions over HTTP, concurrent, with retries of transient failures."""

    backend_name = "openai"
    # Each `generate` call runs its own event loop and client, so calls from threads are
    # independent; the server batches the requests.
    concurrent_requests = True

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        super().__init__(model_name, config, **options)
        try:
            self.settings = OpenAIOptions(**options)
        except ValidationError as err:
            raise UserError(f"bad option for the openai backend: {err}") from err
        base_url = self.settings.base_url or os.environ.get("OPENAI_BASE_URL")
        if not base_url:
            raise UserError(
                f"no server URL for openai:{model_name}; write openai:{model_name}@http://HOST:PORT/v1 "
                "or set OPENAI_BASE_URL"
            )
        if not base_url.startswith(("http://", "https://")):
            raise UserError(f"server URL {base_url!r} must start with http:// or https://")
        self.base_url = base_url.rstrip("/")
        key = os.environ.get(self.settings.api_key_env)
        # SecretStr keeps the key out of reprs, tracebacks' locals and debug dumps.
        self._api_key = SecretStr(key) if key else None
        if self._api_key is None and self.settings.api_key_env != DEFAULT_API_KEY_ENV:
            raise UserError(
                f"the API key variable {self.settings.api_key_env} named by api_key_env is not set"
            )
        self.retry_policy = RetryPolicy(
            max_retries=self.config.max_retries,
            backoff_initial_s=self.settings.backoff_initial_s,
            backoff_max_s=self.settings.backoff_max_s,
            jitter_s=self.settings.jitter_s,
            retry_after_max_s=self.settings.retry_after_max_s,
        )
        # Flipped for good once the server rejects structured outputs, so later batches do not
        # pay a failed request each.
        self.structured_choice = self.settings.structured_choice
        # Built once: loading the CA bundle costs ~30 ms of CPU, and every `generate` call
        # opens a client (the runner makes one call per request, many at a time).
        self._ssl_context = httpx.create_ssl_context()

    def __repr__(self) -> str:
        return f"OpenAIModel(model={self.model_name!r}, base_url={self.base_url!r})"

    def info(self) -> dict[str, str]:
        return {**super().info(), "base_url": self.base_url, "httpx": httpx.__version__}

    def generate(
        self,
        conversations: Sequence[Conversation],
        choices: Sequence[str] | None = None,
    ) -> list[ModelOutput]:
        return generate_with_followup(conversations, choices, self._run)

    def _run(
        self, conversations: Sequence[Conversation], choices: list[str] | None
    ) -> list[ModelOutput]:
        batch = self._generate_all(conversations, choices)
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return asyncio.run(batch)
        # Called from inside a running loop (a notebook, an async caller): that loop cannot be
        # re-entered, so the batch gets its own loop on a worker thread.
        with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
            return pool.submit(asyncio.run, batch).result()

    async def _generate_all(
        self, conversations: Sequence[Conversation], choices: list[str] | None
    ) -> list[ModelOutput]:
        limit = self.config.max_concurrency
        timeout = httpx.Timeout(self.config.timeout_s)
        limits = httpx.Limits(max_connections=limit, max_keepalive_connections=limit)
        semaphore = asyncio.Semaphore(limit)
        async with httpx.AsyncClient(
            base_url=self.base_url,
            timeout=timeout,
            limits=limits,
            headers=self._headers(),
            verify=self._ssl_context,
        ) as client:

            async def one(conversation: Conversation) -> ModelOutput:
                async with semaphore:
                    return await self._generate_one(client, conversation, choices)

            return list(await asyncio.gather(*(one(c) for c in conversations)))

    def _headers(self) -> dict[str, str]:
        if self._api_key is None:
            return {}
        return {"Authorization": f"Bearer {self._api_key.get_secret_value()}"}

    async def _generate_one(
        self, client: httpx.AsyncClient, conversation: Conversation, choices: list[str] | None
    ) -> ModelOutput:
        start = time.perf_counter()
        constrained = bool(choices) and self.structured_choice
        try:
            try:
                reply = await self._post_with_retries(
                    client, self._body(conversation, choices, constrained)
                )
            except _Rejected:
                if not constrained:
                    raise
                # Perhaps the server does not know structured outputs: ask again in free text,
                # and stop asking for them only once the free-text request goes through.
                reply = await self._post_with_retries(
                    client, self._body(conversation, choices, False)
                )
                self.structured_choice = False
            output = _parse_reply(reply, choices)
        except (RequestFailed, _Rejected) as failure:
            return ModelOutput(
                text="",
                finish_reason="error",
                error=self._redact(str(failure)),
                latency_s=time.perf_counter() - start,
            )
        output.latency_s = time.perf_counter() - start
        return output

    def _body(
        self, conversation: Conversation, choices: list[str] | None, constrained: bool
    ) -> dict[str, Any]:
        config = self.config
        body: dict[str, Any] = {
            "model": self.model_name,
            "messages": [{"role": m.role, "content": m.content} for m in conversation],
            "max_tokens": config.max_tokens,
            "temperature": config.temperature,
            "top_p": config.top_p,
        }
        if config.sampling_seed is not None:
            body["seed"] = config.sampling_seed
        if config.stop:
            body["stop"] = config.stop
        body.update(self.settings.extra_body)
        if choices and constrained:
            body["structured_outputs"] = {"choice": choices}
        return body

    async def _post_with_retries(
        self, client: httpx.AsyncClient, body: dict[str, Any]
    ) -> dict[str, Any]:
        url = f"{self.base_url}/chat/completions"
        try:
            async for attempt in async_retrying(self.retry_policy, f"POST {url}"):
                with attempt:
                    return await self._post_once(client, body)
        except RetryError as exhausted:
            last = exhausted.last_attempt
            raise RequestFailed(
                f"POST {url} failed after {last.attempt_number} attempts: {last.exception()}"
            ) from None
        raise AssertionError("tenacity returned without a result")  # pragma: no cover

    async def _post_once(self, client: httpx.AsyncClient, body: dict[str, Any]) -> dict[str, Any]:
        timeout_s = self.config.timeout_s
        try:
            # httpx's timeout bounds each read; this bounds the whole request, so a server that
            # trickles bytes cannot hold a slot for ever.
            async with asyncio.timeout(timeout_s):
                response = await client.post("/chat/completions", json=body)
        except (TimeoutError, httpx.TimeoutException):
            raise TransientError(f"no answer within {timeout_s:g} s") from None
        except httpx.TransportError as err:
            raise TransientError(
                f"connection failed ({type(err).__name__}: {err or 'closed by the server'})"
            ) from None
        status = response.status_code
        if status >= 400:
            message = f"HTTP {status}: {self._redact(response.text[:ERROR_BODY_CHARS])}"
            if is_transient_status(status):
                retry_after = parse_retry_after(response.headers.get("retry-after"))
                raise TransientError(message, status=status, retry_after_s=retry_after)
            raise _Rejected(
                f"POST {self.base_url}/chat/completions rejected, not retried: {message}"
            )
        try:
            reply = response.json()
        except (json.JSONDecodeError, UnicodeDecodeError):
            # A cut or garbled body from a proxy or an overloaded server; worth another try.
            raise TransientError(
                f"HTTP {status} with a body that is not JSON: {response.text[:80]!r}"
            ) from None
        if not isinstance(reply, dict):
            raise TransientError(f"HTTP {status} with a JSON body that is not an object")
        return reply

    def _redact(self, text: str) -> str:
        if self._api_key is not None:
            text = text.replace(self._api_key.get_secret_value(), "***")
        return text


class _Rejected(Exception):
    """The server refused the request itself (a 4xx other than 429): retrying cannot help."""


def _parse_reply(reply: dict[str, Any], choices: list[str] | None) -> ModelOutput:
    try:
        choice = reply["choices"][0]
        message = choice["message"]
        text = message.get("content") or ""
    except (KeyError, IndexError, TypeError, AttributeError):
        raise RequestFailed(
            f"the server's answer has no choices[0].message: {json.dumps(reply)[:ERROR_BODY_CHARS]}"
        ) from None
    usage = reply.get("usage") or {}
    output = ModelOutput(
        text=text,
        prompt_tokens=int(usage.get("prompt_tokens") or 0),
        completion_tokens=int(usage.get("completion_tokens") or 0),
        finish_reason="length" if choice.get("finish_reason") == "length" else "stop",
    )
    # vLLM's reasoning parsers fill `reasoning_content` (older) or `reasoning` (newer); servers
    # without one leave the thinking inline, in <think> tags.
    reasoning = message.get("reasoning_content") or message.get("reasoning") or None
    output = with_reasoning_split(output, reasoning=reasoning)
    if choices is not None and output.text in choices:
        output.finish_reason = "choice"
    return output
