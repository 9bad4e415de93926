"""Thinking text is split from the answer, and a cut-off reasoning answer gets one follow-up."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from llm_agents.agents.answers.parser import parse_action
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


# ---------------------------------------------------------------- one stripping rule, linear

FRAGMENTS = [
    "<think>",
    "</think>",
    "<THINK>",
    "</Think>",
    "<thinking>",
    "</thinking>",
    "<reasoning>",
    "</reasoning>",
    "<thought>",
    "</thought>",
    "<thi",
    "nk>",
    "</",
    "<",
    ">",
    "DO",
    "ACTION: UP",
    "move west",
    "\n",
    " ",
]


def reference_answer(text: str) -> str:
    """The stripping rule written the plain way (quadratic), as the oracle for the fast one."""
    tags = ("think", "thinking", "reasoning", "thought")
    lowered = text.lower()
    kept: list[str] = []
    position = 0
    while True:
        openings = [(lowered.find(f"<{tag}>", position), tag) for tag in tags]
        present = [(index, tag) for index, tag in openings if index >= 0]
        if not present:
            kept.append(text[position:])
            break
        start, tag = min(present)
        kept.append(text[position:start])
        close = lowered.find(f"</{tag}>", start)
        if close < 0:
            break
        position = close + len(tag) + 3
    answer = "".join(kept)
    last_close = max(answer.lower().rfind(f"</{tag}>") for tag in tags)
    if last_close >= 0:
        answer = answer[answer.index(">", last_close) + 1 :]
    return answer.strip()


@settings(max_examples=400, deadline=None)
@given(parts=st.lists(st.sampled_from(FRAGMENTS), max_size=40))
def test_split_matches_the_plain_rule_on_any_mix_of_blocks(parts: list[str]) -> None:
    text = "".join(parts)
    split = split_reasoning(text)
    assert split.answer == reference_answer(text)
    # Text after the completion survives exactly when no block was left open.
    assert split.thinking_finished == reference_answer(text + "\nX").endswith("X")


@pytest.mark.parametrize(
    ("text", "answer", "reasoning", "finished"),
    [
        ("<think>a</think>b<think>c</think>UP", "bUP", "a\n\nc", True),
        ("<think>a<think>b</think>c</think>UP", "UP", "a<think>b\n\nc", True),
        ("<Thought>a</thought>DO<reasoning>b", "DO", "a\n\nb", False),
        ("<think>x</thought></think>NOOP", "NOOP", "x</thought>", True),
    ],
)
def test_every_block_of_every_tag_is_reasoning(
    text: str, answer: str, reasoning: str, finished: bool
) -> None:
    split = split_reasoning(text)
    assert (split.answer, split.reasoning, split.thinking_finished) == (answer, reasoning, finished)


def cpu_seconds(run: Callable[[], object], repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.thread_time()
        run()
        best = min(best, time.thread_time() - start)
    return best


@settings(max_examples=12, deadline=None)
@given(unit=st.lists(st.sampled_from(FRAGMENTS), min_size=1, max_size=12).map("".join))
def test_parsing_any_mix_of_blocks_takes_linear_time(unit: str) -> None:
    # Work grows 4x for 4x the text when linear and 16x when quadratic; the bound sits between
    # with room for noise, and each timing is the best of three in this thread's CPU time.
    copies = max(1, 80_000 // len(unit))
    small = cpu_seconds(lambda: parse_action(unit * copies, "classic"))
    large = cpu_seconds(lambda: parse_action(unit * copies * 4, "classic"))
    assert large <= 9 * max(small, 1e-3), (unit, small, large)
