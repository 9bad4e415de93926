"""The scripted mock backend answers deterministically and records every request."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from env.errors import UserError
from llm_agents.backends import get_model
from llm_agents.backends.base import ERROR_CHARS, ChatMessage, ChoiceRule, ChoiceSet, ModelOutput
from llm_agents.backends.mock import MockModel


def ask(text: str) -> list[ChatMessage]:
    return [ChatMessage(role="user", content=text)]


def texts(model: MockModel, count: int) -> list[str]:
    return [o.text for o in model.generate([ask(str(i)) for i in range(count)])]


def test_the_default_script_answers_noop_forever() -> None:
    assert texts(MockModel(""), 3) == ["NOOP"] * 3
    assert texts(MockModel("noop"), 1) == ["NOOP"]


def test_cycle_repeats_and_list_runs_out() -> None:
    assert texts(MockModel("cycle:A|B|C"), 5) == ["A", "B", "C", "A", "B"]
    outputs = MockModel("list:A|B").generate([ask("x")] * 3)
    assert [o.text for o in outputs[:2]] == ["A", "B"]
    assert outputs[2].finish_reason == "error"
    assert "exhausted" in (outputs[2].error or "")


def test_the_counter_runs_across_calls() -> None:
    model = MockModel("cycle:A|B|C")
    assert texts(model, 2) == ["A", "B"]
    assert texts(model, 2) == ["C", "A"]


def test_a_script_file_is_cycled(tmp_path: Path) -> None:
    path = tmp_path / "answers.json"
    path.write_text(json.dumps(["DO", "NOOP"]))
    assert texts(MockModel(f"file:{path}"), 3) == ["DO", "NOOP", "DO"]


@pytest.mark.parametrize("content", ["{not json", '{"a": 1}', "[]", "[1, 2]"])
def test_a_bad_script_file_is_a_user_error(tmp_path: Path, content: str) -> None:
    path = tmp_path / "answers.json"
    path.write_text(content)
    with pytest.raises(UserError, match=r"answers\.json"):
        MockModel(f"file:{path}")


@pytest.mark.parametrize(
    ("script", "message"),
    [
        ("cycle:", "lists no answers"),
        ("banana", "unknown mock script"),
        ("file:/no/such", "cannot read"),
    ],
)
def test_bad_scripts_are_user_errors(script: str, message: str) -> None:
    with pytest.raises(UserError, match=message):
        get_model(f"mock:{script}")


@pytest.mark.parametrize("rule", ["loglik", "guided"])
def test_choice_mode_always_returns_one_of_the_choices(rule: ChoiceRule) -> None:
    model = MockModel("cycle:DO|JUMP")
    choices = ChoiceSet(options=("NOOP", "DO"), rule=rule)
    outputs = model.generate([ask("a"), ask("b")], choices=choices)
    assert [o.text for o in outputs] == ["DO", "NOOP"]
    assert all(o.finish_reason == "choice" for o in outputs)
    assert model.requests[0][1] == choices


def test_a_responder_sees_the_conversation_and_requests_are_recorded() -> None:
    model = MockModel(outputs=lambda conversation: conversation[-1].content.upper())
    outputs = model.generate([ask("left"), ask("right")], choices=None)
    assert [o.text for o in outputs] == ["LEFT", "RIGHT"]
    assert [(r[0][-1].content, r[1]) for r in model.requests] == [("left", None), ("right", None)]
    assert outputs[0].prompt_tokens == 1 and outputs[0].completion_tokens == 1


def test_fixed_latency_is_reported() -> None:
    [output] = MockModel("noop", latency_s=0.01).generate([ask("x")])
    assert output.latency_s == 0.01


def test_an_error_is_one_bounded_line_whatever_the_backend_wrote() -> None:
    output = ModelOutput(
        text="", finish_reason="error", error="Traceback:\n  line 1\n\tboom  " + "x" * 5000
    )
    assert output.error is not None and "\n" not in output.error and "\t" not in output.error
    assert output.error.startswith("Traceback: line 1 boom x")
    assert len(output.error) == ERROR_CHARS + 3
