"""Nothing secret in a result: a password and a token in the model spec's URL and an API key in
the environment reach the server, and no file any command writes, nor any line it prints or
logs, carries them (eval -> report -> card -> leaderboard -> view -> export)."""

from __future__ import annotations

import base64
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from fault_server import FaultServer

from env.downloads import CACHE_ENV_VAR
from llm_agents.backends import parse_model_spec, redact_secrets, redact_settings
from llm_agents.backends.redaction import is_secret_name, split_urls
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config
from llm_agents.run_data.store import RunIdentity

USER = "canary-user"
PASSWORD = "pw:CANARY@pass/word-7f3a"
TOKEN = "tok-CANARY-query-91c2"
KEY = "sk-CANARY-env-key-5d8e"
#: Passwords of the backend options and the environment: a comma (where a list of URLs splits)
#: and an `@` (where user info ends) inside.
OPTION_PASSWORD = "opt,CANARY@pass-2b6d"
ENV_PASSWORD = "env,CANARY@pass-c41e"
BODY_KEY = "body-CANARY-key-8e07"


def _forms(secret: str) -> set[str]:
    """The ways a secret can be written down: as is, percent-encoded, inside a Basic header."""
    return {secret, quote(secret, safe=""), quote(secret)}


def _pieces(secret: str) -> set[str]:
    """A secret's forms, and the parts its comma and `@` cut it into (an error quoting the
    URL's part before the comma shows the first)."""
    parts = {part for piece in secret.split(",") for part in piece.split("@") if len(part) > 3}
    return _forms(secret) | {form for part in parts for form in _forms(part)}


SECRETS = (
    _forms(PASSWORD)
    | _forms(TOKEN)
    | _forms(KEY)
    | _pieces(OPTION_PASSWORD)
    | _pieces(ENV_PASSWORD)
    | _forms(BODY_KEY)
    | {
        base64.b64encode(f"{USER}:{password}".encode()).decode()
        for password in (PASSWORD, OPTION_PASSWORD, ENV_PASSWORD)
    }
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


@pytest.mark.slow
def test_no_secret_of_a_backend_option_or_the_environment_reaches_any_file_or_output(
    server: FaultServer,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path / "user-cache"))
    host = server.url.removeprefix("http://")
    # Written as a user would, unencoded: the comma and the `@` inside the password.
    option_url = f"http://{USER}:{OPTION_PASSWORD}@{host}"
    monkeypatch.setenv("OPENAI_BASE_URL", f"http://{USER}:{ENV_PASSWORD}@{host}")
    run, env_run, site = tmp_path / "run", tmp_path / "env-run", tmp_path / "site"
    common = ["--protocol", "balrog", "--limit", "2", "--batch-size", "2", "--no-progress"]
    commands = [
        [
            *("-v", "eval", "--model", "openai:canary-model", *common),
            *("--backend-option", f"base_url={option_url}"),
            *("--backend-option", f'extra_body={{"api_key": "{BODY_KEY}", "top_k": 2}}'),
            *("--output-dir", str(run)),
        ],
        # The server URL from the environment.
        ["-v", "eval", "--model", "openai:canary-model", *common, "--output-dir", str(env_run)],
        ["-v", "report", str(run)],
        ["-v", "card", str(run)],
        ["-v", "card", str(env_run)],
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
        # A URL httpx cannot read, its password holding a comma: the error names neither.
        bad = f"base_url=http://{USER}:{OPTION_PASSWORD}@{host.partition(':')[0]}:port/v1"
        refused = ["eval", "--model", "openai:canary-model", *common, "--backend-option", bad]
        assert main([*refused, "--output-dir", str(tmp_path / "refused")]) == 2
        out, err = capfd.readouterr()
        assert "is not a valid URL (Invalid port)" in err
        printed += [out, err]
    printed.append(caplog.text)

    # The credentials reached the server: the canaries could have leaked.
    chats = [r for r in server.requests if not r.key.startswith("GET ")]
    sent = {r.headers["Authorization"] for r in chats}
    assert sent == {
        "Basic " + base64.b64encode(f"{USER}:{password}".encode()).decode()
        for password in (OPTION_PASSWORD, ENV_PASSWORD)
    }
    assert {r.body.get("api_key") for r in chats} == {BODY_KEY, None}

    written = [path for path in tmp_path.rglob("*") if path.is_file()]
    assert {"results.json", "episodes.jsonl", "steps.jsonl", "card.json", "card.md"} <= {
        path.name for path in written
    }
    assert not (tmp_path / "refused").exists()
    leaks = {
        str(path): found
        for path in written
        if (found := _leaks(path.read_bytes().decode("utf-8", "replace")))
    }
    assert leaks == {}
    assert [_leaks(text) for text in printed if _leaks(text)] == []
    # What is recorded instead: the options with their secrets starred out.
    recorded = json.loads((run / "results.json").read_text())["config"]["backend_options"]
    assert recorded["base_url"] == f"http://***@{host}"
    assert recorded["extra_body"] == {"api_key": "***", "top_k": 2}


def test_backend_options_are_recorded_without_their_secrets() -> None:
    options = {
        "base_url": f"http://u:{OPTION_PASSWORD}@h/v1?sig={TOKEN}",
        "extra_body": {"api_key": BODY_KEY, "max_tokens": 5, "headers": {"X-Custom": KEY}},
        "hf_token": KEY,
        "api_key_env": "MY_KEY",
        "threads": 2,
    }
    config = build_config({"backend_options": options})
    assert config.backend_options == {
        "base_url": "http://***@h/v1?sig=***",
        "extra_body": {"api_key": "***", "max_tokens": 5, "headers": {"X-Custom": "***"}},
        "hf_token": "***",
        "api_key_env": "MY_KEY",
        "threads": 2,
    }
    assert config.backend_option_values == options
    for shown in (config.model_dump_json(), repr(config), json.dumps(config.result_settings())):
        assert not _leaks(shown)
    # Starred twice is starred once; another setting assigned keeps the secrets for the backend.
    assert redact_settings(config.backend_options) == config.backend_options
    config.limit = 3
    assert config.backend_option_values == options


@pytest.mark.parametrize(
    ("name", "secret"),
    [
        ("api_key", True),
        ("X-Api-Key", True),
        ("Authorization", True),
        ("accessToken", True),
        ("client_secret", True),
        ("password", True),
        ("max_tokens", False),
        ("api_key_env", False),
        ("tokenizer", False),
        ("revision", False),
    ],
)
def test_a_setting_is_secret_by_its_name(name: str, secret: bool) -> None:
    assert is_secret_name(name) is secret


def test_a_password_holding_a_comma_stays_in_its_url() -> None:
    spec = f"openai:m@http://u:{OPTION_PASSWORD}@h/v1,http://h2/v1"
    assert redact_secrets(spec) == "openai:m@http://***@h/v1,http://h2/v1"
    assert split_urls(f"http://u:{OPTION_PASSWORD}@h/v1, http://h2/v1") == [
        f"http://u:{OPTION_PASSWORD}@h/v1",
        "http://h2/v1",
    ]
    # A comma outside user info still separates URLs: the second, without its scheme, is
    # refused by the backend.
    assert split_urls("http://a:1/v1,b:2/v1") == ["http://a:1/v1", "b:2/v1"]


def test_a_run_recorded_with_a_secret_in_plain_text_resumes_and_is_not_quoted() -> None:
    written = {"backend_options": {"base_url": f"http://u:{OPTION_PASSWORD}@h/v1", "threads": 2}}
    before = RunIdentity.model_validate({"settings": written, "templates": {}})
    now = RunIdentity.model_validate({"settings": redact_settings(written), "templates": {}})
    assert now.differences(before) == []
    changed = redact_settings(written)
    changed["backend_options"]["threads"] = 4
    found = RunIdentity.model_validate({"settings": changed, "templates": {}}).differences(before)
    assert len(found) == 1 and "backend_options" in found[0] and not _leaks(found[0])
