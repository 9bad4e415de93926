"""Nothing secret in a result: a password and a token in the model spec's URL and an API key in
the environment reach the server, and no file any command writes, nor any line it prints or
logs, carries them (eval -> report -> card -> leaderboard -> view -> export)."""

from __future__ import annotations

import base64
import logging
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from fault_server import FaultServer

from env.downloads import CACHE_ENV_VAR
from llm_agents.backends import parse_model_spec, redact_secrets
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config

USER = "canary-user"
PASSWORD = "pw:CANARY@pass/word-7f3a"
TOKEN = "tok-CANARY-query-91c2"
KEY = "sk-CANARY-env-key-5d8e"


def _forms(secret: str) -> set[str]:
    """The ways a secret can be written down: as is, percent-encoded, inside a Basic header."""
    return {secret, quote(secret, safe=""), quote(secret)}


SECRETS = (
    _forms(PASSWORD)
    | _forms(TOKEN)
    | _forms(KEY)
    | {base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode()}
)


@pytest.fixture
def server() -> Iterator[FaultServer]:
    running = FaultServer(
        models=["canary-model"],
        answer=lambda body: {"role": "assistant", "content": "DO"},
        max_requests=100_000,
    ).start()
    yield running
    running.stop()


def _leaks(text: str) -> list[str]:
    return sorted(secret for secret in SECRETS if secret in text)


@pytest.mark.slow
def test_no_secret_reaches_any_file_or_output_of_any_command(
    server: FaultServer,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path / "user-cache"))
    host = server.url.removeprefix("http://")
    url = f"http://{USER}:{quote(PASSWORD, safe='')}@{host}?api_key={TOKEN}&v=1"
    spec = f"openai:canary-model@{url}"
    run, site = tmp_path / "run", tmp_path / "site"
    commands = [
        [
            *("-v", "eval", "--protocol", "balrog", "--model", spec, "--limit", "2"),
            *("--batch-size", "2", "--cache", str(tmp_path / "responses.sqlite")),
            *("--output-dir", str(run), "--no-progress"),
        ],
        ["-v", "report", str(run)],
        ["-v", "card", str(run)],
        [
            *("-v", "leaderboard", f"{run / 'card.json'}={run}"),
            *("--out", str(site), "--markdown", str(tmp_path / "board.md")),
        ],
        ["-v", "view", str(run), "--no-progress"],
        ["-v", "export", "--format", "balrog", str(run), str(tmp_path / "submission")],
    ]
    printed = []
    with caplog.at_level(logging.DEBUG):
        for command in commands:
            assert main(command) == 0, command
            out, err = capfd.readouterr()
            printed += [out, err]
    printed.append(caplog.text)

    # The credentials were given to the server: the canary could have leaked.
    chats = [r for r in server.requests if not r.key.startswith("GET ")]
    assert chats and all(f"api_key={TOKEN}" in r.path for r in chats)
    basic = base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode()
    assert all(r.headers["Authorization"] == f"Basic {basic}" for r in chats)

    written = [path for path in tmp_path.rglob("*") if path.is_file()]
    assert {"results.json", "episodes.jsonl", "steps.jsonl", "card.json", "card.md"} <= {
        path.name for path in written
    }
    assert (site / "index.html").is_file() and (tmp_path / "submission").is_dir()
    assert (run / "report").is_dir() or any(p.suffix == ".html" for p in run.rglob("*"))
    leaks = {
        str(path): found
        for path in written
        if (found := _leaks(path.read_bytes().decode("utf-8", "replace")))
    }
    assert leaks == {}
    assert [_leaks(text) for text in printed if _leaks(text)] == []
    # What is recorded and shown instead: the spec with its credentials starred out.
    assert f"canary-model@http://***@{host}?api_key=***" in (run / "results.json").read_text()


def test_a_spec_is_recorded_without_user_info_or_query_values() -> None:
    password = quote(PASSWORD, safe="")
    spec = f"openai:m@https://u:{password}@h.example/v1?api_key={TOKEN}&v=2,http://h2/v1"
    config = build_config({"model": spec})
    assert config.model == "openai:m@https://***@h.example/v1?api_key=***&v=***,http://h2/v1"
    assert config.backend_spec == spec
    assert not _leaks(config.model_dump_json()) and not _leaks(repr(config))
    # Another setting assigned keeps the credentials; another spec drops them.
    config.limit = 3
    assert config.backend_spec == spec
    config.model = "mock:noop"
    assert config.backend_spec == "mock:noop"


@pytest.mark.parametrize(
    "spec",
    [
        f"oppenai:m@http://u:{PASSWORD}@h/v1",  # an unknown backend
        f"openai:@http://u:{PASSWORD}@h/v1?api_key={TOKEN}",  # no model
    ],
)
def test_a_refused_spec_is_quoted_without_its_credentials(spec: str) -> None:
    with pytest.raises(Exception) as refused:
        parse_model_spec(spec)
    assert "***@h/v1" in str(refused.value) and not _leaks(str(refused.value))


def test_a_password_written_unencoded_is_taken_out_whole() -> None:
    # `/` and `@` unencoded make an ill-formed URL, and still a secret.
    shown = redact_secrets(f"openai:m@http://u:{PASSWORD}@h:8/v1#{TOKEN}")
    assert shown == "openai:m@http://***@h:8/v1"


def test_text_without_urls_is_left_alone() -> None:
    assert redact_secrets("hf:Qwen/Qwen2.5-0.5B@main") == "hf:Qwen/Qwen2.5-0.5B@main"
    assert redact_secrets("see http://host:8000/v1 now") == "see http://host:8000/v1 now"
