"""Thinking text of reasoning models, shared by every backend.

Reasoning models write `<think>...</think>` before their answer. Backends pass each raw completion
through `split_reasoning` so only the answer reaches the parser, and keep the thinking in
`ModelOutput.reasoning` for logs. Chat templates that open the thinking block in the prompt
(the completion then starts inside it) are handled with `thinking_open_in_prompt=True`, or
detected from a closing tag without an opening one.

A completion cut off by the token limit while the model was thinking (or just after) has no
usable answer. `resolve_truncated` makes one "answer only" follow-up request for exactly those
outputs (wording: `prompts/answer_only.j2`) and counts it in `ModelOutput.followups`.
"""

from __future__ import annotations

import collections
import re
from collections.abc import Callable, Sequence

from pydantic import BaseModel, ConfigDict

from llm_agents.backends.base import ChatMessage, Conversation, ModelOutput
from prompts import render_template

THINK_OPEN = "<think>"
THINK_CLOSE = "</think>"
#: Tags of a reasoning block; `<thinking>`, `<reasoning>` and `<thought>` come from prompts and
#: models that name the block themselves.
REASONING_TAGS = ("think", "thinking", "reasoning", "thought")
_TAG = re.compile(r"<(/?)(" + "|".join(REASONING_TAGS) + r")>", re.IGNORECASE | re.ASCII)
_CLOSE_TAG = re.compile(r"</(?:" + "|".join(REASONING_TAGS) + r")>", re.IGNORECASE | re.ASCII)
ANSWER_ONLY_TEMPLATE = "answer_only.j2"

#: One raw backend call: conversations in, one raw output per conversation out.
GenerateCall = Callable[[Sequence[Conversation]], list[ModelOutput]]
#: One raw backend call with optional choices (None: free generation).
ChoiceGenerateCall = Callable[[Sequence[Conversation], list[str] | None], list[ModelOutput]]


class ReasoningSplit(BaseModel):
    """A completion separated into thinking and answer."""

    model_config = ConfigDict(frozen=True)

    answer: str
    """The text after the thinking block (stripped); empty when the thinking never closed."""
    reasoning: str | None
    """The thinking text (stripped), or None when the completion had no thinking block."""
    thinking_finished: bool
    """False when the completion stopped inside the thinking block (no closing tag)."""


def split_reasoning(text: str, *, thinking_open_in_prompt: bool = False) -> ReasoningSplit:
    """Separate the reasoning blocks from the answer in one raw completion, in linear time.

    The one place reasoning is stripped: the backends split their outputs with it and the parser
    reads `answer`. Blocks open with any of `REASONING_TAGS` (ASCII case ignored) and close with
    the same tag; another opening inside a block is part of its text. An opening with no close
    makes the rest reasoning; a close with no opening (the chat template opened the block in the
    prompt) makes everything before the last such close reasoning.
    """
    if thinking_open_in_prompt:
        text = THINK_OPEN + text
    # Pieces as (offset in text, piece), so reasoning is logged in the order it was written.
    kept: list[tuple[int, str]] = []
    reasoning: list[tuple[int, str]] = []
    position = 0
    # One pass over the tags: each is looked at once, so a completion made of thousands of
    # closed blocks costs its length, not its length times the number of blocks.
    block_tag: str | None = None
    body_start = 0
    found_tag = False
    for match in _TAG.finditer(text):
        found_tag = True
        closing, tag = match.group(1) == "/", match.group(2).lower()
        if block_tag is None:
            if not closing:
                kept.append((position, text[position : match.start()]))
                block_tag, body_start = tag, match.end()
        elif closing and tag == block_tag:
            reasoning.append((body_start, text[body_start : match.start()]))
            block_tag, position = None, match.end()
    finished = block_tag is None
    if finished:
        kept.append((position, text[position:]))
    else:
        reasoning.append((body_start, text[body_start:]))
    answer = "".join(piece for _, piece in kept)
    # Joining the pieces can bring together a close tag, exactly as one written there would.
    last_close = collections.deque(_CLOSE_TAG.finditer(answer), maxlen=1)
    if last_close:
        # Everything before the last close is reasoning (the template opened the block).
        cut, seen = last_close[0].start(), 0
        for offset, piece in kept:
            if seen >= cut:
                break
            reasoning.append((offset, piece[: cut - seen]))
            seen += len(piece)
        reasoning.sort()
        answer = answer[last_close[0].end() :]
    parts = [piece.strip() for _, piece in reasoning if piece.strip()]
    return ReasoningSplit(
        answer=answer.strip(),
        reasoning="\n\n".join(parts) if found_tag else None,
        thinking_finished=finished,
    )


def with_reasoning_split(
    output: ModelOutput,
    *,
    thinking_open_in_prompt: bool = False,
    reasoning: str | None = None,
) -> ModelOutput:
    """Return `output` with its thinking moved from `text` to `reasoning`.

    `reasoning` is thinking the server already separated (e.g. a `reasoning_content` field);
    it is kept ahead of any thinking still found in the text.
    """
    split = split_reasoning(output.text, thinking_open_in_prompt=thinking_open_in_prompt)
    parts = [part for part in (reasoning, split.reasoning) if part]
    return output.model_copy(
        update={"text": split.answer, "reasoning": "\n\n".join(parts) if parts else None}
    )


def needs_answer_followup(output: ModelOutput) -> bool:
    """True when the token limit cut a reasoning model off before or during its answer.

    Outputs without reasoning are left alone: a plain truncated answer is the parser's job.
    """
    return output.finish_reason == "length" and output.reasoning is not None


def answer_only_conversation(conversation: Conversation, output: ModelOutput) -> list[ChatMessage]:
    """The follow-up request: the conversation, the cut-off attempt, then "answer only".

    The thinking is replayed as plain assistant text, not inside think tags, because many chat
    templates drop tagged thinking from earlier turns and the model would lose its work.
    """
    attempt = "\n\n".join(part for part in (output.reasoning, output.text) if part)
    request = _answer_only_text(has_partial_answer=bool(output.text.strip()))
    messages = list(conversation)
    if attempt:
        messages.append(ChatMessage(role="assistant", content=attempt))
    messages.append(ChatMessage(role="user", content=request))
    return messages


def merge_followup(first: ModelOutput, followup: ModelOutput) -> ModelOutput:
    """Combine a cut-off output with its follow-up: the follow-up's answer, both costs."""
    if followup.finish_reason == "error":
        # The cut-off answer is still better than nothing; the parser decides if it is usable.
        return first.model_copy(update={"followups": first.followups + 1})
    reasoning = [part for part in (first.reasoning, followup.reasoning) if part]
    return followup.model_copy(
        update={
            "reasoning": "\n\n".join(reasoning) if reasoning else None,
            "prompt_tokens": first.prompt_tokens + followup.prompt_tokens,
            "computed_prompt_tokens": None
            if first.computed_prompt_tokens is None or followup.computed_prompt_tokens is None
            else first.computed_prompt_tokens + followup.computed_prompt_tokens,
            "completion_tokens": first.completion_tokens + followup.completion_tokens,
            "latency_s": first.latency_s + followup.latency_s,
            "followups": first.followups + followup.followups + 1,
        }
    )


def resolve_truncated(
    conversations: Sequence[Conversation],
    outputs: list[ModelOutput],
    generate: GenerateCall,
) -> list[ModelOutput]:
    """Make one "answer only" follow-up call for every output cut off while reasoning.

    `outputs` must already be split (`with_reasoning_split`); `generate` is the backend's raw
    call, and its outputs must be split too. Never more than one follow-up per answer.
    """
    pending = [i for i, output in enumerate(outputs) if needs_answer_followup(output)]
    if not pending:
        return outputs
    followups = generate([answer_only_conversation(conversations[i], outputs[i]) for i in pending])
    resolved = list(outputs)
    for i, followup in zip(pending, followups, strict=True):
        resolved[i] = merge_followup(outputs[i], followup)
    return resolved


def generate_with_followup(
    conversations: Sequence[Conversation],
    choices: Sequence[str] | None,
    generate: ChoiceGenerateCall,
) -> list[ModelOutput]:
    """`ModelAPI.generate` over a backend's raw call `generate(conversations, choices)`.

    With choices, one call (a choice has no thinking to cut off). Without, a free call, then one
    "answer only" follow-up for the outputs cut off while reasoning (`resolve_truncated`).
    """
    if choices:
        return generate(conversations, list(choices))
    outputs = generate(conversations, None)
    return resolve_truncated(conversations, outputs, lambda pending: generate(pending, None))


def _answer_only_text(*, has_partial_answer: bool) -> str:
    return render_template(ANSWER_ONLY_TEMPLATE, {"has_partial_answer": has_partial_answer})
