"""Plans for plan-conditioned agents (CrafText PPO-T+): generate, check, repair, save and load.

A planner model rewrites every instruction as at most a few short numbered steps. The result is
one JSON object, instruction text -> plan text ("1. ...\\n2. ..."), the shape of CrafText's
official plan file, plus a sidecar JSON recording how it was made. Every answer is appended to a
JSONL journal as soon as it arrives; the plans file is rebuilt from the journal atomically, so an
interrupted run loses nothing and a rerun skips what is already planned.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from tqdm import tqdm

from env import craftax_names as names
from env.dataset import CATEGORY_SPLIT, Goal, check_split, load_dataset
from env.errors import UserError
from env.variant import Variant
from llm_agents.actions import action_catalogue
from llm_agents.backends.base import ChatMessage, ModelAPI, ModelOutput
from llm_agents.config import ModelSettings
from llm_agents.run_store import (
    append_lines,
    atomic_write_json,
    check_output_dir,
    complete_lines,
    make_output_dir,
)
from prompts import BlockRole, render_blocks, template_source

__all__ = [
    "PlanCheck",
    "PlanIssue",
    "PlanLimits",
    "PlanRecord",
    "PlanSummary",
    "PlannerConfig",
    "check_plan",
    "craftax_vocabulary",
    "goal_instructions",
    "is_known",
    "load_plans",
    "parse_plan",
    "plan_instructions",
    "run_planner",
    "unknown_words",
    "word_tokens",
]

PLANNER_TEMPLATE = "planner.j2"
REPAIR_TEMPLATE = "plan_repair.j2"

#: Enum members that are engine bookkeeping, not things a plan can name.
_INTERNAL_NAMES = frozenset(
    {"INVALID", "OUT_OF_BOUNDS", "DARKNESS", "NONE", "LADDER_DOWN_BLOCKED", "ARROW2"}
    | {"FIREBALL2", "ICEBALL2", "GRAVE2", "GRAVE3", "NECROMANCER_VULNERABLE"}
)
#: Achievement prefixes followed by a creature's name (DEFEAT_ZOMBIE, EAT_COW).
_CREATURE_PREFIXES = ("DEFEAT_", "EAT_")

#: Words any plan may use besides Craftax names: function words, generic verbs, directions,
#: counts, units of space and words about the plan itself. Synonyms of Craftax things ("rock",
#: "smelter", "workbench", "seeds") are deliberately absent: a plan must use the game's names.
_COMMON_WORDS_TEXT = """
    a an the this that these those it its them they their there here you your yourself player agent
    i me my we our us he she his her itself themselves one's
    and or but then if until while when once before after again also only just still so as than
    to of in on at by for from with without into onto near next beside nearby nearest close closer
    closest around between behind front above below under over top bottom side sides edge
    beneath underneath atop upon within through across along toward towards away off out ahead
    against among about per via
    left right up down north south east west forward back backward straight horizontal vertical
    diagonal upper lower middle center centre corner adjacent opposite
    is are be been being was were have has had do does done did can could will would should must
    may might need needed not no all any each every both some more most less least few many much
    enough another other same new several single multiple additional extra remaining total
    one two three four five six seven eight nine ten eleven twelve first second third fourth fifth
    last final initial current previous original twice thrice times time day night
    go went gone move walk head turn face stand stay step return reach approach navigate travel
    explore find found locate look search spot identify check ensure keep continue repeat wait
    get got take took gather collect obtain acquire harvest mine chop cut dig break hit strike use
    make made craft build create place put set position drop plant
    eat drink sleep rest wake attack fight kill defeat avoid protect survive
    start begin proceed finish complete end stop confirm verify validate select choose pick
    count measure observe inspect examine scan view see watch note remember determine decide
    prepare arrange align fill clear leave hold carry bring follow seek hunt slay encounter
    engage interact perform apply add remove replace adjust ready
    block blocks tile tiles square squares space spaces cell cells spot area location position
    distance direction way path ground surface floor row column line grid pattern shape form
    unit units point spot zone region site
    item items object objects resource resources material materials inventory health food energy
    task goal plan action instruction step steps game map world environment surroundings
    desired required necessary suitable specific specified designated chosen selected existing
    appropriate correct correctly available visible empty full small large big
    piece pieces number size length sequence target source based surrounding consecutive further
    successful accordingly strategically presence existence report work
    consume deposit retrieve destroy construct assemble
    creature creatures enemy monster animal tool weapon
"""
COMMON_WORDS = frozenset(_COMMON_WORDS_TEXT.split())
#: Derivational endings stripped to reach a known word (wooden -> wood, upwards -> up).
_DERIVATIONAL_SUFFIXES = ("wards", "ward", "ment", "ion", "ly", "en", "er")

_STEP_LINE = re.compile(r"^\s*(?:step\s*)?(\d+)\s*[.):]\s*(.*?)\s*$", re.IGNORECASE)
_BULLET_LINE = re.compile(r"^\s*[-*\u2022]\s+(.*?)\s*$")
#: Words of letters; tokens holding digits (2x2, 1st) are counts, never names.
_WORD = re.compile(r"\b[a-z]+(?:'[a-z]+)?\b")


class PlanLimits(BaseModel):
    """How short a plan must be."""

    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)

    max_steps: int = Field(5, ge=1)
    """Most numbered steps a plan may have."""
    max_step_words: int = Field(8, ge=1)
    """Most words one step may have."""


IssueKind = Literal["no_steps", "too_many_steps", "step_too_long", "unknown_words"]


class PlanIssue(BaseModel):
    """One way a plan breaks the rules."""

    model_config = ConfigDict(frozen=True)

    kind: IssueKind
    """What is wrong: no steps, too many steps, a step too long, or words unknown to Craftax."""
    detail: str
    """A human-readable explanation, also shown to the model in the repair request."""


class PlanCheck(BaseModel):
    """A plan parsed into steps and checked against the limits and the Craftax vocabulary."""

    steps: list[str]
    """The step texts, without their numbers."""
    extra_lines: list[str]
    """Lines that are neither steps nor a heading such as "Plan:"; dropped from the kept plan."""
    unknown: list[str]
    """Words that are neither Craftax names nor common words, in order of first use."""
    issues: list[PlanIssue]
    """Every rule the plan breaks; empty for a valid plan."""

    @property
    def ok(self) -> bool:
        return not self.issues

    @property
    def text(self) -> str:
        """The plan as numbered lines, the format of CrafText's plan file."""
        return "\n".join(f"{i}. {step}" for i, step in enumerate(self.steps, 1))


PlanStatus = Literal["valid", "repaired", "failed"]


class PlanRecord(BaseModel):
    """One planned instruction, as kept in the journal."""

    instruction: str
    """The instruction text, exactly as in the dataset (it is the key of the plans file)."""
    plan: str
    """The kept plan as numbered lines; empty when the model gave no steps at all."""
    status: PlanStatus
    """`valid`: first answer passed; `repaired`: the repair passed; `failed`: neither did."""
    issues: list[PlanIssue] = Field(default_factory=list)
    """What is still wrong with the kept plan (empty unless failed)."""
    raw: str
    """The planner's first answer, verbatim."""
    repair_raw: str | None = None
    """The answer to the repair request, verbatim; None when none was made."""


class PlanSettings(BaseModel):
    """Everything that decides what a plan looks like; a journal is resumed only under the same settings."""

    model_config = ConfigDict(frozen=True)

    backend: str
    """The backend's registry name."""
    model: str
    """The planner model's name."""
    generation: dict[str, Any]
    """The sampling parameters (transport settings such as timeouts left out)."""
    templates: dict[str, str]
    """Template file name -> sha256 of its source."""
    limits: PlanLimits
    """The plan limits in force."""
    variant: Variant
    """Whose names the prompt lists and the checker accepts."""
    repair: bool
    """Whether flagged plans got one repair request."""


class PlannerConfig(ModelSettings):
    """What `craftext-llm plan` does."""

    output: Path
    """The plans JSON to write; the journal and sidecar sit beside it."""
    splits: list[str] = Field(
        default_factory=lambda: ["easy_train", "easy_test_paraphrased", "easy_test_other_params"]
    )
    """Dataset splits (easy_train easy_test_paraphrased easy_test_other_params) or eval's
    category names (one and combo plan the train split) whose instructions get plans."""
    limits: PlanLimits = Field(default_factory=PlanLimits)
    """How short plans must be."""
    repair: bool = True
    """Send one repair request for every plan that breaks the rules."""
    drop_failed: bool = False
    """Leave plans that still break the rules after repair out of the plans file."""
    requests_per_call: int = Field(32, ge=1)
    """Conversations sent to the backend in one call."""
    restart: bool = False
    """Discard an existing journal instead of resuming it."""

    @field_validator("splits", mode="before")
    @classmethod
    def _split_names(cls, value: Any) -> list[str]:
        names: list[str] = [value] if isinstance(value, str) else list(value)
        by_category: dict[str, str] = {str(k): str(v) for k, v in CATEGORY_SPLIT.items()}
        return list(dict.fromkeys(check_split(by_category.get(n, n)) for n in names))

    @field_validator("output")
    @classmethod
    def _plans_file(cls, value: Path) -> Path:
        if value.is_dir():
            raise ValueError(f"{value} is a directory; name the plans JSON file to write")
        check_output_dir(value.parent)
        return value


class PlanSummary(BaseModel):
    """The outcome of a planning run, over every instruction it was asked for."""

    output: Path
    """The plans JSON."""
    sidecar: Path
    """The JSON recording model, parameters, template hashes and these counts."""
    journal: Path
    """The append-only JSONL journal the plans file is built from."""
    instructions: int
    """Distinct instructions asked for."""
    resumed: int
    """Of those, already planned by an earlier run and skipped."""
    valid: int
    """Plans that passed on the first answer."""
    repaired: int
    """Plans that passed after the repair request."""
    failed: int
    """Plans that still break the rules (kept in the plans file unless `drop_failed`)."""
    errors: int
    """Instructions the backend failed on in this run; a rerun retries them."""
    in_file: int
    """Plans in the plans file (it may also hold plans of other splits from earlier runs)."""
    prompt_tokens: int = 0
    """Prompt tokens spent in this run."""
    completion_tokens: int = 0
    """Completion tokens spent in this run."""
    wall_s: float = 0.0
    """Seconds this run took."""
    failed_instructions: list[str] = Field(default_factory=list)
    """The instructions whose plans failed, for inspection."""


# ---------------------------------------------------------------- vocabulary


@cache
def _things(variant: Variant) -> tuple[str, ...]:
    """Names of blocks, items, projectiles and creatures of the variant, e.g. `CRAFTING_TABLE`."""
    enums: tuple[tuple[str, ...], ...]
    if variant is Variant.FULL:
        enums = (names.FULL_BLOCKS, names.FULL_ITEMS, names.FULL_PROJECTILES)
    else:
        enums = (names.CLASSIC_BLOCKS,)
    # Creatures are named as their achievements name them (DEFEAT_ZOMBIE, EAT_COW).
    creatures = [
        name.removeprefix(prefix)
        for name in variant.achievement_names
        for prefix in _CREATURE_PREFIXES
        if name.startswith(prefix)
    ]
    things = [name for enum in enums for name in enum if name not in _INTERNAL_NAMES]
    return tuple(dict.fromkeys(things + creatures))


@cache
def craftax_vocabulary(variant: Variant = Variant.FULL) -> frozenset[str]:
    """Lower-case words of every Craftax name of the variant: things, creatures, actions, achievements."""
    every = [*_things(variant), *variant.achievement_names, *variant.action_names]
    return frozenset(word for name in every for word in name.lower().split("_") if word.isalpha())


def _known(word: str, vocabulary: frozenset[str]) -> bool:
    """Whether a word or a plain inflection or derivation of it (stones, placing, wooden) is known."""
    word = word.removesuffix("'s")
    stems = {word}
    if word.endswith(("ies", "ied")):
        stems.add(word[:-3] + "y")
    for suffix in ("es", "s", "ing", "ed", *_DERIVATIONAL_SUFFIXES):
        if word.endswith(suffix) and len(word) > len(suffix) + 1:
            base = word[: -len(suffix)]
            stems |= {base, base + "e", base[:-1]}
    return any(stem in vocabulary or stem in COMMON_WORDS for stem in stems)


def word_tokens(text: str) -> list[str]:
    """The lower-case words of a text that the vocabulary check looks at (no numbers)."""
    return _WORD.findall(text.lower())


def is_known(word: str, variant: Variant = Variant.FULL) -> bool:
    """Whether a lower-case word is a Craftax name of the variant, a common word, or a form of one."""
    return _known(word, craftax_vocabulary(variant))


def unknown_words(text: str, variant: Variant = Variant.FULL) -> list[str]:
    """Words of `text` that are neither Craftax names of the variant nor common words, each once."""
    return list(dict.fromkeys(w for w in word_tokens(text) if not is_known(w, variant)))


# ---------------------------------------------------------------- parsing and checking


def parse_plan(text: str) -> tuple[list[str], list[str]]:
    """Split a plan into step texts and leftover lines.

    Steps are numbered lines ("1. x", "2) x", "Step 3: x"); if there are none, bulleted lines
    count as steps. Headings (a short line ending in a colon, such as "Plan:") are dropped.
    """
    steps: list[str] = []
    bullets: list[str] = []
    extra: list[str] = []
    for line in text.splitlines():
        stripped = line.strip().strip("*_").strip()
        if not stripped:
            continue
        if numbered := _STEP_LINE.match(stripped):
            if numbered.group(2):
                steps.append(numbered.group(2))
        elif bulleted := _BULLET_LINE.match(stripped):
            bullets.append(bulleted.group(1))
        elif not (stripped.endswith(":") and len(stripped.split()) <= 6):
            extra.append(stripped)
    if not steps:
        steps = bullets
    else:
        extra += bullets
    return steps, extra


def check_plan(
    text: str, limits: PlanLimits | None = None, variant: Variant = Variant.FULL
) -> PlanCheck:
    """Parse a plan and list every rule it breaks."""
    limits = limits or PlanLimits()
    steps, extra = parse_plan(text)
    issues: list[PlanIssue] = []
    if not steps:
        issues.append(PlanIssue(kind="no_steps", detail="the answer has no numbered steps"))
    if len(steps) > limits.max_steps:
        issues.append(
            PlanIssue(
                kind="too_many_steps",
                detail=f"{len(steps)} steps; at most {limits.max_steps} are allowed",
            )
        )
    for number, step in enumerate(steps, 1):
        if (words := len(step.split())) > limits.max_step_words:
            issues.append(
                PlanIssue(
                    kind="step_too_long",
                    detail=f"step {number} has {words} words; at most {limits.max_step_words} are allowed",
                )
            )
    unknown = unknown_words("\n".join(steps), variant)
    if unknown:
        issues.append(
            PlanIssue(
                kind="unknown_words",
                detail=f"words that name nothing in Craftax: {', '.join(unknown)}",
            )
        )
    return PlanCheck(steps=steps, extra_lines=extra, unknown=unknown, issues=issues)


# ---------------------------------------------------------------- prompts


def _template_hashes(templates_dir: str | Path | None) -> dict[str, str]:
    return {
        name: hashlib.sha256(template_source(name, templates_dir).encode("utf-8")).hexdigest()
        for name in (PLANNER_TEMPLATE, REPAIR_TEMPLATE)
    }


def _messages(blocks: Sequence[tuple[BlockRole, str]]) -> list[ChatMessage]:
    return [ChatMessage(role=role, content=text) for role, text in blocks]


class _Prompter:
    """Renders plan and repair requests with the limits and the variant's names."""

    def __init__(self, limits: PlanLimits, variant: Variant, templates_dir: str | Path | None):
        self.templates_dir = templates_dir
        self.common = {
            "things": [name.lower().replace("_", " ") for name in _things(variant)],
            "actions": [
                {"name": spec.name.lower().replace("_", " "), "description": spec.description}
                for spec in action_catalogue(variant)
            ],
            "max_steps": limits.max_steps,
            "max_step_words": limits.max_step_words,
        }

    def plan(self, instruction: str) -> list[ChatMessage]:
        context = {"instruction": instruction, **self.common}
        return _messages(render_blocks(PLANNER_TEMPLATE, context, self.templates_dir))

    def repair(self, instruction: str, answer: str, check: PlanCheck) -> list[ChatMessage]:
        context = {
            "instruction": instruction,
            "plan": answer,
            "problems": [issue.detail for issue in check.issues],
            **self.common,
        }
        return _messages(render_blocks(REPAIR_TEMPLATE, context, self.templates_dir))


# ---------------------------------------------------------------- files


def _paths(output: Path) -> tuple[Path, Path]:
    """(journal, sidecar) beside the plans file."""
    return output.with_name(f"{output.stem}.journal.jsonl"), output.with_name(
        f"{output.stem}.meta.json"
    )


class _Journal:
    """The append-only JSONL log: a settings header, then one `PlanRecord` per line."""

    def __init__(self, path: Path, settings: PlanSettings, restart: bool):
        self.path = path
        self.records: dict[str, PlanRecord] = {}
        if restart:
            path.unlink(missing_ok=True)
        lines = complete_lines(path)
        if lines:
            self._resume(lines, settings)
        else:
            make_output_dir(path.parent)
            path.write_bytes(b"")
            append_lines(path, [json.dumps({"settings": settings.model_dump(mode="json")})])

    def _resume(self, lines: list[str], settings: PlanSettings) -> None:
        try:
            previous = PlanSettings.model_validate(json.loads(lines[0])["settings"])
        except (json.JSONDecodeError, KeyError, TypeError, ValidationError) as err:
            raise UserError(
                f"{self.path} is not a planner journal ({err}); move it away or pass --restart"
            ) from err
        if previous != settings:
            changed = [
                name
                for name in PlanSettings.model_fields
                if getattr(previous, name) != getattr(settings, name)
            ]
            raise UserError(
                f"{self.path} was written with different {', '.join(changed)}; mixing them would "
                "make the plans file irreproducible: write to another --output or pass --restart"
            )
        for number, line in enumerate(lines[1:], 2):
            try:
                record = PlanRecord.model_validate_json(line)
            except ValidationError:
                raise UserError(f"{self.path} line {number} is corrupt; pass --restart") from None
            self.records[record.instruction] = record

    def add(self, records: Sequence[PlanRecord]) -> None:
        append_lines(self.path, [record.model_dump_json() for record in records])
        self.records.update((record.instruction, record) for record in records)

    def plans(self, drop_failed: bool) -> dict[str, str]:
        return {
            instruction: record.plan
            for instruction, record in self.records.items()
            if record.plan and not (drop_failed and record.status == "failed")
        }


def load_plans(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a plans file (instruction text -> plan text), such as CrafText's official one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"plans file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f"cannot read plans file {path}: {err}") from err
    except json.JSONDecodeError as err:
        raise UserError(f"plans file {path} is not valid JSON: {err}") from err
    if not isinstance(data, dict):
        raise UserError(
            f"plans file {path} must hold one JSON object mapping instruction text to plan text, "
            f"not a {type(data).__name__}"
        )
    bad = [key for key, value in data.items() if not isinstance(value, str)]
    if bad:
        raise UserError(
            f"plans file {path}: the plan of {bad[0]!r} is not a string "
            f"({len(bad)} such entr{'y' if len(bad) == 1 else 'ies'})"
        )
    if not data:
        raise UserError(f"plans file {path} holds no plans")
    return data


# ---------------------------------------------------------------- planning


def _settings(model: ModelAPI, config: PlannerConfig) -> PlanSettings:
    transport = {"timeout_s", "max_concurrency", "max_retries"}
    return PlanSettings(
        backend=model.backend_name,
        model=model.model_name,
        generation=model.config.model_dump(mode="json", exclude=transport),
        templates=_template_hashes(config.templates_dir),
        limits=config.limits,
        variant=config.variant,
        repair=config.repair,
    )


def _groups(items: Sequence[str], size: int) -> Iterator[Sequence[str]]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


@dataclass
class _Usage:
    prompt_tokens: int = 0
    completion_tokens: int = 0
    errors: int = 0

    def add(self, outputs: Iterable[ModelOutput]) -> None:
        for output in outputs:
            self.prompt_tokens += output.prompt_tokens
            self.completion_tokens += output.completion_tokens


def _plan_group(
    instructions: Sequence[str],
    model: ModelAPI,
    prompter: _Prompter,
    config: PlannerConfig,
    usage: _Usage,
) -> list[PlanRecord]:
    """Plan up to `requests_per_call` instructions: one call for the plans, one for the repairs."""
    outputs = model.generate([prompter.plan(text) for text in instructions])
    usage.add(outputs)
    records: dict[str, PlanRecord] = {}
    flagged: list[tuple[str, str, PlanCheck]] = []
    for instruction, output in zip(instructions, outputs, strict=True):
        if output.finish_reason == "error":
            usage.errors += 1
            continue
        check = check_plan(output.text, config.limits, config.variant)
        records[instruction] = PlanRecord(
            instruction=instruction,
            plan=check.text,
            status="valid" if check.ok else "failed",
            issues=check.issues,
            raw=output.text,
        )
        if not check.ok and config.repair:
            flagged.append((instruction, output.text, check))
    if flagged:
        repairs = model.generate([prompter.repair(*item) for item in flagged])
        usage.add(repairs)
        for (instruction, _, first), output in zip(flagged, repairs, strict=True):
            if output.finish_reason == "error":
                continue
            second = check_plan(output.text, config.limits, config.variant)
            record = records[instruction]
            record.repair_raw = output.text
            if second.ok:
                record.plan, record.status, record.issues = second.text, "repaired", []
            elif second.steps and len(second.issues) <= len(first.issues):
                record.plan, record.issues = second.text, second.issues
    return [records[text] for text in instructions if text in records]


def plan_instructions(
    instructions: Sequence[str],
    model: ModelAPI,
    config: PlannerConfig,
    provenance: dict[str, Any] | None = None,
    *,
    progress: bool = False,
) -> PlanSummary:
    """Plan every instruction not yet in the journal, then rebuild the plans file and sidecar.

    `provenance` (where the instructions came from) is recorded in the sidecar as is.
    """
    started = time.perf_counter()
    wanted = list(dict.fromkeys(instructions))
    settings = _settings(model, config)
    journal_path, sidecar_path = _paths(config.output)
    journal = _Journal(journal_path, settings, config.restart)
    todo = [text for text in wanted if text not in journal.records]
    prompter = _Prompter(config.limits, config.variant, config.templates_dir)
    usage = _Usage()
    try:
        with tqdm(
            total=len(wanted),
            initial=len(wanted) - len(todo),
            desc="planning",
            unit="instr",
            disable=not progress,
        ) as bar:
            for group in _groups(todo, config.requests_per_call):
                journal.add(_plan_group(group, model, prompter, config, usage))
                bar.update(len(group))
    finally:
        # Runs on Ctrl-C too, so the plans file always reflects the journal.
        plans = journal.plans(config.drop_failed)
        atomic_write_json(config.output, plans)
    statuses = [journal.records[t].status for t in wanted if t in journal.records]
    summary = PlanSummary(
        output=config.output,
        sidecar=sidecar_path,
        journal=journal_path,
        instructions=len(wanted),
        resumed=len(wanted) - len(todo),
        valid=statuses.count("valid"),
        repaired=statuses.count("repaired"),
        failed=statuses.count("failed"),
        errors=usage.errors,
        in_file=len(plans),
        prompt_tokens=usage.prompt_tokens,
        completion_tokens=usage.completion_tokens,
        wall_s=round(time.perf_counter() - started, 3),
        failed_instructions=[
            t for t in wanted if t in journal.records and journal.records[t].status == "failed"
        ],
    )
    sidecar = {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "model_info": model.info(),
        "settings": settings.model_dump(mode="json"),
        "instructions_from": provenance or {},
        "summary": summary.model_dump(mode="json", exclude={"failed_instructions"}),
    }
    atomic_write_json(sidecar_path, sidecar)
    return summary


def goal_instructions(goals: Iterable[Goal]) -> list[str]:
    """Every instruction and paraphrase of the goals, each once, in dataset order."""
    return list(dict.fromkeys(text for goal in goals for text in goal.texts))


def planned_instructions(config: PlannerConfig) -> tuple[list[str], dict[str, Any]]:
    """The instructions `config` asks plans for (cut to `limit`), and where they came from."""
    dataset = load_dataset(config.dataset)
    instructions = goal_instructions(
        goal for split in config.splits for goal in dataset.split(split)
    )
    if config.limit is not None:
        instructions = instructions[: config.limit]
    provenance = {"splits": config.splits, "dataset": dataset.source.model_dump(mode="json")}
    return instructions, provenance


def run_planner(config: PlannerConfig, model: ModelAPI, *, progress: bool = False) -> PlanSummary:
    """Plan every instruction and paraphrase of the configured splits (`craftext-llm plan`)."""
    instructions, provenance = planned_instructions(config)
    return plan_instructions(instructions, model, config, provenance, progress=progress)
