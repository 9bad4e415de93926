"""Model specs name a backend; a typo gets suggestions and a missing extra its install command."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, ClassVar

import pytest
from pydantic import BaseModel, ValidationError

from env.errors import UserError
from llm_agents import backends
from llm_agents.backends import (
    BackendNotInstalled,
    CachedModel,
    GenerateConfig,
    ModelAPI,
    ModelOutput,
    get_model,
    parse_model_spec,
)
from llm_agents.backends.base import ChatMessage, ChoiceRule, ChoiceSet
from llm_agents.backends.mock import MockModel


@pytest.mark.parametrize(
    ("spec", "backend", "name", "base_url"),
    [
        ("hf:smollm2-135m", "hf", "smollm2-135m", None),
        ("HF:/models/x", "hf", "/models/x", None),
        ("openai:gpt-4o@http://localhost:8000/v1", "openai", "gpt-4o", "http://localhost:8000/v1"),
        ("openai:org/model@name@http://h:1/v1", "openai", "org/model@name", "http://h:1/v1"),
        ("vllm:Qwen/Qwen3-0.6B", "vllm", "Qwen/Qwen3-0.6B", None),
        ("mock:cycle:A|B", "mock", "cycle:A|B", None),
        ("mock:", "mock", "noop", None),
    ],
)
def test_specs_are_split_into_backend_model_and_url(
    spec: str, backend: str, name: str, base_url: str | None
) -> None:
    parsed = parse_model_spec(spec)
    assert (parsed.backend, parsed.name, parsed.base_url) == (backend, name, base_url)


@pytest.mark.parametrize(
    ("spec", "suggestion"),
    [("hff:smollm2-135m", "hf"), ("vlm:x", "vllm"), ("opneai:gpt@http://h", "openai")],
)
def test_a_mistyped_backend_gets_close_matches(spec: str, suggestion: str) -> None:
    with pytest.raises(UserError, match=f"did you mean {suggestion}") as caught:
        parse_model_spec(spec)
    assert spec in str(caught.value)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("smollm2-135m", "no backend"),
        ("zzzzzz:model", "unknown backend 'zzzzzz'"),
        ("hf:", "names no model"),
    ],
)
def test_bad_specs_are_user_errors(spec: str, message: str) -> None:
    with pytest.raises(UserError, match=message):
        parse_model_spec(spec)


def test_get_model_builds_the_backend_with_config_and_options() -> None:
    model = get_model("mock:cycle:A|B", GenerateConfig(max_tokens=5), latency_s=0.0)
    assert isinstance(model, MockModel)
    assert model.config.max_tokens == 5
    conversation = [ChatMessage(role="user", content="go")]
    assert [o.text for o in model.generate([conversation] * 3)] == ["A", "B", "A"]


class RecorderOptions(BaseModel):
    base_url: str | None = None


class Recorder(ModelAPI):
    """Records how the registry constructed it."""

    backend_name = "openai"
    options_model = RecorderOptions

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        super().__init__(model_name, config, **options)

    def _generate(self, conversations: Any, choices: Any) -> list[ModelOutput]:
        return []


def test_the_base_url_reaches_the_http_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(backends.BACKENDS, "openai", f"{__name__}:Recorder")
    model = get_model("openai:gpt-4o@http://127.0.0.1:9/v1")
    assert isinstance(model, Recorder)
    assert model.model_name == "gpt-4o"
    assert model.options == {"base_url": "http://127.0.0.1:9/v1"}


@pytest.fixture
def broken_backend_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """A backend module whose third-party dependency is not installed."""
    (tmp_path / "craftext_fake_backend.py").write_text(
        "import craftext_dependency_that_is_not_installed\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "craftext_fake_backend", raising=False)
    return "craftext_fake_backend:Model"


def test_a_missing_extra_gives_the_install_command(
    monkeypatch: pytest.MonkeyPatch, broken_backend_module: str
) -> None:
    monkeypatch.setitem(backends.BACKENDS, "vllm", broken_backend_module)
    with pytest.raises(BackendNotInstalled, match=r"pip install 'craftext-llm\[vllm\]'") as caught:
        get_model("vllm:some-model")
    assert "craftext_dependency_that_is_not_installed" in str(caught.value)
    assert isinstance(caught.value, UserError)


def test_a_dependency_that_names_no_module_is_still_explained(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "craftext_unnamed_backend.py").write_text(
        "raise ModuleNotFoundError('the tokenizers wheel is incomplete')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(backends.BACKENDS, "vllm", "craftext_unnamed_backend:Model")
    with pytest.raises(BackendNotInstalled) as caught:
        get_model("vllm:some-model")
    assert "None" not in str(caught.value)
    assert "the tokenizers wheel is incomplete" in str(caught.value)


def test_a_missing_project_module_is_a_bug_not_a_user_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(backends.BACKENDS, "hf", "llm_agents.backends.no_such_module:X")
    with pytest.raises(ModuleNotFoundError) as caught:
        get_model("hf:x")
    assert not isinstance(caught.value, UserError)


class GuidedOnly(Recorder):
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"guided"})
    choice_rule_gaps: ClassVar[dict[ChoiceRule, str]] = {"loglik": "no prompt scores here"}


def test_a_choice_rule_the_backend_lacks_is_refused_with_the_rules_it_has(tmp_path: Path) -> None:
    model = GuidedOnly("m")
    model.check_choice_rule("guided")
    refusal = r"openai backend cannot choose by 'loglik' \(it supports: guided\): no prompt scores"
    with pytest.raises(UserError, match=refusal):
        model.check_choice_rule("loglik")
    # A response cache answers for the backend it wraps.
    with pytest.raises(UserError, match="cannot choose by 'loglik'"):
        CachedModel(model, tmp_path / "cache.sqlite").check_choice_rule("loglik")


def test_a_choice_set_needs_options_and_a_known_rule() -> None:
    with pytest.raises(ValidationError):
        ChoiceSet(options=(), rule="loglik")
    with pytest.raises(ValidationError):
        ChoiceSet(options=("DO",), rule="best")  # type: ignore[arg-type]


def test_the_base_refuses_a_choice_rule_before_the_backend_answers() -> None:
    class GuidedOnly(Recorder):
        backend_name = "guided-only"
        choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"guided"})
        answered = 0

        def _generate(self, conversations: Any, choices: Any) -> list[ModelOutput]:
            GuidedOnly.answered += 1
            return [ModelOutput(text="DO") for _ in conversations]

    model = GuidedOnly("m")
    conversation = [ChatMessage(role="user", content="go")]
    with pytest.raises(UserError, match="cannot choose by 'loglik'"):
        model.generate([conversation], ChoiceSet(options=("DO",), rule="loglik"))
    assert GuidedOnly.answered == 0
    assert model.generate([conversation], ChoiceSet(options=("DO",), rule="guided"))[0].text == "DO"
    assert GuidedOnly.answered == 1


def test_an_older_transformers_is_refused_at_start_with_the_install_command(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:

    import transformers

    from llm_agents.cli import main

    monkeypatch.setattr(transformers, "__version__", "4.57.1")
    monkeypatch.delitem(sys.modules, "llm_agents.backends.hf", raising=False)
    out = tmp_path / "run"
    argv = ["eval", "--model", "hf:smollm2-135m", "--variant", "classic", "--categories", "combo"]
    code = main([*argv, "--limit", "1", "--output-dir", str(out), "--no-progress"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert "needs transformers>=5.0, this environment has 4.57.1" in lines[0]
    assert "pip install -U 'craftext-llm[hf]'" in lines[0]
    assert not out.exists()


def test_the_transformers_bound_refused_below_is_the_one_the_package_declares() -> None:
    import tomllib

    from llm_agents.backends.hf import MIN_TRANSFORMERS

    declared = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    hf_extra = declared["project"]["optional-dependencies"]["hf"]
    assert f"transformers>={MIN_TRANSFORMERS}" in hf_extra
