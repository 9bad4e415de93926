"""Plans for plan-conditioned agents (CrafText PPO-T+): generate, check, repair, save and load.

A planner model rewrites every instruction as at most a few short numbered steps. The result is
one JSON object, instruction text -> plan text ("1. ...\\n2. ..."), the shape of CrafText's
official plan file, plus a sidecar JSON recording how it was made. Every answer is appended to a
JSONL journal as soon as it arrives; the plans file is rebuilt from the journal atomically, so an
interrupted run loses nothing and a rerun skips what is already planned.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, field_validator, model_validator
from tqdm import tqdm

from env.dataset import SPLITS, AnyGoal, check_split, load_dataset
from env.errors import UserError
from env.goals import difficulty_of, split_categories
from env.variant import Variant
from llm_agents.agents.answers.actions import action_catalogue
from llm_agents.backends.base import ChatMessage, ModelAPI, ModelOutput
from llm_agents.evaluation.config import TextSelection
from llm_agents.planning.checks import PlanCheck, PlanLimits, check_plan
from llm_agents.planning.journal import Journal, PlanRecord, PlanSettings, journal_paths
from llm_agents.planning.vocabulary import craftax_things
from llm_agents.run_data.store import (
    atomic_write_json,
    check_output_dir,
)
from prompts import BlockRole, render_blocks, template_digests

PLANNER_TEMPLATE = "planner.j2"
REPAIR_TEMPLATE = "plan_repair.j2"


class PlannerConfig(TextSelection):
    """What `craftext-llm plan` does."""

    output: Path
    """The plans JSON to write; the journal and sidecar sit beside it."""
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
    candidates: int | None = Field(None, ge=1, le=64)
    """Sample this many plans per instruction (sampling seeds `sampling_seed`, +1, ...; a
    temperature above 0) and write a candidates file, instruction -> [distinct plans]; unset:
    one plan each, the official shape."""

    @model_validator(mode="before")
    @classmethod
    def _split_names(cls, data: Any) -> Any:
        """Dataset split names, what `--splits` took before plan chose texts as eval does, as
        their difficulty and categories (`easy_train` is `one` and `combo`)."""
        if not isinstance(data, dict) or "categories" not in data:
            return data
        given = data["categories"]
        names = [given] if isinstance(given, str) else list(given)
        names = [part.strip() for name in names for part in str(name).split(",") if part.strip()]
        splits = [check_split(name) for name in names if name in SPLITS]
        if not splits:
            return data
        difficulties = {difficulty_of(split) for split in splits}
        difficulties |= {data["difficulty"]} if "difficulty" in data else set()
        if len(difficulties) > 1:
            raise UserError(
                f"plan reads one difficulty at a time, not {' and '.join(sorted(difficulties))}: "
                "run it once per difficulty with the same --output (plans accumulate in the file)"
            )
        categories = [
            category
            for name in names
            for category in (split_categories(check_split(name))[1] if name in SPLITS else (name,))
        ]
        return data | {"difficulty": difficulties.pop(), "categories": categories}

    @model_validator(mode="after")
    def _sampled(self) -> PlannerConfig:
        """Candidates are samples: greedy decoding would give one plan per text."""
        if (self.candidates or 0) > 1 and self.generation.temperature == 0:
            raise UserError(
                "--candidates samples plans: greedy decoding (temperature 0) gives one plan per "
                "instruction; set --temperature above 0 (e.g. 0.8)"
            )
        return self

    @field_validator("output")
    @classmethod
    def _plans_file(cls, value: Path) -> Path:
        if value.is_dir():
            raise ValueError(f"{value} is a directory; name the plans JSON file to write")
        check_output_dir(value.parent)
        return value


class PlanSummary(BaseModel):
    """The outcome of a planning run, over every instruction it was asked for."""

    duplicates: int = 0
    """`--candidates`: samples that repeated an earlier plan of their instruction (not kept)."""

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
    computed_prompt_tokens: int | None = None
    """Of those, the tokens the backend computed, the rest reused from its prefix cache; None
    where the backend did not say for some answer."""
    completion_tokens: int = 0
    """Completion tokens spent in this run."""
    wall_s: float = 0.0
    """Seconds this run took."""
    failed_instructions: list[str] = Field(default_factory=list)
    """The instructions whose plans failed, for inspection."""


# ---------------------------------------------------------------- prompts


def _messages(blocks: Sequence[tuple[BlockRole, str]]) -> list[ChatMessage]:
    return [ChatMessage(role=role, content=text) for role, text in blocks]


class _Prompter:
    """Renders plan and repair requests with the limits and the variant's names."""

    def __init__(self, limits: PlanLimits, variant: Variant, templates_dir: str | Path | None):
        self.templates_dir = templates_dir
        self.common = {
            "things": [name.lower().replace("_", " ") for name in craftax_things(variant)],
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


def planner_messages(
    instruction: str,
    limits: PlanLimits | None = None,
    variant: Variant = Variant.FULL,
    templates_dir: str | Path | None = None,
) -> list[ChatMessage]:
    """The request `plan` sends the planner model for one instruction."""
    return _Prompter(limits or PlanLimits(), variant, templates_dir).plan(instruction)


# ---------------------------------------------------------------- planning


def _settings(model: ModelAPI, config: PlannerConfig) -> PlanSettings:
    transport = {"timeout_s", "max_concurrency", "max_retries"}
    return PlanSettings(
        backend=model.backend_name,
        model=model.model_name,
        generation=model.config.model_dump(mode="json", exclude=transport),
        templates=template_digests((PLANNER_TEMPLATE, REPAIR_TEMPLATE), config.templates_dir),
        limits=config.limits,
        variant=config.variant,
        repair=config.repair,
        candidates=config.candidates,
    )


def _groups(items: Sequence[str], size: int) -> Iterator[Sequence[str]]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


@dataclass
class _Usage:
    prompt_tokens: int = 0
    # None once any answer's backend does not say, so a partial count never reads as a share.
    computed_prompt_tokens: int | None = 0
    completion_tokens: int = 0
    errors: int = 0

    def add(self, outputs: Iterable[ModelOutput]) -> None:
        for output in outputs:
            self.prompt_tokens += output.prompt_tokens
            self.completion_tokens += output.completion_tokens
            if (
                self.computed_prompt_tokens is not None
                and output.computed_prompt_tokens is not None
            ):
                self.computed_prompt_tokens += output.computed_prompt_tokens
            else:
                self.computed_prompt_tokens = None


def _plan_group(
    instructions: Sequence[str],
    model: ModelAPI,
    prompter: _Prompter,
    config: PlannerConfig,
    usage: _Usage,
    sample: int = 0,
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
            sample=sample,
            seed=model.config.sampling_seed if config.candidates else None,
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
    journal_path, sidecar_path = journal_paths(config.output)
    check_sampling(model, config)
    journal = Journal(journal_path, settings, config.restart)
    samples = config.candidates or 1
    todo = [
        (sample, text)
        for sample in range(samples)
        for text in wanted
        if (text, sample) not in journal.samples
    ]
    prompter = _Prompter(config.limits, config.variant, config.templates_dir)
    usage = _Usage()
    duplicates = 0
    try:
        with tqdm(
            total=len(wanted) * samples,
            initial=len(wanted) * samples - len(todo),
            desc="planning",
            unit="plan",
            disable=not progress,
        ) as bar:
            for sample in range(samples):
                texts = [text for s, text in todo if s == sample]
                with _sampling_seed(model, config, sample):
                    for group in _groups(texts, config.requests_per_call):
                        journal.add(_plan_group(group, model, prompter, config, usage, sample))
                        bar.update(len(group))
    finally:
        # Runs on Ctrl-C too, so the plans file always reflects the journal.
        plans: dict[str, Any]
        if config.candidates:
            plans, duplicates = journal.candidates(config.drop_failed)
        else:
            plans = journal.plans(config.drop_failed)
        atomic_write_json(config.output, plans)
    statuses = [
        journal.samples[(t, sample)].status
        for sample in range(samples)
        for t in wanted
        if (t, sample) in journal.samples
    ]
    summary = PlanSummary(
        output=config.output,
        sidecar=sidecar_path,
        journal=journal_path,
        instructions=len(wanted),
        resumed=len(wanted) * samples - len(todo),
        valid=statuses.count("valid"),
        repaired=statuses.count("repaired"),
        failed=statuses.count("failed"),
        errors=usage.errors,
        in_file=len(plans),
        duplicates=duplicates,
        prompt_tokens=usage.prompt_tokens,
        computed_prompt_tokens=usage.computed_prompt_tokens if usage.prompt_tokens else None,
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
        # Where the templates whose digests `settings` holds were read, so that plan-score's
        # exports ask the plans' own prompt (the digests are compared there).
        "templates_dir": str(Path(config.templates_dir).resolve())
        if config.templates_dir
        else None,
        "instructions_from": provenance or {},
        "summary": summary.model_dump(mode="json", exclude={"failed_instructions"}),
    }
    atomic_write_json(sidecar_path, sidecar)
    return summary


def check_sampling(model: ModelAPI, config: PlannerConfig) -> None:
    """Refuse `--candidates` where the answers could not differ (before anything is written)."""
    if config.candidates is None:
        return
    reason = model.cannot_sample()
    if reason is not None:
        raise UserError(f"--candidates samples plans, and {reason}")


@contextmanager
def _sampling_seed(model: ModelAPI, config: PlannerConfig, sample: int) -> Iterator[None]:
    """Sample `sample` drawn with the configured seed plus `sample` (in place: a caching
    wrapper shares its model's settings object)."""
    base = model.config.sampling_seed
    if config.candidates is None or base is None:
        yield
        return
    model.config.sampling_seed = base + sample
    try:
        yield
    finally:
        model.config.sampling_seed = base


def goal_instructions(goals: Iterable[AnyGoal]) -> list[str]:
    """Every instruction and paraphrase of the goals, each once, in dataset order."""
    return list(dict.fromkeys(text for goal in goals for text in goal.texts))


def planned_instructions(config: PlannerConfig) -> tuple[list[str], dict[str, Any]]:
    """The instructions `config` asks plans for (cut to `limit`), and where they came from."""
    dataset = load_dataset(config.dataset)
    instructions = goal_instructions(dataset.select_goals(config.categories, config.difficulty))
    if config.limit is not None:
        instructions = instructions[: config.limit]
    provenance = {
        "difficulty": config.difficulty,
        "categories": list(config.categories),
        "dataset": dataset.source.model_dump(mode="json"),
    }
    return instructions, provenance


def run_planner(config: PlannerConfig, model: ModelAPI, *, progress: bool = False) -> PlanSummary:
    """Plan every instruction and paraphrase of the configured categories (`craftext-llm plan`)."""
    instructions, provenance = planned_instructions(config)
    return plan_instructions(instructions, model, config, provenance, progress=progress)
