"""Before a run: the probe finds a dead server, a wrong model name or a refused key within
seconds, and a backend refuses settings it would silently ignore. Real loopback servers."""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fault_server import Fault, FaultServer

from env.errors import UserError
from llm_agents.backends import CachedModel, get_model, load_backend_class
from llm_agents.backends.base import ChatMessage, GenerateConfig, ModelAPI
from llm_agents.backends.mock import MockModel
from llm_agents.backends.openai import OpenAIModel

SECRET = "sk-live-7Hq2ZtX9mR4pW1vB8nK3"
PROBE_PROMPT = "Say OK."


@pytest.fixture
def server() -> Iterator[FaultServer]:
    fault_server = FaultServer().start()
    yield fault_server
    fault_server.stop()


@pytest.fixture(autouse=True)
def no_ambient_openai_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)


def probe_error(spec: str, **config: float) -> tuple[str, float]:
    """The probe's one-line message for a model spec, and how long it took to fail."""
    model = get_model(spec, GenerateConfig(**config))
    start = time.monotonic()
    with pytest.raises(UserError) as caught:
        model.probe()
    elapsed = time.monotonic() - start
    message = str(caught.value)
    assert "\n" not in message
    return message, elapsed


def dead_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port  # closed again: nothing listens there


def test_a_served_model_passes_with_one_listing_request(server: FaultServer) -> None:
    server.models = ["other/model", "test-model"]
    get_model(f"openai:test-model@{server.url}").probe()
    assert [r.key for r in server.requests] == ["GET /v1/models"]


def test_a_dead_port_fails_at_once_naming_the_url() -> None:
    url = f"http://127.0.0.1:{dead_port()}/v1"
    message, elapsed = probe_error(f"openai:m@{url}")
    assert message.startswith(f"cannot reach {url}") and "refused" in message.lower()
    # Well under PROBE_TIMEOUT_S: a refused connection is not waited on.
    assert elapsed < 5.0


def test_an_unresolvable_host_fails_within_the_probe_timeout() -> None:
    message, elapsed = probe_error("openai:m@http://no-such-host.invalid:8000/v1", timeout_s=2.0)
    assert "no-such-host.invalid" in message
    assert message.startswith(("cannot reach", "no answer from"))
    assert elapsed < 6.0


def test_a_server_that_never_answers_fails_after_the_timeout() -> None:
    with socket.socket() as listener:
        # Connections complete in the kernel's backlog, but nothing ever reads or answers.
        listener.bind(("127.0.0.1", 0))
        listener.listen(8)
        url = f"http://127.0.0.1:{listener.getsockname()[1]}/v1"
        message, elapsed = probe_error(f"openai:m@{url}", timeout_s=1.0)
    assert message.startswith(f"no answer from {url} within 1 s")
    assert 0.9 <= elapsed < 5.0


def test_a_wrong_model_name_lists_the_close_matches(server: FaultServer) -> None:
    server.models = ["HuggingFaceTB/SmolLM2-135M-Instruct", "Qwen/QwQ-32B", "meta/llama-3-8b"]
    message, elapsed = probe_error(f"openai:HuggingFaceTB/SmolLM2-135M-Instruc@{server.url}")
    assert "'HuggingFaceTB/SmolLM2-135M-Instruc' is not served" in message
    assert "did you mean 'HuggingFaceTB/SmolLM2-135M-Instruct'?" in message
    assert "Qwen/QwQ-32B" in message  # the full list, for names nothing like the typo
    assert elapsed < 5.0
    assert not any(r.key == PROBE_PROMPT for r in server.requests)  # no generation was paid


@pytest.mark.parametrize("key", [None, "sk-wrong"])
def test_a_missing_or_refused_key_is_named(
    server: FaultServer, monkeypatch: pytest.MonkeyPatch, key: str | None
) -> None:
    server.models = ["m"]
    server.required_key = "sk-right"
    server.echo_authorization = True
    if key is not None:
        monkeypatch.setenv("OPENAI_API_KEY", key)
    message, _ = probe_error(f"openai:m@{server.url}")
    assert "refused the API key (HTTP 401)" in message
    assert ("no key was sent: set OPENAI_API_KEY" in message) == (key is None)
    assert ("check the key in OPENAI_API_KEY" in message) == (key is not None)
    assert key is None or key not in message


def test_the_right_key_passes(server: FaultServer, monkeypatch: pytest.MonkeyPatch) -> None:
    server.models = ["m"]
    server.required_key = "sk-right"
    monkeypatch.setenv("OPENAI_API_KEY", "sk-right")
    get_model(f"openai:m@{server.url}").probe()


def test_without_a_model_list_one_token_is_generated(server: FaultServer) -> None:
    server.models = None  # GET /models answers 404
    get_model(f"openai:m@{server.url}").probe()
    [listing, chat] = server.requests
    assert listing.key == "GET /v1/models" and chat.key == PROBE_PROMPT
    assert chat.body["max_tokens"] == 1 and chat.body["model"] == "m"


@pytest.mark.parametrize(
    ("status", "expected"),
    [
        (404, "refused a one-token request to model 'm' (HTTP 404)"),
        (400, "refused a one-token request to model 'm' (HTTP 400)"),
        (503, "failed a one-token request to model 'm' (HTTP 503)"),
    ],
)
def test_without_a_model_list_a_refused_token_is_named(
    server: FaultServer, status: int, expected: str
) -> None:
    server.plan = {PROBE_PROMPT: [Fault("status", status=status, body="model does not exist")]}
    message, _ = probe_error(f"openai:m@{server.url}")
    assert expected in message and "model does not exist" in message
    assert server.count(PROBE_PROMPT) == 1  # never retried


def test_the_probe_leaves_the_generation_settings_alone(server: FaultServer) -> None:
    model = get_model(f"openai:m@{server.url}", GenerateConfig(max_retries=4, timeout_s=60))
    model.probe()
    assert (model.config.max_retries, model.config.timeout_s) == (4, 60)
    assert (model.retry_policy.max_retries, model.retry_policy.attempt_timeout_s) == (4, 60)


def test_mock_probe_fails_only_for_the_error_script() -> None:
    scripted = MockModel("list:A|B", cycle=False)
    scripted.probe()
    conversation = [ChatMessage(role="user", content="go")]
    assert [o.text for o in scripted.generate([conversation] * 2)] == ["A", "B"]  # none used up
    message, _ = probe_error("mock:error:the server went away")
    assert message == "mock:error:the server went away does not answer: the server went away"
    [failed] = get_model("mock:error").generate([conversation])
    assert failed.finish_reason == "error" and failed.error == "scripted mock error"


def test_a_cached_model_probes_the_model_it_wraps(tmp_path: Path) -> None:
    cached = CachedModel(get_model("mock:error:down"), tmp_path / "cache.sqlite")
    with pytest.raises(UserError, match="down"):
        cached.probe()
    cached.close()


# ---------------------------------------------------------------- declared capabilities


@pytest.mark.parametrize(
    ("spec", "option", "expected"),
    [
        ("openai:m@http://127.0.0.1:9/v1", "backof_initial_s", "did you mean 'backoff_initial_s'?"),
        ("openai:m@http://127.0.0.1:9/v1", "api_key", "did you mean 'api_key_env'?"),
        ("mock:", "latency", "did you mean 'latency_s'?"),
        ("mock:", "zzz", "(accepted: outputs, cycle, latency_s)"),
    ],
)
def test_an_unknown_backend_option_is_refused_by_name(
    spec: str, option: str, expected: str
) -> None:
    with pytest.raises(UserError) as caught:
        get_model(spec, **{option: 1})
    message = str(caught.value)
    assert f"has no option {option!r}" in message and expected in message


def test_options_are_checked_before_the_backend_is_built() -> None:
    pytest.importorskip("torch")
    hf = load_backend_class("hf")
    assert set(hf.accepted_options()) >= {"device", "dtype", "threads", "rows_per_forward"}
    # Built first, these would fail on the missing folder or URL instead.
    with pytest.raises(UserError, match="no option 'thread'; did you mean 'threads'"):
        get_model("hf:/no/such/model/folder", thread=2)
    with pytest.raises(UserError, match="did you mean 'base_url'"):
        get_model("openai:m", baseurl="http://127.0.0.1:9/v1")


def test_an_ignored_answer_setting_is_refused() -> None:
    with pytest.raises(UserError) as caught:
        get_model("openai:m@http://127.0.0.1:9/v1", GenerateConfig(reasoning_budget=64))
    assert "cannot honour reasoning_budget" in str(caught.value)
    # hf enforces a thinking budget itself, so there it is accepted.
    pytest.importorskip("torch")
    load_backend_class("hf").check_settings(GenerateConfig(reasoning_budget=64), {})


def test_an_ignored_transport_setting_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    pytest.importorskip("torch")
    hf = load_backend_class("hf")
    with caplog.at_level(logging.WARNING):
        hf.check_settings(GenerateConfig(timeout_s=5, max_concurrency=16), {})
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "hf backend ignores timeout_s=5" in warnings[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        OpenAIModel.check_settings(GenerateConfig(timeout_s=5, max_concurrency=2), {})
    assert not caplog.records


# ---------------------------------------------------------------- the default probe


def test_the_default_probe_turns_an_error_output_into_one_line() -> None:
    # The base implementation on a real backend whose every generation fails.
    failing = MockModel("error:engine died")
    with pytest.raises(UserError) as caught:
        ModelAPI.probe(failing)
    assert (
        str(caught.value)
        == "mock:error:engine died does not answer a one-token request: engine died"
    )
    answering = MockModel("cycle:A|B", GenerateConfig(max_tokens=50, max_retries=3))
    ModelAPI.probe(answering)
    assert answering.requests[0][0][0].content == "Say OK."
    assert (answering.config.max_tokens, answering.config.max_retries) == (50, 3)


@pytest.mark.slow
def test_the_default_probe_generates_one_token_with_a_real_model() -> None:
    pytest.importorskip("torch")
    model = get_model("hf:smollm2-135m", GenerateConfig(max_tokens=12), threads=1)
    start = time.monotonic()
    model.probe()
    assert time.monotonic() - start < 30
    assert model.config.max_tokens == 12


def test_a_bad_option_value_is_one_line_naming_the_option() -> None:
    with pytest.raises(UserError) as caught:
        get_model("openai:m@http://127.0.0.1:9/v1", backoff_initial_s=-1, jitter_s="lots")
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith("bad option for the openai backend: backoff_initial_s: ")
    assert "; jitter_s: " in message
