"""The openai backend against a local fault-injecting server: retries, timeouts, choice mode, secrets."""

from __future__ import annotations

import asyncio
import concurrent.futures
import gc
import logging
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime
from pathlib import Path
from typing import Any

import pytest
from fault_server import Fault, FaultServer

from env.errors import UserError
from llm_agents.backends import CachedModel, get_model
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig
from llm_agents.backends.openai import LOOP_THREAD_NAME, OpenAIModel
from llm_agents.backends.retry import RetryPolicy, RetryWaits, backoff_wait, parse_retry_after

#: Retries fast enough for tests; the timeout is short so "slow" faults stay cheap.
FAST = {"backoff_initial_s": 0.01, "backoff_max_s": 0.05, "jitter_s": 0.0}
SECRET = "sk-test-0123456789-very-secret"
GUIDED = ChoiceSet(options=("NOOP", "MOVE_LEFT"), rule="guided")


@pytest.fixture
def server() -> Iterator[FaultServer]:
    fault_server = FaultServer().start()
    yield fault_server
    fault_server.stop()


@pytest.fixture(autouse=True)
def no_ambient_openai_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)


def conv(text: str) -> list[ChatMessage]:
    return [ChatMessage(role="system", content="be brief"), ChatMessage(role="user", content=text)]


def model(
    server: FaultServer, *, api_key_env: str = "OPENAI_API_KEY", **config: Any
) -> OpenAIModel:
    """A backend on the fault server; keyword arguments are `GenerateConfig` fields."""
    settings = GenerateConfig(**{"timeout_s": 2.0, "max_retries": 3, **config})
    return OpenAIModel("test-model", settings, base_url=server.url, api_key_env=api_key_env, **FAST)


def test_answers_every_conversation_in_order_with_bounded_concurrency(server: FaultServer) -> None:
    # Earlier conversations answer later, so gather order and completion order differ.
    keys = [f"q{i}" for i in range(8)]
    server.plan = {key: [Fault("slow", delay_s=0.05 * (8 - i))] for i, key in enumerate(keys)}
    outputs = model(server, max_concurrency=3).generate([conv(k) for k in keys])
    assert [o.text for o in outputs] == [f"echo: {k}" for k in keys]
    assert all(o.finish_reason == "stop" and o.error is None for o in outputs)
    assert outputs[0].prompt_tokens == 7 and outputs[0].completion_tokens == 3
    assert 2 <= server.max_in_flight <= 3
    sent = server.requests[0].body
    assert (
        sent["model"] == "test-model" and sent["temperature"] == 0.0 and sent["max_tokens"] == 256
    )
    assert "Authorization" not in server.requests[0].headers


@pytest.mark.parametrize(
    "fault",
    [
        Fault("drop"),
        Fault("status", status=500),
        Fault("status", status=503),
        Fault("status", status=429),
        Fault("malformed"),
        Fault("slow", delay_s=1.5),
    ],
    ids=["dropped-connection", "500", "503", "429", "malformed-json", "timeout"],
)
def test_transient_failures_are_retried_until_an_answer(server: FaultServer, fault: Fault) -> None:
    server.plan = {"flaky": [fault, fault]}
    outputs = model(server, timeout_s=0.5).generate([conv("flaky"), conv("fine")])
    assert [o.text for o in outputs] == ["echo: flaky", "echo: fine"]
    assert server.count("flaky") == 3
    assert server.count("fine") == 1


def test_retry_after_is_honoured(server: FaultServer) -> None:
    server.plan = {
        "limited": [Fault("status", status=429, retry_after="1")],
        "plain": [Fault("status", status=429)],
    }
    outputs = model(server).generate([conv("limited"), conv("plain")])
    assert all(o.finish_reason == "stop" for o in outputs)
    limited, plain = server.times("limited"), server.times("plain")
    assert limited[1] - limited[0] >= 0.95
    # Without the header the backoff of the test config applies: far shorter.
    assert plain[1] - plain[0] < 0.9


@pytest.mark.parametrize("status", [400, 401, 404, 422])
def test_client_errors_are_not_retried(server: FaultServer, status: int) -> None:
    server.plan = {"bad": [Fault("status", status=status, body="nope")]}
    [output] = model(server).generate([conv("bad")])
    assert server.count("bad") == 1
    assert output.finish_reason == "error" and output.text == ""
    assert output.error is not None and f"HTTP {status}" in output.error and "nope" in output.error
    assert "not retried" in output.error


def test_exhausted_retries_give_a_clear_error_without_losing_the_batch(
    server: FaultServer, caplog: pytest.LogCaptureFixture
) -> None:
    server.plan = {"down": [Fault("status", status=503)] * 10}
    with caplog.at_level(logging.WARNING, logger="llm_agents.backends.retry"):
        outputs = model(server, max_retries=2).generate([conv("ok-1"), conv("down"), conv("ok-2")])
    assert [o.finish_reason for o in outputs] == ["stop", "error", "stop"]
    error = outputs[1].error or ""
    assert "3 attempts" in error and "HTTP 503" in error and "/chat/completions" in error
    assert server.count("down") == 3
    assert len([r for r in caplog.records if "retrying" in r.getMessage()]) == 2


def test_exhausted_timeouts_name_the_timeout(server: FaultServer) -> None:
    # Answers far later than the bound below, so only the timeouts can end the call within it.
    server.plan = {"stuck": [Fault("slow", delay_s=10.0)] * 3}
    start = time.monotonic()
    [output] = model(server, timeout_s=0.3, max_retries=1).generate([conv("stuck")])
    assert output.finish_reason == "error"
    assert "2 attempts" in (output.error or "") and "0.3 s" in (output.error or "")
    assert time.monotonic() - start < 5.0


def test_api_key_is_sent_but_never_leaks(
    server: FaultServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("MY_PROVIDER_KEY", SECRET)
    server.echo_authorization = True
    server.plan = {
        "retried": [Fault("status", status=500)] * 5,
        "refused": [Fault("status", status=401)],
    }
    backend = model(server, api_key_env="MY_PROVIDER_KEY", max_retries=1)
    with caplog.at_level(logging.DEBUG):
        outputs = backend.generate([conv("retried"), conv("refused"), conv("fine")])
    assert server.requests[0].headers["Authorization"] == f"Bearer {SECRET}"
    assert outputs[2].text == "echo: fine"
    errors = " ".join(o.error or "" for o in outputs)
    assert "Authorization: Bearer ***" in errors  # the echoed header arrived, scrubbed
    visible = [errors, caplog.text, repr(backend), str(backend.info()), str(backend.__dict__)]
    visible += [o.model_dump_json() for o in outputs]
    assert not any(SECRET in text for text in visible)


def test_choice_mode_uses_structured_outputs(server: FaultServer) -> None:
    choices = ["NOOP", "MOVE_LEFT", "DO"]
    outputs = model(server).generate(
        [conv("a"), conv("b")], choices=ChoiceSet(options=tuple(choices), rule="guided")
    )
    assert [o.text for o in outputs] == ["DO", "DO"]
    assert all(o.finish_reason == "choice" for o in outputs)
    assert server.requests[0].body["structured_outputs"] == {"choice": choices}


def test_choice_mode_falls_back_to_free_text_when_the_server_rejects_it(
    server: FaultServer,
) -> None:
    server.reject_structured_outputs = True
    server.answer = lambda body: {"role": "assistant", "content": " MOVE_LEFT\n"}
    backend = model(server)
    [first] = backend.generate([conv("a")], choices=GUIDED)
    assert first.text == "MOVE_LEFT" and first.finish_reason == "choice"
    assert server.count("a") == 2  # the rejected constrained request, then free text
    server.answer = lambda body: {"role": "assistant", "content": "I would go left"}
    [second] = backend.generate([conv("b")], choices=GUIDED)
    assert server.count("b") == 1  # no constrained request any more
    assert "structured_outputs" not in server.requests[-1].body
    assert second.text == "I would go left" and second.finish_reason == "stop"


def test_reasoning_content_is_kept_apart_from_the_answer(server: FaultServer) -> None:
    server.answer = lambda body: {
        "role": "assistant",
        "content": "NOOP",
        "reasoning_content": "nothing to do here",
    }
    [output] = model(server).generate([conv("think")])
    assert output.text == "NOOP" and output.reasoning == "nothing to do here"


def test_inline_thinking_is_split_from_the_answer(server: FaultServer) -> None:
    server.answer = lambda body: {"role": "assistant", "content": "<think>a tree</think>\nDO"}
    [output] = model(server).generate([conv("inline")])
    assert output.text == "DO" and output.reasoning == "a tree"


def test_reasoning_cut_off_by_the_token_limit_gets_one_answer_only_followup(
    server: FaultServer,
) -> None:
    def answer(body: dict[str, Any]) -> dict[str, Any]:
        if len(body["messages"]) == 2:  # the original request: thinking runs out of tokens
            return {
                "role": "assistant",
                "content": "<think>the tree is near",
                "finish_reason": "length",
            }
        return {"role": "assistant", "content": "DO"}

    server.answer = answer
    [output] = model(server).generate([conv("deep thought")])
    assert output.text == "DO" and output.followups == 1
    assert output.reasoning is not None and "the tree is near" in output.reasoning
    followup = server.requests[-1].body["messages"]
    assert len(server.requests) == 2 and followup[2]["role"] == "assistant"
    assert "the tree is near" in followup[2]["content"]


def test_generate_works_inside_a_running_event_loop(server: FaultServer) -> None:
    backend = model(server)

    async def caller() -> list[str]:
        return [o.text for o in backend.generate([conv("x")])]

    assert asyncio.run(caller()) == ["echo: x"]


def test_calls_from_many_threads_share_kept_alive_connections(server: FaultServer) -> None:
    def loop_threads() -> set[threading.Thread]:
        return {t for t in threading.enumerate() if t.name == LOOP_THREAD_NAME}

    before = loop_threads()
    backend = model(server, max_concurrency=4)
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        outputs = list(pool.map(lambda i: backend.generate([conv(f"q{i}")])[0], range(40)))
    assert [o.text for o in outputs] == [f"echo: q{i}" for i in range(40)]
    # A connection per call would make 40; kept alive, the 4 threads need at most 4.
    assert len({r.connection for r in server.requests}) <= 4
    [own] = loop_threads() - before
    backend.close()
    assert not own.is_alive()
    # A closed backend opens a new loop and client when used again.
    assert backend.generate([conv("again")])[0].text == "echo: again"
    backend.close()

    def use_and_drop_a_backend() -> threading.Thread:
        dropped = model(server)
        dropped.generate([conv("dropped")])
        [thread] = loop_threads() - before
        return thread

    thread = use_and_drop_a_backend()
    gc.collect()
    thread.join(timeout=5)
    assert not thread.is_alive(), "a backend dropped without close() left its loop running"


def test_spec_and_environment_pick_the_server(
    server: FaultServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    by_spec = get_model(f"openai:some/model@{server.url}")
    assert isinstance(by_spec, OpenAIModel) and by_spec.model_name == "some/model"
    assert by_spec.generate([conv("spec")])[0].text == "echo: spec"
    monkeypatch.setenv("OPENAI_BASE_URL", server.url + "/")
    by_env = get_model("openai:other")
    assert by_env.generate([conv("env")])[0].text == "echo: env"
    assert server.requests[-1].body["model"] == "other"


def test_configuration_mistakes_are_user_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(UserError, match="OPENAI_BASE_URL"):
        get_model("openai:m")
    with pytest.raises(UserError, match="ftp://x"):
        get_model("openai:m@ftp://x")
    with pytest.raises(UserError, match="NOT_SET_KEY"):
        get_model("openai:m@http://127.0.0.1:9/v1", api_key_env="NOT_SET_KEY")
    with pytest.raises(UserError, match="backof_initial_s"):
        get_model("openai:m@http://127.0.0.1:9/v1", backof_initial_s=1)


def test_parse_retry_after_reads_seconds_and_dates() -> None:
    now = datetime(2030, 1, 1, tzinfo=UTC)
    date = format_datetime(now + timedelta(seconds=30), usegmt=True)
    assert parse_retry_after("7") == 7.0
    assert parse_retry_after("0.5") == 0.5
    assert parse_retry_after(date, now=now.timestamp()) == pytest.approx(30.0)
    assert (
        parse_retry_after(
            format_datetime(now - timedelta(seconds=5), usegmt=True), now=now.timestamp()
        )
        == 0.0
    )
    for unreadable in [None, "", "soon", "nan"]:
        assert parse_retry_after(unreadable) is None


def test_backoff_grows_exponentially_with_bounded_jitter_and_caps() -> None:
    policy = RetryPolicy.for_generation(
        GenerateConfig(),
        RetryWaits(backoff_initial_s=1.0, backoff_max_s=10.0, jitter_s=0.5, retry_after_max_s=60),
    )
    for attempt, base in [(1, 1.0), (2, 2.0), (3, 4.0), (5, 10.0), (9, 10.0)]:
        waits = [backoff_wait(policy, attempt) for _ in range(50)]
        assert all(base <= w <= base + 0.5 for w in waits)
        assert len(set(waits)) > 1  # jittered
    assert backoff_wait(policy, 1, retry_after_s=20.0) == 20.0
    assert backoff_wait(policy, 1, retry_after_s=3600.0) == 60.0
    assert 1.0 <= backoff_wait(policy, 1, retry_after_s=0.1) <= 1.5


LEAKY_KEY = "sk-live-7Hq2ZtX9mR4pW1vB8nK3"


def test_the_key_never_leaks_from_any_body_of_any_length(
    server: FaultServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A proxy echoes the Authorization header into 200 (not a completion), 4xx and 5xx bodies,
    as text or JSON, at offsets where a cut before redaction would split the key."""
    monkeypatch.setenv("OPENAI_API_KEY", LEAKY_KEY)
    # 300 and 80 are the cuts of error bodies and of non-JSON excerpts.
    pads = [0, 60, 75, 78, 280, 290, 295, 298, 5000]
    faults = {
        f"{status}-{pad}-{as_json}": Fault("echo_auth", status=status, pad=pad, as_json=as_json)
        for status in (200, 400, 401, 404, 500, 503)
        for pad in pads
        for as_json in (False, True)
    }
    server.plan = {key: [fault] * 2 for key, fault in faults.items()}
    backend = model(server, max_retries=1)
    with caplog.at_level(logging.DEBUG):
        outputs = backend.generate([conv(key) for key in faults])
    assert all(r.headers["Authorization"] == f"Bearer {LEAKY_KEY}" for r in server.requests)
    assert all(o.finish_reason == "error" and o.error for o in outputs)
    assert all("\n" not in (o.error or "") for o in outputs)
    short = [o.error or "" for key, o in zip(faults, outputs, strict=True) if "-0-" in key]
    assert all("Bearer ***" in error for error in short)  # the echo arrived, scrubbed
    visible = [o.model_dump_json() for o in outputs] + [caplog.text]
    visible += [r.getMessage() for r in caplog.records]
    # No piece of the key either: a cut inside it would leave its start.
    pieces = {LEAKY_KEY[i : i + 6] for i in range(len(LEAKY_KEY) - 5)}
    leaks = [(piece, text[:200]) for text in visible for piece in pieces if piece in text]
    assert not leaks


def test_an_unexpected_reply_shape_is_an_error_output_not_a_crash(server: FaultServer) -> None:
    server.answer = lambda body: {"role": "assistant", "content": ["not", "text"]}
    [odd, *_] = model(server).generate([conv("odd")])
    assert odd.finish_reason == "error" and "not a chat completion" in (odd.error or "")


def test_cached_and_followups_describe_each_answer_through_the_cache(
    server: FaultServer, tmp_path: Path
) -> None:
    def answer(body: dict[str, Any]) -> dict[str, Any]:
        if len(body["messages"]) == 2:
            return {"role": "assistant", "content": "<think>hmm", "finish_reason": "length"}
        return {"role": "assistant", "content": "DO"}

    server.answer = answer
    server.plan = {"down": [Fault("status", status=503)] * 8}
    cached = CachedModel(model(server, max_retries=1), tmp_path / "cache.sqlite")
    first = cached.generate([conv("cut"), conv("down")])
    again = cached.generate([conv("cut"), conv("down")])
    cached.close()
    assert [(o.cached, o.followups, o.finish_reason) for o in first] == [
        (False, 1, "stop"),
        (False, 0, "error"),
    ]
    # The hit replays the answer and what it cost then; the failure is asked again, not replayed.
    assert [(o.cached, o.followups, o.finish_reason) for o in again] == [
        (True, 1, "stop"),
        (False, 0, "error"),
    ]
    assert server.count("down") == 4 and server.count("cut") == 1


def test_a_password_in_the_url_is_a_secret_too(
    server: FaultServer, caplog: pytest.LogCaptureFixture
) -> None:
    port = server.url.split(":")[2].split("/")[0]
    url = f"http://user:pa%40ss-w0rd-xyz@127.0.0.1:{port}/v1"
    server.plan = {"down": [Fault("status", status=503)] * 3}
    backend = OpenAIModel("test-model", GenerateConfig(max_retries=1), base_url=url, **FAST)
    with caplog.at_level(logging.DEBUG):
        [failed] = backend.generate([conv("down")])
    assert server.requests[0].headers["Authorization"].startswith("Basic ")  # it was used
    visible = [failed.model_dump_json(), caplog.text, repr(backend), str(backend.info())]
    assert backend.info()["base_url"] == f"http://127.0.0.1:{port}/v1"
    assert not any(secret in text for text in visible for secret in ("pa%40ss", "pa@ss"))


def test_loglik_choices_are_refused_with_the_reason(server: FaultServer) -> None:
    with pytest.raises(UserError, match=r"cannot choose by 'loglik'.*log-probabilities"):
        model(server).generate([conv("a")], choices=ChoiceSet(options=("DO",), rule="loglik"))
    assert server.requests == []


def test_the_servers_cached_prompt_tokens_are_not_counted_as_computed() -> None:
    from llm_agents.backends.openai import _parse_reply

    def reply(usage: dict[str, Any]) -> dict[str, Any]:
        return {
            "choices": [{"message": {"content": "DO"}, "finish_reason": "stop"}],
            "usage": usage,
        }

    cached = {"prompt_tokens": 900, "prompt_tokens_details": {"cached_tokens": 768}}
    assert _parse_reply(reply(cached), None).computed_prompt_tokens == 132
    # A server that does not say leaves the count unknown rather than "all computed".
    assert _parse_reply(reply({"prompt_tokens": 900}), None).computed_prompt_tokens is None
    silent = {"prompt_tokens": 900, "prompt_tokens_details": None}
    assert _parse_reply(reply(silent), None).computed_prompt_tokens is None


def test_a_token_in_the_urls_query_is_sent_with_each_request_and_shown_nowhere(
    server: FaultServer, caplog: pytest.LogCaptureFixture
) -> None:
    token = "tok-in-the-query-0123"
    server.models = ["test-model"]
    server.plan = {"down": [Fault("status", status=503)] * 3}
    url = f"{server.url}?api-key={token}&v=1"
    backend = OpenAIModel("test-model", GenerateConfig(max_retries=1), base_url=url, **FAST)
    with caplog.at_level(logging.DEBUG):
        backend.probe()
        [failed] = backend.generate([conv("down")])
    # Every request carried it, the probe's included; httpx logged each request's URL.
    assert server.requests and all(f"api-key={token}" in r.path for r in server.requests)
    assert "HTTP Request: POST" in caplog.text
    visible = [failed.model_dump_json(), caplog.text, repr(backend), str(backend.info())]
    assert backend.info()["base_url"] == server.url
    assert not any(token in text for text in visible)
