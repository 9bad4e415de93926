"""One model spec over several servers: requests spread by load, a failing server taken out and
its requests retried elsewhere at once, back in when it recovers, and the run's failure rules
when every server is down. Servers are real loopback HTTP servers, some in their own processes
so that they can be killed."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fault_server import FaultServer

from env.errors import UserError
from llm_agents.backends import get_model, parse_model_spec
from llm_agents.backends.base import ChatMessage, GenerateConfig
from llm_agents.backends.endpoints import EndpointStats, merge_endpoint_stats
from llm_agents.backends.openai import OpenAIModel
from llm_agents.cli import EXIT_BACKEND_FAILURE, EXIT_USER_ERROR, main
from llm_agents.run_data.store import read_results

FAST = {"backoff_initial_s": 0.01, "backoff_max_s": 0.05, "jitter_s": 0.0}
SERVER_SCRIPT = Path(__file__).with_name("fault_server.py")


@pytest.fixture(autouse=True)
def no_ambient_openai_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)


@pytest.fixture
def servers() -> Iterator[list[FaultServer]]:
    started = [FaultServer(latency_s=0.05).start() for _ in range(2)]
    yield started
    for server in started:
        server.stop()


@pytest.fixture
def spawn() -> Iterator[Callable[..., str]]:
    """Start a fault server in its own process (killable for real); returns its URL."""
    processes: list[subprocess.Popen[str]] = []

    def start(*args: str) -> str:
        process = subprocess.Popen(
            [sys.executable, str(SERVER_SCRIPT), *args], stdout=subprocess.PIPE, text=True
        )
        processes.append(process)
        assert process.stdout is not None
        return process.stdout.readline().strip()

    yield start
    for process in processes:
        process.kill()
        process.wait()


def conv(text: str) -> list[ChatMessage]:
    return [ChatMessage(role="user", content=text)]


def pooled(urls: list[str], **options: Any) -> OpenAIModel:
    config = GenerateConfig(timeout_s=2.0, max_retries=2, max_concurrency=8)
    return OpenAIModel("m", config, base_url=",".join(urls), **{**FAST, **options})


def test_the_spec_names_several_servers_and_each_is_checked() -> None:
    spec = parse_model_spec("openai:org/m@x@http://u:p@a:1/v1,https://b:2/v1")
    assert (spec.name, spec.base_url) == ("org/m@x", "http://u:p@a:1/v1,https://b:2/v1")
    model = get_model("openai:m@http://a:1/v1, http://b:2/v1/")
    assert isinstance(model, OpenAIModel)
    assert model.base_url == "http://a:1/v1,http://b:2/v1"
    with pytest.raises(UserError, match="listed twice"):
        get_model("openai:m@http://a:1/v1,http://a:1/v1/")
    with pytest.raises(UserError, match="must start with http"):
        get_model("openai:m@http://a:1/v1,b:2/v1")


def test_requests_spread_over_the_servers_by_load(servers: list[FaultServer]) -> None:
    model = pooled([s.url for s in servers])
    outputs = model.generate([conv(f"q{i}") for i in range(8)])
    assert [o.text for o in outputs] == [f"echo: q{i}" for i in range(8)]
    # Eight at once over two idle servers: least-outstanding gives each half.
    assert [len(s.requests) for s in servers] == [4, 4]
    stats = model.endpoint_stats()
    assert [(e.url, e.requests, e.errors, e.taken_out) for e in stats] == [
        (servers[0].url, 4, 0, 0),
        (servers[1].url, 4, 0, 0),
    ]
    assert all(e.mean_latency_s is not None and e.mean_latency_s >= 0.05 for e in stats)


def test_a_dead_server_is_taken_out_its_requests_retried_elsewhere_at_once_and_back_when_up(
    servers: list[FaultServer],
) -> None:
    dead, alive = servers
    port = int(dead.url.rsplit(":", 1)[1].split("/")[0])
    # Waits between retries so long that only an immediate failover can finish in time.
    model = pooled([dead.url, alive.url], backoff_initial_s=30.0, health_interval_s=0.1)
    dead.stop()
    started = time.monotonic()
    outputs = model.generate([conv(f"q{i}") for i in range(6)])
    assert time.monotonic() - started < 15.0
    assert all(o.finish_reason == "stop" for o in outputs)
    dead_stats, alive_stats = model.endpoint_stats()
    assert dead_stats.errors >= 1 and dead_stats.taken_out == 1
    assert dead_stats.requests == dead_stats.errors
    assert alive_stats.requests == 6 and alive_stats.errors == 0

    revived = FaultServer(port=port).start()
    try:
        deadline = time.monotonic() + 10.0
        while not model.pool.endpoints[0].in_rotation and time.monotonic() < deadline:
            time.sleep(0.05)
        assert model.pool.endpoints[0].in_rotation
        outputs = model.generate([conv(f"again{i}") for i in range(4)])
        assert all(o.finish_reason == "stop" for o in outputs)
        assert sum(1 for r in revived.requests if r.key.startswith("again")) >= 1
    finally:
        revived.stop()
        model.close()


def test_with_every_server_down_the_answer_fails_after_the_retries_and_the_probe_refuses(
    servers: list[FaultServer],
) -> None:
    urls = [s.url for s in servers]
    for server in servers:
        server.stop()
    model = pooled(urls)
    [output] = model.generate([conv("q")])
    assert output.finish_reason == "error" and output.error is not None
    assert "after 3 attempts" in output.error and "connection failed" in output.error
    assert sum(e.requests for e in model.endpoint_stats()) == 3
    with pytest.raises(UserError, match=r"cannot reach http://127\.0\.0\.1"):
        model.probe()


def test_stats_of_several_workers_add_up_per_url() -> None:
    a = [EndpointStats(url="u1", requests=3, errors=1, latency_s_total=1.0)]
    b = [
        EndpointStats(url="u2", requests=2, latency_s_total=0.5),
        EndpointStats(url="u1", requests=1, taken_out=1, latency_s_total=0.5),
    ]
    merged = merge_endpoint_stats([a, b])
    assert [(m.url, m.requests, m.errors, m.taken_out) for m in merged] == [
        ("u1", 4, 1, 1),
        ("u2", 2, 0, 0),
    ]
    assert merged[0].mean_latency_s == pytest.approx(0.5)


def eval_argv(model: str, out: Path, *extra: str) -> list[str]:
    return [
        "eval", "--model", model, "--variant", "classic", "--categories", "combo",
        "--max-steps", "6", "--limit", "4", "--batch-size", "2", "--max-concurrency", "2",
        "--timeout-s", "5", "--output-dir", str(out), "--no-progress",
        "--backend-option", "backoff_initial_s=0.01", "--backend-option", "jitter_s=0",
        *extra,
    ]  # fmt: skip


def test_a_server_killed_mid_run_costs_no_answer(tmp_path: Path, spawn: Callable[..., str]) -> None:
    steady = spawn("--latency", "0.01")
    # Dies on its 6th request (the probe's included), dropping whatever it holds in flight.
    doomed = spawn("--latency", "0.01", "--die-after", "6")
    assert main(eval_argv(f"openai:test-model@{steady},{doomed}", tmp_path)) == 0
    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.finished == 4
    assert results.backend_errors.failed_calls == 0
    stats = {e.url: e for e in results.endpoints}
    assert set(stats) == {steady, doomed}
    assert stats[doomed].errors >= 1 and stats[doomed].taken_out >= 1
    assert stats[steady].errors == 0
    steps = [json.loads(line) for line in (tmp_path / "steps.jsonl").read_text().splitlines()]
    assert steps and all(step["error"] is None for step in steps)
    answered = sum(e.requests - e.errors for e in results.endpoints)
    assert answered == len(steps)


def test_every_server_dying_mid_run_stops_it_as_a_backend_failure(
    tmp_path: Path, spawn: Callable[..., str], capsys: pytest.CaptureFixture[str]
) -> None:
    urls = [spawn("--die-after", "4"), spawn("--die-after", "4")]
    argv = eval_argv(
        f"openai:test-model@{','.join(urls)}",
        tmp_path,
        "--max-retries", "1", "--max-consecutive-failures", "2",
    )  # fmt: skip
    assert main(argv) == EXIT_BACKEND_FAILURE
    assert "2 failed model answers in a row" in capsys.readouterr().err
    results = read_results(tmp_path / "results.json")
    assert results.status == "failed" and results.backend_errors.failed_calls >= 2
    assert {e.url for e in results.endpoints} == set(urls)


def test_a_server_down_at_the_start_is_a_user_error(
    tmp_path: Path, spawn: Callable[..., str], capsys: pytest.CaptureFixture[str]
) -> None:
    up = spawn()
    argv = eval_argv(f"openai:test-model@{up},http://127.0.0.1:9/v1", tmp_path)
    assert main(argv) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert "cannot reach http://127.0.0.1:9/v1" in err
    assert not (tmp_path / "results.json").exists()
