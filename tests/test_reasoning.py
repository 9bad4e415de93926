"""Thinking text is split from the answer, and a cut-off reasoning answer gets one follow-up."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from llm_agents.backends.base import ChatMessage, ModelOutput
from llm_agents.backends.mock import MockModel
from llm_agents.backends.reasoning import (
    answer_only_conversation,
    needs_answer_followup,
    resolve_truncated,
    split_reasoning,
    with_reasoning_split,
)

QUESTION = [ChatMessage(role="user", content="Which action?")]


@pytest.mark.parametrize(
    ("text", "answer", "reasoning", "finished"),
    [
        ("<think>trees are near</think>\nDO", "DO", "trees are near", True),
        ("<think>trees are near, I should", "", "trees are near, I should", False),
        ("plan first</think> MOVE_LEFT", "MOVE_LEFT", "plan first", True),
        ("NOOP", "NOOP", None, True),
        ("Sure. <think>hmm</think> DO", "Sure. DO", "hmm", True),
    ],
)
def test_split_reasoning_separates_thinking(
    text: str, answer: str, reasoning: str | None, finished: bool
) -> None:
    split = split_reasoning(text)
    assert " ".join(split.answer.split()) == answer
    assert split.reasoning == reasoning
    assert split.thinking_finished is finished


def test_thinking_opened_by_the_prompt_is_all_reasoning_until_closed() -> None:
    unfinished = split_reasoning("I see a tree", thinking_open_in_prompt=True)
    assert (unfinished.answer, unfinished.reasoning, unfinished.thinking_finished) == (
        "",
        "I see a tree",
        False,
    )
    finished = split_reasoning("I see a tree</think>DO", thinking_open_in_prompt=True)
    assert (finished.answer, finished.reasoning) == ("DO", "I see a tree")


def test_server_separated_reasoning_is_kept_before_inline_thinking() -> None:
    output = with_reasoning_split(ModelOutput(text="<think>b</think>DO"), reasoning="a")
    assert output.text == "DO"
    assert output.reasoning == "a\n\nb"


def test_only_truncated_reasoning_needs_a_followup() -> None:
    assert needs_answer_followup(ModelOutput(text="", reasoning="x", finish_reason="length"))
    assert not needs_answer_followup(ModelOutput(text="DO", reasoning="x", finish_reason="stop"))
    assert not needs_answer_followup(ModelOutput(text="MOVE_LE", finish_reason="length"))


def test_followup_conversation_replays_thinking_without_tags() -> None:
    cut = ModelOutput(text="", reasoning="the table is west", finish_reason="length")
    messages = answer_only_conversation(QUESTION, cut)
    assert messages[0] == QUESTION[0]
    assert messages[1].role == "assistant"
    assert messages[1].content == "the table is west"
    assert messages[2].role == "user"
    assert "only your final answer" in messages[2].content
    assert "{" not in messages[2].content


def _split_all(outputs: list[ModelOutput]) -> list[ModelOutput]:
    return [with_reasoning_split(output) for output in outputs]


def test_truncated_thinking_gets_exactly_one_followup_through_a_backend() -> None:
    # The mock answers in order: two first attempts, then the single follow-up.
    mock = MockModel(
        outputs=["<think>wood first, then", "<think>ok</think>NOOP", "DO"], cycle=False
    )
    conversations = [QUESTION, QUESTION]

    def generate(batch: Sequence[Sequence[ChatMessage]]) -> list[ModelOutput]:
        outputs = mock.generate(batch)
        # The mock cannot run out of tokens, so mark unterminated thinking as cut off.
        return _split_all(
            [
                o.model_copy(update={"finish_reason": "length"}) if "</think>" not in o.text else o
                for o in outputs
            ]
        )

    first = generate(conversations)
    resolved = resolve_truncated(conversations, first, generate)
    assert [o.text for o in resolved] == ["DO", "NOOP"]
    assert [o.followups for o in resolved] == [1, 0]
    assert resolved[0].reasoning == "wood first, then"
    assert resolved[0].completion_tokens == first[0].completion_tokens + 1
    assert len(mock.requests) == 3
    followup_request = mock.requests[2][0]
    assert followup_request[-2].content == "wood first, then"
    assert followup_request[-1].role == "user"


def test_a_failed_followup_keeps_the_first_attempt() -> None:
    cut = ModelOutput(text="", reasoning="hmm", finish_reason="length", completion_tokens=5)
    failing = MockModel(outputs=[], cycle=False)
    resolved = resolve_truncated([QUESTION], [cut], lambda batch: failing.generate(batch))
    assert resolved[0].finish_reason == "length"
    assert resolved[0].reasoning == "hmm"
    assert resolved[0].followups == 1
