"""Time to failure of the start-of-run probe (`ModelAPI.probe`) for the openai backend, on loopback.

Cases: a dead port (connection refused), a host name that does not resolve, a server that
accepts connections but never answers (the probe's timeout), a wrong model name (the server's
`GET /models` lists others), a refused API key, and, for scale, a probe that passes. Each figure
is the best of `--repeats` probes, with the one-line error the user sees.

    python benchmarks/bench_probe.py [--repeats 5] [--timeout 10]
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from env.errors import UserError
from llm_agents.backends import get_model
from llm_agents.backends.base import GenerateConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

SERVED = ["HuggingFaceTB/SmolLM2-135M-Instruct", "Qwen/QwQ-32B", "meta/llama-3-8b"]


@contextmanager
def models_server(require_key: str | None = None) -> Iterator[str]:
    """The tests' loopback server, listing SERVED on `GET /v1/models` (401 without the right key)."""
    from fault_server import FaultServer

    server = FaultServer(models=SERVED, required_key=require_key).start()
    try:
        yield server.url
    finally:
        server.stop()


@contextmanager
def silent_server() -> Iterator[str]:
    """A port whose connections complete in the kernel's backlog but are never answered."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(16)
        yield f"http://127.0.0.1:{listener.getsockname()[1]}/v1"


def dead_url() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"http://127.0.0.1:{port}/v1"


def time_probe(spec: str, timeout_s: float, repeats: int) -> tuple[float, str]:
    best, outcome = float("inf"), ""
    for _ in range(repeats):
        model = get_model(spec, GenerateConfig(timeout_s=timeout_s))
        start = time.perf_counter()
        try:
            model.probe()
            outcome = "passes"
        except UserError as err:
            outcome = str(err)
        best = min(best, time.perf_counter() - start)
    return best, outcome


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="best of this many probes")
    parser.add_argument("--timeout", type=float, default=10.0, help="the run's timeout_s")
    args = parser.parse_args()
    cases: list[tuple[str, Callable[[], Any], str]] = [
        ("dead port", lambda: _fixed(dead_url()), "openai:m@{url}"),
        (
            "unresolvable host",
            lambda: _fixed("http://no-such-host.invalid:8000/v1"),
            "openai:m@{url}",
        ),
        ("wrong model name", models_server, "openai:HuggingFaceTB/SmolLM2-135M@{url}"),
        ("refused API key", lambda: models_server("sk-right"), "openai:Qwen/QwQ-32B@{url}"),
        ("served model (passes)", models_server, "openai:Qwen/QwQ-32B@{url}"),
        ("server never answers", silent_server, "openai:m@{url}"),
    ]
    print(f"probe time to failure (best of {args.repeats}, timeout_s={args.timeout:g}):")
    for label, make, spec in cases:
        repeats = 1 if label == "server never answers" else args.repeats
        with make() as url:
            seconds, outcome = time_probe(spec.format(url=url), args.timeout, repeats)
        print(f"  {label:<24} {seconds * 1e3:9.1f} ms  {outcome}")


@contextmanager
def _fixed(url: str) -> Iterator[str]:
    yield url


if __name__ == "__main__":
    main()
