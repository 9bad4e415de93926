"""Grounding: asking a model what an instruction's goal is, and reading its answer as a typed goal.

The prompt (`ground.j2`) shows the achievement names the variant's EASY goals can use (the 22 the
checker scores, in either variant) and asks for one JSON object `{"required": [...],
"forbidden": [...]}`. The answer is read in stages: the whole answer as JSON, else a fenced code
block, else the first `{...}` in the text; names are matched case-insensitively with spaces or
underscores. Anything that is not exactly a well-formed goal over known names is `invalid`, with
the reason: an answer is never guessed at. `--choice` answers pick one of the goals' canonical
JSON (`reading_options`) instead, read by the same parser.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal

from pydantic import ValidationError

from env.achievements import ACHIEVEMENT_IDS
from env.variant import Variant
from llm_agents.backends.base import ChatMessage
from llm_agents.run_data.readings import EasyReading, GoalReading, Grounding
from prompts import render_blocks

GROUND_TEMPLATE = "ground"
_FENCED = re.compile(r"```(?:json)?\s*(\{.*?\})\s*```", re.DOTALL)
_FIELDS = ("required", "forbidden")

__all__ = [
    "GROUND_TEMPLATE",
    "goal_vocabulary",
    "grounding_messages",
    "parse_grounding",
    "reading_json",
    "reading_options",
]


def goal_vocabulary(variant: Variant) -> tuple[str, ...]:
    """The achievement names a goal of `variant` can name: the EASY checker's, in id order."""
    return tuple(name for name in variant.achievement_names if name in ACHIEVEMENT_IDS)


def grounding_messages(
    instruction: str, variant: Variant, templates_dir: str | Path | None = None
) -> list[ChatMessage]:
    """The conversation asking for `instruction`'s goal as JSON."""
    context = {
        "instruction": instruction,
        "achievements": [
            {"name": name, "words": name.lower().replace("_", " ")}
            for name in goal_vocabulary(variant)
        ],
    }
    return [
        ChatMessage(role=role, content=text)
        for role, text in render_blocks(GROUND_TEMPLATE, context, templates_dir)
    ]


def reading_json(reading: GoalReading) -> str:
    """The canonical JSON of a reading, as the prompt asks for it."""
    return json.dumps({"required": list(reading.required), "forbidden": list(reading.forbidden)})


def reading_options(readings: Iterable[GoalReading]) -> tuple[str, ...]:
    """The distinct readings' canonical JSON, in first-seen order: the options of `--choice`."""
    return tuple(dict.fromkeys(reading_json(reading) for reading in readings))


def _invalid(
    stage: Literal["json", "fenced", "embedded", "none"], reason: str, raw: str
) -> Grounding:
    return Grounding(outcome="invalid", stage=stage, reason=" ".join(reason.split()), raw=raw)


def _first_object(text: str) -> str | None:
    """The first balanced `{...}` of `text` (braces inside strings are not special-cased: the
    JSON parse that follows rejects a cut that went wrong)."""
    start = text.find("{")
    while start != -1:
        depth = 0
        for end in range(start, len(text)):
            depth += {"{": 1, "}": -1}.get(text[end], 0)
            if depth == 0:
                return text[start : end + 1]
        start = text.find("{", start + 1)
    return None


def _located(raw: str) -> tuple[Literal["json", "fenced", "embedded", "none"], object]:
    """Where the answer's JSON object is, and it parsed; (`none`, None) when there is none."""
    text = raw.strip()
    try:
        return "json", json.loads(text)
    except json.JSONDecodeError:
        pass
    fenced = _FENCED.search(text)
    if fenced:
        try:
            return "fenced", json.loads(fenced.group(1))
        except json.JSONDecodeError:
            pass
    embedded = _first_object(text)
    if embedded is not None:
        try:
            return "embedded", json.loads(embedded)
        except json.JSONDecodeError as err:
            return "embedded", err
    return "none", None


def _names(value: object, field: str, vocabulary: Sequence[str]) -> list[str] | str:
    """The field's names in the vocabulary's spelling, or why they cannot be read."""
    if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
        return f"not a goal: {field} is not a list of names"
    known = {name.replace("_", " "): name for name in vocabulary}
    names = []
    for item in value:
        name = known.get(" ".join(item.replace("_", " ").split()).upper())
        if name is None:
            return f"unknown achievement: {item!r} in {field}"
        names.append(name)
    return names


def parse_grounding(raw: str, variant: Variant) -> Grounding:
    """The goal an answer states, or `invalid` with the reason (never a guess)."""
    stage, parsed = _located(raw)
    if parsed is None:
        return _invalid(stage, "no JSON object in the answer", raw)
    if isinstance(parsed, json.JSONDecodeError):
        return _invalid(stage, f"JSON does not parse: {parsed.msg}", raw)
    if not isinstance(parsed, dict):
        return _invalid(stage, "not a goal: the JSON is not an object", raw)
    extra = sorted(set(parsed) - set(_FIELDS))
    if extra:
        return _invalid(stage, f"not a goal: unexpected keys {', '.join(map(str, extra))}", raw)
    vocabulary = goal_vocabulary(variant)
    fields: dict[str, list[str]] = {}
    for field in _FIELDS:
        names = _names(parsed.get(field, []), field, vocabulary)
        if isinstance(names, str):
            return _invalid(stage, names, raw)
        fields[field] = names
    try:
        reading = EasyReading(**fields)
    except ValidationError as err:
        message = err.errors()[0]["msg"].removeprefix("Value error, ")
        return _invalid(stage, f"not a goal: {message}", raw)
    return Grounding(outcome="valid", stage=stage, reading=reading, raw=raw)
