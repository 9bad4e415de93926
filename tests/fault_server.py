"""A fault-injecting OpenAI-compatible chat server on loopback, for the HTTP backend's tests.

Faults are planned per conversation (keyed by the last message's text), so a plan holds even
when requests arrive concurrently and in any order. Each request pops the next fault of its key;
when a key's plan is empty the server answers normally. The server only ever binds 127.0.0.1 and
refuses to serve more than `max_requests` requests, so a retry loop gone wrong stays bounded.

Run as a script (`python tests/fault_server.py --latency 0.05 --capacity 4`) it is a server of its
own process, printing its URL: one that can be killed like a real one (`--die-after N` exits on
the Nth chat request, dropping every connection), or a fixed-latency server for benchmarks.
Benchmarks that need their own answers (a heavy-tailed latency, a proxy to `vllm serve`) start it
in a process of theirs with an `answer` function; `GET /stats` hands such a process's caller the
answers' timings. This is the one OpenAI-compatible loopback server of the tests and benchmarks.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Literal
from urllib.parse import urlsplit

FaultKind = Literal["drop", "status", "slow", "malformed", "echo_auth"]


@dataclass(frozen=True)
class Fault:
    """What the server does to one request instead of answering it normally."""

    kind: FaultKind
    status: int = 500
    """HTTP status for `status` faults."""
    retry_after: str | None = None
    """`Retry-After` header value for `status` faults."""
    delay_s: float = 0.0
    """Seconds a `slow` fault waits before answering normally."""
    body: str = ""
    """Extra text in a `status` fault's body."""
    pad: int = 0
    """Characters before the echoed Authorization header in an `echo_auth` fault's body."""
    as_json: bool = False
    """Whether an `echo_auth` fault's body is a JSON object (else plain text)."""


@dataclass(frozen=True)
class Request:
    """One request as the server saw it."""

    key: str
    body: dict[str, Any]
    headers: dict[str, str]
    received_at: float
    #: The client's (host, port): one per connection.
    connection: tuple[str, int] = ("", 0)
    #: The request's path, its query included.
    path: str = ""


@dataclass(frozen=True)
class Answer:
    """When one normal answer was worked on (monotonic seconds of the server's process)."""

    key: str
    started_at: float
    ended_at: float


#: Request body -> the answer's message; a `finish_reason` key in it sets the choice's.
Answerer = Callable[[dict[str, Any]], dict[str, Any]]


def echo_answer(body: dict[str, Any]) -> dict[str, Any]:
    """Echoes the last message; under a structured choice, picks the last choice."""
    choice = (body.get("structured_outputs") or {}).get("choice")
    content = choice[-1] if choice else f"echo: {body['messages'][-1]['content']}"
    return {"role": "assistant", "content": content}


class _Server(ThreadingHTTPServer):
    # A real server's backlog: the default of 5 resets connections when a client opens many at
    # once (a run's 32 in flight), and the client would retry them.
    request_queue_size = 1024
    daemon_threads = True


@dataclass
class FaultServer:
    """The server's state; `url` is the base URL to give the backend (ends in /v1)."""

    plan: dict[str, list[Fault]] = field(default_factory=dict)
    answer: Answerer = echo_answer
    reject_structured_outputs: bool = False
    """Answer 400 to any request asking for structured outputs, like a server that lacks them."""
    echo_authorization: bool = False
    """Put the request's Authorization header in every error body, like a careless proxy."""
    models: list[str] | None = None
    """Model ids `GET /models` lists; None answers it 404, like a server without the endpoint."""
    required_key: str | None = None
    """When set, every request without `Authorization: Bearer <key>` gets a 401."""
    max_requests: int = 200
    latency_s: float = 0.0
    """Every normal answer waits this long, like a model generating."""
    capacity: int | None = None
    """At most this many answers generated at once (others queue), like one GPU's batch."""
    die_after: int | None = None
    """The process exits at once on this chat request (a script server only: kills the tests)."""
    port: int = 0
    """Port to bind on 127.0.0.1; 0 picks a free one."""
    requests: list[Request] = field(default_factory=list)
    answers: list[Answer] = field(default_factory=list)
    """Normal answers, in the order they ended; `GET /stats` returns and clears them."""
    in_flight: int = 0
    max_in_flight: int = 0
    url: str = ""
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _httpd: ThreadingHTTPServer | None = None
    _slots: threading.BoundedSemaphore | None = None

    def count(self, key: str) -> int:
        """Requests received for one conversation key."""
        return sum(1 for r in self.requests if r.key == key)

    def times(self, key: str) -> list[float]:
        """Arrival times (monotonic) of the requests for one conversation key."""
        return [r.received_at for r in self.requests if r.key == key]

    def start(self) -> FaultServer:
        state = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            # As real servers do: otherwise a body written after its headers waits for the
            # client's delayed ACK (40 ms) on a kept-alive connection.
            disable_nagle_algorithm = True

            def log_message(self, format: str, *args: Any) -> None:
                return None

            def _authorised(self) -> bool:
                if state.required_key is None:
                    return True
                if self.headers.get("Authorization") == f"Bearer {state.required_key}":
                    return True
                self._send(401, self._error("invalid API key"))
                return False

            def do_GET(self) -> None:
                with state._lock:
                    state.requests.append(
                        Request(
                            f"GET {self.path}",
                            {},
                            dict(self.headers.items()),
                            time.monotonic(),
                            path=self.path,
                        )
                    )
                if not self._authorised():
                    return
                # Routed on the path alone: a server URL may carry a query (an API version, a token).
                route = urlsplit(self.path).path.rstrip("/")
                if route.endswith("/stats"):
                    with state._lock:
                        taken, state.answers = state.answers, []
                    self._send(200, [[a.started_at, a.ended_at, a.key] for a in taken])
                    return
                if route.endswith("/models") and state.models is not None:
                    listing = [{"id": model, "object": "model"} for model in state.models]
                    self._send(200, {"object": "list", "data": listing})
                    return
                self._send(404, self._error(f"no route {self.path}"))

            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                body = json.loads(self.rfile.read(length) or b"{}")
                if not self._authorised():
                    return
                key = str(body.get("messages", [{}])[-1].get("content", ""))
                with state._lock:
                    if state.die_after is not None and len(state.requests) + 1 >= state.die_after:
                        os._exit(1)
                    if len(state.requests) >= state.max_requests:
                        self._send(503, {"error": "fault server request budget spent"})
                        return
                    state.requests.append(
                        Request(
                            key,
                            body,
                            dict(self.headers.items()),
                            time.monotonic(),
                            self.client_address,
                            self.path,
                        )
                    )
                    pending = state.plan.get(key)
                    fault = pending.pop(0) if pending else None
                    state.in_flight += 1
                    state.max_in_flight = max(state.max_in_flight, state.in_flight)
                try:
                    self._serve(key, body, fault)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up first, as a timed-out client does
                finally:
                    with state._lock:
                        state.in_flight -= 1

            def _serve(self, key: str, body: dict[str, Any], fault: Fault | None) -> None:
                started = time.monotonic()
                if fault is not None and fault.kind == "drop":
                    self.close_connection = True
                    self.connection.shutdown(socket.SHUT_RDWR)
                    return
                if fault is not None and fault.kind == "status":
                    headers = {"Retry-After": fault.retry_after} if fault.retry_after else {}
                    self._send(
                        fault.status, self._error(f"injected {fault.status} {fault.body}"), headers
                    )
                    return
                if fault is not None and fault.kind == "slow":
                    time.sleep(fault.delay_s)
                if fault is not None and fault.kind == "echo_auth":
                    echoed = "x" * fault.pad + f"{self.headers.get('Authorization')} and more text"
                    if fault.as_json:
                        self._send(fault.status, {"detail": echoed})
                    else:
                        self._send_raw(fault.status, echoed.encode())
                    return
                if fault is not None and fault.kind == "malformed":
                    self._send_raw(200, b'{"choices": [{"message": ')
                    return
                if state.reject_structured_outputs and (
                    "structured_outputs" in body or "response_format" in body
                ):
                    self._send(400, self._error("unknown field structured_outputs"))
                    return
                if state.latency_s:
                    if state._slots is None:
                        time.sleep(state.latency_s)
                    else:
                        with state._slots:
                            time.sleep(state.latency_s)
                message = dict(state.answer(body))
                finish = message.pop("finish_reason", "stop")
                with state._lock:
                    state.answers.append(Answer(key, started, time.monotonic()))
                self._send(
                    200,
                    {
                        "object": "chat.completion",
                        "model": body.get("model"),
                        "choices": [{"index": 0, "message": message, "finish_reason": finish}],
                        "usage": {"prompt_tokens": 7, "completion_tokens": 3, "total_tokens": 10},
                    },
                )

            def _error(self, message: str) -> dict[str, Any]:
                if state.echo_authorization:
                    message += f" (you sent Authorization: {self.headers.get('Authorization')})"
                return {"error": {"message": message}}

            def _send(
                self, status: int, payload: Any, headers: dict[str, str] | None = None
            ) -> None:
                self._send_raw(status, json.dumps(payload).encode(), headers)

            def _send_raw(
                self, status: int, data: bytes, headers: dict[str, str] | None = None
            ) -> None:
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                for name, value in (headers or {}).items():
                    self.send_header(name, value)
                self.end_headers()
                self.wfile.write(data)

        if self.capacity is not None:
            self._slots = threading.BoundedSemaphore(self.capacity)
        httpd = _Server(("127.0.0.1", self.port), Handler)
        self._httpd = httpd
        # A short poll keeps shutdown (once per test) quick.
        threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True).start()
        self.url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
        return self

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None


def main() -> None:
    parser = argparse.ArgumentParser(description="a loopback OpenAI-compatible test server")
    parser.add_argument("--latency", type=float, default=0.0, help="seconds per answer")
    parser.add_argument("--capacity", type=int, help="answers generated at once")
    parser.add_argument("--die-after", type=int, help="exit on this chat request")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--max-requests", type=int, default=1_000_000)
    args = parser.parse_args()
    server = FaultServer(
        latency_s=args.latency,
        capacity=args.capacity,
        die_after=args.die_after,
        port=args.port,
        max_requests=args.max_requests,
    ).start()
    print(server.url, flush=True)
    threading.Event().wait()


if __name__ == "__main__":
    main()
