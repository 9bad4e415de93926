"""Backend for any OpenAI-compatible chat server: vLLM's `vllm serve`, or a hosted provider.

Spec: `openai:<model>@<base url>`, e.g. `openai:HuggingFaceTB/SmolLM2-135M-Instruct@http://127.0.0.1:8000/v1`;
without `@url` the base URL comes from `OPENAI_BASE_URL`. Several base URLs separated by commas
(`openai:M@http://a:8000/v1,http://b:8000/v1`) serve one model from several servers: each attempt
goes to the one with the fewest requests in flight, and a failing one is taken out of rotation
and health-checked until it answers again (`endpoints.py`). The API key is read from an environment
variable (`OPENAI_API_KEY` unless `api_key_env` names another) and is scrubbed from every error
and log line. Every request runs on one event loop in a background thread, through one client
that keeps its connections open, whichever thread calls the synchronous `generate` (a run calls
it from many at once); a call sends its conversations concurrently, at most `max_concurrency` in
flight. Transient failures are retried by the policy in `retry.py`.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import difflib
import json
import logging
import os
import socket
import threading
import time
import weakref
from collections.abc import Awaitable, Callable, Sequence
from typing import Any, ClassVar, TypeVar, TypeVarTuple
from urllib.parse import quote

# The backend registry turns a missing httpx into an install hint for the `openai` extra.
import httpx
import numpy as np
from anyio.from_thread import BlockingPortal, start_blocking_portal
from pydantic import ConfigDict, Field, SecretStr, ValidationError
from tenacity import RetryError

from env.errors import UserError
from llm_agents.backends.base import (
    PROBE_TIMEOUT_S,
    ChatMessage,
    ChoiceRule,
    ChoiceSet,
    Conversation,
    GenerateConfig,
    ImagePart,
    ModelAPI,
    ModelOutput,
    OutputSchema,
    bad_options,
    openai_message,
)
from llm_agents.backends.endpoints import Endpoint, EndpointPool, EndpointStats, takes_out
from llm_agents.backends.reasoning import generate_with_followup, with_reasoning_split
from llm_agents.backends.redaction import REDACTED, redact_secrets, split_urls
from llm_agents.backends.retry import (
    RetryPolicy,
    RetryWaits,
    TransientError,
    async_retrying,
    is_transient_status,
    parse_retry_after,
)

DEFAULT_API_KEY_ENV = "OPENAI_API_KEY"
#: How much of a server's error body is kept in an error message.
ERROR_BODY_CHARS = 300
#: Most model ids a probe lists when the requested one is not served.
LISTED_MODELS = 8
#: The shortest URL query value redacted from messages as a possible token.
MIN_SECRET_CHARS = 4

#: The name of the thread that runs the requests' event loop.
LOOP_THREAD_NAME = "openai-requests"

T = TypeVar("T")
Args = TypeVarTuple("Args")


class OpenAIOptions(RetryWaits):
    """Options of the openai backend (keyword arguments of `get_model`)."""

    model_config = ConfigDict(extra="forbid")

    base_url: str | None = None
    """Server root up to `/v1`, or several separated by commas (requests spread over them); None
    reads `OPENAI_BASE_URL`."""
    api_key_env: str = DEFAULT_API_KEY_ENV
    """Environment variable holding the API key; when the default one is unset no key is sent (local servers)."""
    structured_choice: bool = True
    """Constrain choice answers with the server's structured outputs; off, or after the server rejects it, choices are answered in free text."""
    extra_body: dict[str, Any] = Field(default_factory=dict)
    """Extra JSON fields merged into every request (server-specific sampling options)."""
    health_interval_s: float = Field(5.0, gt=0.0)
    """With several URLs: seconds between health checks of an endpoint taken out of rotation."""


class _RedactedURLs(logging.Filter):
    """httpx logs each request's URL, its query (where a token may ride) included: the
    record is rewritten through `redact_secrets` before any handler sees it."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        shown = redact_secrets(message)
        if shown != message:
            record.msg, record.args = shown, None
        return True


logging.getLogger("httpx").addFilter(_RedactedURLs())


class RequestFailed(Exception):
    """A request that failed for good, with a message fit for `ModelOutput.error`."""


class OpenAIModel(ModelAPI):
    """Chat completions over HTTP, concurrent, with retries of transient failures."""

    backend_name = "openai"
    options_model = OpenAIOptions
    # Everything but a thinking budget, which the chat API has no field for (a server-specific
    # one can go in `extra_body`).
    honoured_config = frozenset(GenerateConfig.model_fields) - {"reasoning_budget"}
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"guided"})
    choice_rule_gaps: ClassVar[dict[ChoiceRule, str]] = {
        "loglik": "chat completions return log-probabilities of generated tokens only, not of "
        "a given answer after the prompt; use the vllm backend (offline engine) or hf for loglik"
    }
    # Calls from many threads share the loop and its client; the server batches the requests.
    concurrent_requests = True

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        super().__init__(model_name, config, **options)
        try:
            self.settings = OpenAIOptions(**options)
        except ValidationError as err:
            raise bad_options("openai", err) from None
        base_url = self.settings.base_url or os.environ.get("OPENAI_BASE_URL")
        if not base_url:
            raise UserError(
                f"no server URL for openai:{model_name}; write openai:{model_name}@http://HOST:PORT/v1 "
                "or set OPENAI_BASE_URL"
            )
        self._auth: dict[str, httpx.BasicAuth | None] = {}
        self._params: dict[str, httpx.QueryParams] = {}
        self._url_secrets: list[SecretStr] = []
        for written_url in split_urls(base_url):
            self._add_endpoint(written_url)
        #: Every endpoint's URL, comma-separated, as messages and results name the server.
        self.base_url = ",".join(self._auth)
        self.pool = EndpointPool(
            list(self._auth), self._healthy, health_interval_s=self.settings.health_interval_s
        )
        key = os.environ.get(self.settings.api_key_env)
        # SecretStr keeps the key out of reprs, tracebacks' locals and debug dumps.
        self._api_key = SecretStr(key) if key else None
        if self._api_key is None and self.settings.api_key_env != DEFAULT_API_KEY_ENV:
            raise UserError(
                f"the API key variable {self.settings.api_key_env} named by api_key_env is not set"
            )
        # Flipped for good once the server rejects structured outputs, so later batches do not
        # pay a failed request each.
        self.structured_choice = self.settings.structured_choice
        # Built once: loading the CA bundle costs ~30 ms of CPU, and health checks open clients.
        self._ssl_context = httpx.create_ssl_context()
        self._portal = _Portal()
        # A backend dropped without `close()` still ends its loop's thread.
        weakref.finalize(self, self._portal.stop, wait=False)
        self._client: httpx.AsyncClient | None = None

    def _add_endpoint(self, written: str) -> None:
        if not written.startswith(("http://", "https://")):
            # What precedes an `@` may be credentials written without a scheme.
            shown = written.rpartition("@")[2]
            raise UserError(f"server URL {shown!r} must start with http:// or https://")
        try:
            url = httpx.URL(written.rstrip("/"))
        except httpx.InvalidURL as err:
            # httpx quotes the part it could not read, which may be a piece of a password:
            # only its kind of fault is kept.
            fault = str(err).partition(":")[0]
            raise UserError(
                f"server URL {redact_secrets(written)} is not a valid URL ({fault})"
            ) from None
        # Credentials in the URL travel as a Basic auth header instead, and its query (a token,
        # an API version) as each request's parameters, so that neither httpx's request log nor
        # any message shows them; they are then redacted like the key.
        bare = str(url.copy_with(userinfo=b"", query=None, fragment=None))
        if bare in self._auth:
            raise UserError(f"server URL {redact_secrets(written)} is listed twice")
        self._auth[bare] = httpx.BasicAuth(url.username, url.password) if url.userinfo else None
        self._params[bare] = url.params
        if url.userinfo:
            password = url.userinfo.decode("ascii", "replace").partition(":")[2]
            header = base64.b64encode(f"{url.username}:{url.password}".encode()).decode()
            self._url_secrets += [SecretStr(p) for p in {password, url.password, header} if p]
        # A value of a few characters (`v=2`) is no secret, and replacing it everywhere would
        # garble every message.
        self._url_secrets += [
            SecretStr(form)
            for _name, value in url.params.multi_items()
            if len(value) >= MIN_SECRET_CHARS
            for form in {value, quote(value, safe="")}
        ]

    @property
    def retry_policy(self) -> RetryPolicy:
        """Retry limits from the current `GenerateConfig` (read at each call), waits from options."""
        return RetryPolicy.for_generation(self.config, self.settings)

    def __repr__(self) -> str:
        return f"OpenAIModel(model={self.model_name!r}, base_url={self.base_url!r})"

    def info(self) -> dict[str, str]:
        return {**super().info(), "base_url": self.base_url, "httpx": httpx.__version__}

    def endpoint_stats(self) -> list[EndpointStats]:
        return self.pool.stats()

    def close(self) -> None:
        self.pool.close()
        if self._client is not None:
            self._portal.run(self._client.aclose)
            self._client = None
        self._portal.stop()

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        options = list(choices.options) if choices is not None else None
        return generate_with_followup(conversations, options, self._run)

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        # No free-text fallback: an answer the server did not hold to the schema is not the
        # answer the run asked for, so a rejected request is that conversation's error.
        return self._portal.run(self._generate_all, conversations, None, schema)

    def check_schema(self, schema: OutputSchema) -> None:
        """One one-token request under `schema` to every endpoint: a server that rejects
        `response_format` stops the run before it writes anything."""
        self._portal.run(self._check_schema, schema)

    async def _check_schema(self, schema: OutputSchema) -> None:
        timeout_s = min(self.config.timeout_s, PROBE_TIMEOUT_S)
        body = {
            **self._body([ChatMessage(role="user", content="Say OK.")], None, False, schema),
            "max_tokens": 1,
        }
        for base_url in self._auth:
            async with httpx.AsyncClient(
                base_url=base_url,
                timeout=httpx.Timeout(timeout_s),
                headers=self._headers(),
                auth=self._auth[base_url],
                params=self._params[base_url],
                verify=self._ssl_context,
            ) as client:
                reply = await self._probe_request(
                    client, base_url, "POST", "/chat/completions", body, timeout_s
                )
            if reply.status_code != 200:
                raise UserError(
                    f"the openai backend's server {base_url} rejects response_format with the "
                    f"{schema.name} JSON schema (HTTP {reply.status_code}: "
                    f"{self._excerpt(reply.text, 160)}): serve the model with structured outputs "
                    "(e.g. vllm serve), or leave --structured-output off"
                )

    def probe(self) -> None:
        """List the server's models and check ours is one; a one-token chat where none are listed.

        One attempt, no retries, at most `PROBE_TIMEOUT_S`: a dead port, a wrong model name or a
        refused key ends the start within seconds, with a one-line `UserError` naming the cause.
        """
        self._portal.run(self._probe)

    def check_choice_rule(self, rule: ChoiceRule) -> None:
        """As `ModelAPI.check_choice_rule`; `guided` also needs structured outputs left on: with
        `structured_choice=false` the answers come back in free text, held to nothing."""
        super().check_choice_rule(rule)
        if rule == "guided" and not self.settings.structured_choice:
            raise UserError(
                "the openai backend cannot constrain decoding with structured_choice=false: "
                "--choice guided needs the server's structured outputs (leave that option out)"
            )

    def check_images(self) -> None:
        """One one-token request carrying a small image: a server or model that takes no
        images refuses it, and the run stops before anything is written."""
        blank = ImagePart.from_frame(np.zeros((8, 8, 3), np.uint8))
        self.answers_quickly(
            [ChatMessage(role="user", content="Say OK.", images=(blank,))],
            "refuses a request with an image (a text-only model?)",
        )

    def _run(
        self, conversations: Sequence[Conversation], choices: list[str] | None
    ) -> list[ModelOutput]:
        return self._portal.run(self._generate_all, conversations, choices)

    def _shared_client(self) -> httpx.AsyncClient:
        """The client every request uses, made on the loop's thread on first use: a client per
        call opened a connection per request and cost the host 2.5 ms of CPU per request against
        1.4 ms (loopback server, 32 threads)."""
        if self._client is None:
            limit = self.config.max_concurrency
            self._client = httpx.AsyncClient(
                timeout=httpx.Timeout(self.config.timeout_s),
                # Callers may overlap (a run's many threads), so connections are not capped:
                # a capped pool would make requests queue for a connection, not for the server.
                limits=httpx.Limits(max_connections=None, max_keepalive_connections=limit),
                headers=self._headers(),
                verify=self._ssl_context,
            )
        return self._client

    async def _generate_all(
        self,
        conversations: Sequence[Conversation],
        choices: list[str] | None,
        schema: OutputSchema | None = None,
    ) -> list[ModelOutput]:
        client = self._shared_client()
        semaphore = asyncio.Semaphore(self.config.max_concurrency)

        async def one(conversation: Conversation) -> ModelOutput:
            async with semaphore:
                return await self._generate_one(client, conversation, choices, schema)

        return list(await asyncio.gather(*(one(c) for c in conversations)))

    def _headers(self) -> dict[str, str]:
        if self._api_key is None:
            return {}
        return {"Authorization": f"Bearer {self._api_key.get_secret_value()}"}

    async def _generate_one(
        self,
        client: httpx.AsyncClient,
        conversation: Conversation,
        choices: list[str] | None,
        schema: OutputSchema | None = None,
    ) -> ModelOutput:
        start = time.perf_counter()
        constrained = bool(choices) and self.structured_choice
        try:
            try:
                reply = await self._post_with_retries(
                    client, self._body(conversation, choices, constrained, schema)
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
            output = self._parse_reply(reply, choices)
        except (RequestFailed, _Rejected) as failure:
            return self._failed(str(failure), start)
        except Exception as unexpected:  # one odd reply must not lose the rest of the batch
            return self._failed(f"{type(unexpected).__name__}: {unexpected}", start)
        output.latency_s = time.perf_counter() - start
        return output

    def _failed(self, cause: str, start: float) -> ModelOutput:
        return ModelOutput(
            text="",
            finish_reason="error",
            error=self._excerpt(cause, limit=2 * ERROR_BODY_CHARS),
            latency_s=time.perf_counter() - start,
        )

    def _body(
        self,
        conversation: Conversation,
        choices: list[str] | None,
        constrained: bool,
        schema: OutputSchema | None = None,
    ) -> dict[str, Any]:
        config = self.config
        body: dict[str, Any] = {
            "model": self.model_name,
            "messages": [openai_message(m) for m in conversation],
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
        if schema is not None:
            body["response_format"] = {
                "type": "json_schema",
                "json_schema": {"name": schema.name, "schema": schema.as_data(), "strict": True},
            }
        return body

    async def _post_with_retries(
        self, client: httpx.AsyncClient, body: dict[str, Any]
    ) -> dict[str, Any]:
        url = (
            f"{self.base_url}/chat/completions"
            if len(self._auth) == 1
            else f"/chat/completions on {self.base_url}"
        )
        policy = self.retry_policy
        try:
            async for attempt in async_retrying(policy, f"POST {url}"):
                with attempt:
                    return await self._attempt(client, body, policy.attempt_timeout_s)
        except RetryError as exhausted:
            last = exhausted.last_attempt
            raise RequestFailed(
                f"POST {url} failed after {last.attempt_number} attempts: {last.exception()}"
            ) from None
        raise AssertionError("tenacity returned without a result")  # pragma: no cover

    async def _attempt(
        self, client: httpx.AsyncClient, body: dict[str, Any], timeout_s: float
    ) -> dict[str, Any]:
        """One attempt, on the endpoint the pool picks; the outcome goes back to the pool."""
        endpoint = self.pool.acquire()
        started = time.perf_counter()
        try:
            reply = await self._post_once(client, endpoint.url, body, timeout_s)
        except TransientError as err:
            err.failover = self.pool.failed(endpoint, take_out=takes_out(err.status))
            if len(self.pool.endpoints) > 1:
                err.args = (f"{endpoint.url}: {err}",)
            raise
        except _Rejected:
            self.pool.failed(endpoint, take_out=False)
            raise
        except BaseException:
            self.pool.released(endpoint)
            raise
        self.pool.succeeded(endpoint, time.perf_counter() - started)
        return reply

    async def _post_once(
        self, client: httpx.AsyncClient, base_url: str, body: dict[str, Any], timeout_s: float
    ) -> dict[str, Any]:
        try:
            # httpx's timeout bounds each read; this bounds the whole request, so a server that
            # trickles bytes cannot hold a slot for ever.
            async with asyncio.timeout(timeout_s):
                response = await client.post(
                    f"{base_url}/chat/completions",
                    json=body,
                    params=self._params[base_url],
                    auth=self._auth[base_url] or httpx.USE_CLIENT_DEFAULT,
                )
        except (TimeoutError, httpx.TimeoutException):
            raise TransientError(f"no answer within {timeout_s:g} s") from None
        except httpx.TransportError as err:
            raise TransientError(
                self._excerpt(
                    f"connection failed ({type(err).__name__}: {err or 'closed by the server'})"
                )
            ) from None
        status = response.status_code
        if status >= 400:
            message = f"HTTP {status}: {self._excerpt(response.text)}"
            if is_transient_status(status):
                retry_after = parse_retry_after(response.headers.get("retry-after"))
                raise TransientError(message, status=status, retry_after_s=retry_after)
            raise _Rejected(f"POST {base_url}/chat/completions rejected, not retried: {message}")
        try:
            reply = response.json()
        except (json.JSONDecodeError, UnicodeDecodeError):
            # A cut or garbled body from a proxy or an overloaded server; worth another try.
            raise TransientError(
                f"HTTP {status} with a body that is not JSON: {self._excerpt(response.text, 80)!r}"
            ) from None
        if not isinstance(reply, dict):
            raise TransientError(f"HTTP {status} with a JSON body that is not an object")
        return reply

    def _redact(self, text: str) -> str:
        for secret in (self._api_key, *self._url_secrets):
            if secret is None:
                continue
            value = secret.get_secret_value()
            # A JSON body may carry the secret escaped (quotes, backslashes, non-ASCII).
            for form in {
                value,
                json.dumps(value)[1:-1],
                json.dumps(value, ensure_ascii=False)[1:-1],
            }:
                text = text.replace(form, REDACTED)
        return text

    def _excerpt(self, text: str, limit: int = ERROR_BODY_CHARS) -> str:
        """Server text fit for an error or a log line: the key removed first, then one line, cut.

        Redacting after the cut would miss a key the cut splits, so the order matters.
        """
        line = " ".join(self._redact(text).split())
        return line if len(line) <= limit else line[:limit] + "..."

    def _parse_reply(self, reply: dict[str, Any], choices: list[str] | None) -> ModelOutput:
        try:
            return _parse_reply(reply, choices)
        except (KeyError, IndexError, TypeError, AttributeError, ValueError):
            raise RequestFailed(
                f"the server's answer is not a chat completion: {self._excerpt(json.dumps(reply))}"
            ) from None

    # ------------------------------------------------------------------ probe

    async def _probe(self) -> None:
        # Every endpoint must pass: a wrong URL among several is a mistake to fix before the run.
        await asyncio.gather(*(self._probe_endpoint(url) for url in self._auth))

    async def _probe_endpoint(self, base_url: str) -> None:
        timeout_s = min(self.config.timeout_s, PROBE_TIMEOUT_S)
        async with httpx.AsyncClient(
            base_url=base_url,
            timeout=httpx.Timeout(timeout_s),
            headers=self._headers(),
            auth=self._auth[base_url],
            params=self._params[base_url],
        ) as client:
            listing = await self._probe_request(client, base_url, "GET", "/models", None, timeout_s)
            served = _served_models(listing) if listing.status_code == 200 else None
            if served is not None:
                self._check_served(served, base_url)
                return
            if listing.status_code not in (404, 405, 200):
                self._probe_refused(listing, base_url, "GET /models")
            # No model list here: one real request of a single token tells as much.
            body = {
                "model": self.model_name,
                "messages": [{"role": "user", "content": "Say OK."}],
                "max_tokens": 1,
                **self.settings.extra_body,
            }
            chat = await self._probe_request(
                client, base_url, "POST", "/chat/completions", body, timeout_s
            )
            if chat.status_code != 200:
                self._probe_refused(
                    chat, base_url, f"a one-token request to model {self.model_name!r}"
                )

    def _healthy(self, endpoint: Endpoint) -> bool:
        """A health check of an endpoint out of rotation: any answer but a 5xx to `GET /models`."""
        try:
            response = httpx.get(
                f"{endpoint.url}/models",
                headers=self._headers(),
                auth=self._auth[endpoint.url],
                params=self._params[endpoint.url],
                timeout=min(self.config.timeout_s, PROBE_TIMEOUT_S),
                verify=self._ssl_context,
            )
        except httpx.HTTPError:
            return False
        return response.status_code < 500

    async def _probe_request(
        self,
        client: httpx.AsyncClient,
        base_url: str,
        method: str,
        path: str,
        body: dict[str, Any] | None,
        timeout_s: float,
    ) -> httpx.Response:
        try:
            # Bounds name resolution too, which httpx's own timeout does not.
            async with asyncio.timeout(timeout_s):
                return await client.request(method, path, json=body)
        except (TimeoutError, httpx.TimeoutException):
            raise UserError(
                f"no answer from {base_url} within {timeout_s:g} s: check the URL and "
                "that the server is up"
            ) from None
        except httpx.TransportError as err:
            cause = self._excerpt(_transport_cause(err), 120)
            raise UserError(
                f"cannot reach {base_url}: {cause}; check the URL and that the server is up"
            ) from None

    def _probe_refused(self, response: httpx.Response, base_url: str, what: str) -> None:
        status = response.status_code
        excerpt = self._excerpt(response.text, 160)
        if status in (401, 403):
            env = self.settings.api_key_env
            advice = (
                f"no key was sent: set {env}"
                if self._api_key is None
                else f"check the key in {env}"
            )
            raise UserError(
                f"{base_url} refused the API key (HTTP {status}): {advice}; server said: {excerpt}"
            )
        if status >= 500:
            raise UserError(f"{base_url} failed {what} (HTTP {status}): {excerpt}")
        raise UserError(f"{base_url} refused {what} (HTTP {status}): {excerpt}")

    def _check_served(self, served: list[str], base_url: str) -> None:
        if self.model_name in served:
            return
        close = difflib.get_close_matches(self.model_name, served, n=3, cutoff=0.4)
        hint = f"; did you mean {' or '.join(repr(m) for m in close)}?" if close else ""
        shown = ", ".join(served[:LISTED_MODELS]) + (" ..." if len(served) > LISTED_MODELS else "")
        raise UserError(
            f"model {self.model_name!r} is not served at {base_url}{hint} "
            f"(served: {shown or 'none'})"
        )


class _Rejected(Exception):
    """The server refused the request itself (a 4xx other than 429): retrying cannot help."""


class _Portal:
    """anyio's blocking portal (an event loop in a daemon thread), opened on first use.

    Synchronous callers on any thread (also one already inside a running loop, as in a
    notebook) hand it coroutine functions and wait for their results.
    """

    def __init__(self) -> None:
        self._opened: (
            tuple[contextlib.AbstractContextManager[BlockingPortal], BlockingPortal] | None
        ) = None
        self._lock = threading.Lock()

    def run(self, work: Callable[[*Args], Awaitable[T]], *args: *Args) -> T:
        future = self._portal().start_task_soon(work, *args)
        try:
            return future.result()
        except BaseException:
            # An interrupted caller does not leave its requests running.
            future.cancel()
            raise

    def stop(self, *, wait: bool = True) -> None:
        """Stop the loop; `wait` for its thread to end, else (a finalizer, on any thread) only
        ask it to."""
        with self._lock:
            opened, self._opened = self._opened, None
        if opened is None:
            return
        manager, portal = opened
        if wait:
            manager.__exit__(None, None, None)
        else:
            # On the loop's own thread the portal refuses; its daemon thread ends with the process.
            with contextlib.suppress(RuntimeError):
                portal.start_task_soon(portal.stop)

    def _portal(self) -> BlockingPortal:
        with self._lock:
            if self._opened is None:
                manager = start_blocking_portal(name=LOOP_THREAD_NAME)
                self._opened = (manager, manager.__enter__())
            return self._opened[1]


def _transport_cause(err: BaseException) -> str:
    """The root cause of a transport error: httpx often says only "All connection attempts
    failed", while the OS error it wraps says "Connection refused" or names the DNS failure."""
    cause: BaseException | None = err
    while cause is not None:
        if isinstance(cause, socket.gaierror):
            return f"cannot resolve the host name ({cause.strerror or cause})"
        if isinstance(cause, OSError) and cause.errno:
            # asyncio's own strerror ("Connect call failed (...)") hides the reason; errno has it.
            return os.strerror(cause.errno).lower()
        cause = cause.__cause__ or cause.__context__
    return str(err) or type(err).__name__


def _served_models(response: httpx.Response) -> list[str] | None:
    """Model ids from a `GET /models` answer; None when the body is not such a list."""
    try:
        data = response.json()["data"]
        return [str(entry["id"]) for entry in data]
    except (ValueError, KeyError, TypeError):
        return None


def _computed_prompt_tokens(usage: dict[str, Any], prompt_tokens: int) -> int | None:
    """Prompt tokens the server computed: all but those its prefix cache served
    (`usage.prompt_tokens_details.cached_tokens`, which OpenAI's API gives and `vllm serve`
    gives when started with `--enable-prompt-tokens-details`); None where it does not say."""
    details = usage.get("prompt_tokens_details")
    cached = details.get("cached_tokens") if isinstance(details, dict) else None
    if not isinstance(cached, int):
        return None
    return max(0, prompt_tokens - cached)


def _parse_reply(reply: dict[str, Any], choices: list[str] | None) -> ModelOutput:
    """Read a chat completion; raises KeyError, TypeError or ValueError on any other shape."""
    choice = reply["choices"][0]
    message = choice["message"]
    text = message.get("content") or ""
    if not isinstance(text, str):
        raise TypeError("content is not text")
    usage = reply.get("usage") or {}
    prompt_tokens = int(usage.get("prompt_tokens") or 0)
    output = ModelOutput(
        text=text,
        prompt_tokens=prompt_tokens,
        computed_prompt_tokens=_computed_prompt_tokens(usage, prompt_tokens),
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
