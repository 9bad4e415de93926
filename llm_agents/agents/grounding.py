"""Grounding: asking a model what an instruction's goal is, and reading its answer as a typed goal.

The prompt (`ground.j2`) offers the goal kinds of the difficulty being grounded
(`env.goals.DIFFICULTY_KINDS`) with the names their fields take in the variant: for EASY only
achievements goals, `{"required": [...], "forbidden": [...]}` over the achievement names the
checker scores; for Medium and Hard also the placing goals, `{"kind": ..., ...}` with their typed
parameters (Craftax block names, inventory items, sides, sizes, counts). The answer is read in
stages: the whole answer as JSON, else a fenced code block, else the first `{...}` in the text;
names are matched case-insensitively with spaces or underscores; an answer with no `kind` is an
achievements goal. Anything that is not exactly a well-formed goal of an offered kind over known
names is `invalid`, with the reason: an answer is never guessed at. `--choice` answers pick one
of the goals' canonical JSON (`reading_options`) instead, read by the same parser.

With `--grounding-shots N`, the request first shows N worked examples: instructions of the
difficulty's training goals, each answered with its goal's canonical JSON, as earlier turns of the
conversation (`grounding_examples`). No text is ever shown its own answer: every text takes the
same fixed list, less each example whose goal it phrases or whose canonical reading equals the
text's own (a test paraphrase of a goal that training states in other words, or a train text
whose goal another training goal repeats), the examples after them taking their places. That
skip is the only way the answer shapes the request.

The canonical JSON of a reading (`reading_json`) is one per difficulty, as its prompt asks for
it: EASY's achievements goal without its `kind`, every goal of Medium and Hard with it; the
worked examples and the `--choice` options are both written in it.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal, Protocol, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from env.achievements import ACHIEVEMENT_IDS
from env.goals import (
    CROSS_TYPES,
    DEFAULT_DIFFICULTY,
    DIFFICULTY_KINDS,
    SIDES,
    AnyGoal,
    Dataset,
    Difficulty,
    GoalKind,
    category_split,
    run_category,
)
from env.scenario_tasks import CLASSIC_INVENTORY_SLOTS, INVENTORY_SLOTS
from env.variant import Variant
from llm_agents.backends.base import ChatMessage
from llm_agents.run_data.readings import (
    READING_CLASSES,
    AchievementsReading,
    GoalReading,
    Grounding,
    reading_of,
)
from prompts import render_blocks

GROUND_TEMPLATE = "ground"
_FENCED = re.compile(r"```(?:json)?\s*(\{.*?\})\s*```", re.DOTALL)
_FIELDS = ("required", "forbidden")
_Stage = Literal["json", "fenced", "embedded", "none"]
#: The placing goals' fields that name a block, an inventory item, or take a fixed word.
_BLOCK_FIELDS = frozenset({"place", "target", "block"})
_ITEM_FIELDS = frozenset({"collect"})
_WORDS: dict[str, tuple[str, ...]] = {"side": SIDES, "cross": CROSS_TYPES}

__all__ = [
    "GROUND_TEMPLATE",
    "GroundingExample",
    "WorkedExample",
    "examples_digest",
    "examples_for",
    "goal_vocabulary",
    "grounding_examples",
    "grounding_messages",
    "inventory_items",
    "parse_grounding",
    "reading_json",
    "reading_options",
    "training_examples",
]


def goal_vocabulary(variant: Variant) -> tuple[str, ...]:
    """The achievement names a goal of `variant` can name: the EASY checker's, in id order."""
    return tuple(name for name in variant.achievement_names if name in ACHIEVEMENT_IDS)


def inventory_items(variant: Variant) -> tuple[str, ...]:
    """The items a conditional-placing goal of `variant` can count (the checker's slots)."""
    return CLASSIC_INVENTORY_SLOTS if variant is Variant.CLASSIC else INVENTORY_SLOTS


class GroundingExample(BaseModel):
    """A worked example shown before the instruction: a training goal's instruction and answer."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    instruction: str
    """The goal's original instruction."""
    answer: str
    """The goal's canonical JSON (`reading_json`), as a right answer would give it."""
    reading: GoalReading
    """The goal as a reading: a text whose own reading equals it is not shown this example."""
    texts: frozenset[str]
    """Every phrasing of the goal: a text among them is not shown this example."""


def grounding_examples(goals: Sequence[AnyGoal]) -> tuple[GroundingExample, ...]:
    """Worked examples from `goals` (a difficulty's training goals), in the order they are
    offered: goal kinds and categories taken in turn, so a few shots show several kinds, and
    within each an order fixed by a digest of the instruction."""
    groups: dict[tuple[str, str], list[AnyGoal]] = {}
    for goal in sorted(goals, key=lambda g: hashlib.sha256(g.instruction.encode()).hexdigest()):
        groups.setdefault((goal.kind, run_category(goal)), []).append(goal)
    queues = [groups[key] for key in sorted(groups)]
    ordered = [
        queue[depth] for depth in range(len(goals)) for queue in queues if depth < len(queue)
    ]
    return tuple(
        GroundingExample(
            instruction=goal.instruction,
            answer=reading_json(reading_of(goal), goal.difficulty),
            reading=reading_of(goal),
            texts=frozenset(goal.texts),
        )
        for goal in ordered
    )


def examples_digest(examples: Sequence[GroundingExample]) -> str:
    """SHA-256 of a worked-example list as it is offered (order, instructions, answers and the
    phrasings each is withheld from): part of the identity of a run that shows examples."""
    content = [[example.instruction, example.answer, sorted(example.texts)] for example in examples]
    text = json.dumps(content, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def training_examples(dataset: Dataset, difficulty: Difficulty) -> tuple[GroundingExample, ...]:
    """The worked examples of `difficulty`: its train split's goals (a `UserError` when the
    dataset has none)."""
    return grounding_examples(dataset.split(category_split("train", difficulty)))


class WorkedExample(Protocol):
    """A worked example of some goal: withheld from a text that phrases that goal or whose own
    reading is it (grounding's examples, the skills agent's demonstrations)."""

    @property
    def reading(self) -> GoalReading: ...
    @property
    def texts(self) -> frozenset[str]: ...


Example = TypeVar("Example", bound=WorkedExample)


def examples_for(
    text: str, answer: GoalReading, examples: Sequence[Example], shots: int
) -> tuple[Example, ...]:
    """The first `shots` examples that neither phrase `text`'s goal nor read as `answer`, its
    canonical reading: the one rule by which a text is never shown its own answer."""
    return tuple(
        example for example in examples if text not in example.texts and example.reading != answer
    )[:shots]


def grounding_messages(
    instruction: str,
    variant: Variant,
    templates_dir: str | Path | None = None,
    difficulty: Difficulty = DEFAULT_DIFFICULTY,
    examples: Sequence[GroundingExample] = (),
    shots: int = 0,
    answer: GoalReading | None = None,
) -> list[ChatMessage]:
    """The conversation asking for `instruction`'s goal as JSON, offering `difficulty`'s kinds,
    after the first `shots` of `examples` that neither phrase its goal nor read as `answer` (its
    goal's reading, needed whenever examples are shown), as earlier turns (each instruction
    asked as the template asks, answered)."""
    if shots and examples:
        if answer is None:
            raise ValueError("worked examples are chosen knowing the text's goal: pass answer")
        examples = examples_for(instruction, answer, examples, shots)
    else:
        examples = ()
    kinds = DIFFICULTY_KINDS[difficulty]
    context = {
        "achievements": [
            {"name": name, "words": name.lower().replace("_", " ")}
            for name in goal_vocabulary(variant)
        ],
        "placing": [kind for kind in kinds if kind != "achievements"],
        "with_achievements": "achievements" in kinds,
        "blocks": list(variant.block_names),
        "items": list(inventory_items(variant)),
        "sides": list(SIDES),
        "crosses": list(CROSS_TYPES),
        "worked_examples": bool(examples),
    }
    messages = [
        ChatMessage(role=role, content=text)
        for role, text in render_blocks(
            GROUND_TEMPLATE, context | {"instruction": instruction}, templates_dir
        )
    ]
    turns: list[ChatMessage] = []
    for example in examples:
        asked = render_blocks(
            GROUND_TEMPLATE, context | {"instruction": example.instruction}, templates_dir
        )
        turns += [ChatMessage(role=role, content=text) for role, text in asked if role == "user"]
        turns.append(ChatMessage(role="assistant", content=example.answer))
    split = next((i for i, m in enumerate(messages) if m.role == "user"), len(messages))
    return [*messages[:split], *turns, *messages[split:]]


def reading_json(reading: GoalReading, difficulty: Difficulty = DEFAULT_DIFFICULTY) -> str:
    """The canonical JSON of a reading, as `difficulty`'s prompt asks for it: an achievements
    goal without its kind on EASY (whose prompt offers no other kind), every goal with its kind
    on Medium and Hard."""
    if isinstance(reading, AchievementsReading) and difficulty == "easy":
        return json.dumps(
            {"required": list(reading.required), "forbidden": list(reading.forbidden)}
        )
    return json.dumps(reading.model_dump(mode="json"))


def reading_options(
    readings: Iterable[GoalReading], difficulty: Difficulty = DEFAULT_DIFFICULTY
) -> tuple[str, ...]:
    """The distinct readings' canonical JSON (`difficulty`'s), in first-seen order: the options
    of `--choice`."""
    return tuple(dict.fromkeys(reading_json(reading, difficulty) for reading in readings))


def _invalid(stage: _Stage, reason: str, raw: str) -> Grounding:
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


def _located(raw: str) -> tuple[_Stage, object]:
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


def _spelled(item: str) -> str:
    return " ".join(item.replace("_", " ").split()).upper()


def _names(value: object, field: str, vocabulary: Sequence[str]) -> list[str] | str:
    """The field's names in the vocabulary's spelling, or why they cannot be read."""
    if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
        return f"not a goal: {field} is not a list of names"
    known = {name.replace("_", " "): name for name in vocabulary}
    names = []
    for item in value:
        name = known.get(_spelled(item))
        if name is None:
            return f"unknown achievement: {item!r} in {field}"
        names.append(name)
    return names


def _name(value: object, vocabulary: Sequence[str]) -> str | None:
    """`value` in the vocabulary's spelling; None when it is not one of its names."""
    if not isinstance(value, str):
        return None
    known = {_spelled(name): name for name in vocabulary}
    return known.get(_spelled(value))


def _achievements(parsed: dict[str, object], variant: Variant) -> AchievementsReading | str:
    vocabulary = goal_vocabulary(variant)
    fields: dict[str, list[str]] = {}
    for field in _FIELDS:
        names = _names(parsed.get(field, []), field, vocabulary)
        if isinstance(names, str):
            return names
        fields[field] = names
    # A name in both lists is read as required: of the two readings, the only one whose goal
    # can be met (no schema can keep a structured answer from naming it twice).
    fields["forbidden"] = [name for name in fields["forbidden"] if name not in fields["required"]]
    return AchievementsReading(**fields)


def _placing(kind: GoalKind, parsed: dict[str, object], variant: Variant) -> GoalReading | str:
    """The placing goal's fields checked one by one against the variant's names; numbers must
    be JSON integers and flags JSON booleans (a "2" or a 1 for true is not read as one)."""
    wanted = [name for name in READING_CLASSES[kind].model_fields if name != "kind"]
    missing = [name for name in wanted if name not in parsed]
    if missing:
        return f"not a goal: {kind} lacks {', '.join(missing)}"
    fields: dict[str, object] = {"kind": kind}
    for field in wanted:
        value = parsed[field]
        if field in _BLOCK_FIELDS or field in _ITEM_FIELDS or field in _WORDS:
            if field in _BLOCK_FIELDS:
                vocabulary, what = variant.block_names, "block"
            elif field in _ITEM_FIELDS:
                vocabulary, what = inventory_items(variant), "item"
            else:
                vocabulary, what = _WORDS[field], field
            name = _name(value, vocabulary)
            if name is None:
                return f"unknown {what}: {value!r} in {field}"
            fields[field] = name
        elif field == "diagonal":
            if not isinstance(value, bool):
                return f"not a goal: {field} is not true or false"
            fields[field] = value
        else:
            if isinstance(value, bool) or not isinstance(value, int):
                return f"not a goal: {field} is not a whole number"
            fields[field] = value
    return READING_CLASSES[kind].model_validate(fields)  # type: ignore[return-value]


def parse_grounding(
    raw: str, variant: Variant, difficulty: Difficulty = DEFAULT_DIFFICULTY
) -> Grounding:
    """The goal an answer states, or `invalid` with the reason (never a guess at a name or a
    field; an achievement named both required and forbidden is read as required). The goal
    kinds read are those the prompt of `difficulty` offers."""
    stage, parsed = _located(raw)
    if parsed is None:
        return _invalid(stage, "no JSON object in the answer", raw)
    if isinstance(parsed, json.JSONDecodeError):
        return _invalid(stage, f"JSON does not parse: {parsed.msg}", raw)
    if not isinstance(parsed, dict):
        return _invalid(stage, "not a goal: the JSON is not an object", raw)
    offered = DIFFICULTY_KINDS[difficulty]
    # No kind means an achievements goal: EASY's prompt never asks for one.
    stated = parsed.get("kind", "achievements")
    kind = next((known for known in offered if known == stated), None)
    if kind is None:
        return _invalid(stage, f"unknown kind: {stated!r}; known: {', '.join(offered)}", raw)
    fields = _FIELDS if kind == "achievements" else tuple(READING_CLASSES[kind].model_fields)
    extra = sorted(set(parsed) - {"kind", *fields})
    if extra:
        return _invalid(stage, f"not a goal: unexpected keys {', '.join(map(str, extra))}", raw)
    try:
        reading = (
            _achievements(parsed, variant)
            if kind == "achievements"
            else _placing(kind, parsed, variant)
        )
    except ValidationError as err:
        message = err.errors()[0]["msg"].removeprefix("Value error, ")
        return _invalid(stage, f"not a goal: {message}", raw)
    if isinstance(reading, str):
        return _invalid(stage, reading, raw)
    return Grounding(outcome="valid", stage=stage, reading=reading, raw=raw)
