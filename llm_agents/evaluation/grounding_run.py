"""`craftext-llm ground`: every instruction text of the chosen splits read by the model as a
typed goal, and scored against the dataset's.

`--difficulty` picks the goals as eval's does (EASY's categories, or Medium's and Hard's splits
`train`, `paraphrased`, `new_objects`); the prompt then offers that difficulty's goal kinds, and
the run records the difficulty in its identity.

A grounding run lives in a run directory as an evaluation does, through the same store:
`groundings.jsonl` (a line per instruction text, appended and fsynced as answers arrive) and
`results.json` (kind `ground`: the resolved config, the run's identity, versions, dataset source,
status and the `GroundingSummary`). A directory is resumed only by the same run (same identity:
the settings that change answers, the template's hash, the dataset's, its parsed goals' and the
worked-example list's); a rerun asks only for the texts not yet answered, and each answer records
the code version that read it. A backend failure is never an answer: the text stays unanswered
and a rerun asks again; `--max-consecutive-failures` failures in a row stop the run (status
`failed`, exit 3), keeping every answer.
"""

from __future__ import annotations

import importlib.metadata
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, model_validator

from env.dataset import Instruction, load_dataset
from env.errors import UserError
from env.goals import DIFFICULTY_KINDS, run_category
from env.scenario_tasks import encode_goals
from llm_agents.agents.answer_schemas import reading_schema
from llm_agents.agents.grounding import (
    GROUND_TEMPLATE,
    GroundingExample,
    examples_digest,
    grounding_messages,
    parse_grounding,
    reading_options,
    training_examples,
)
from llm_agents.backends.base import (
    CHANGES_RESULTS,
    ChatMessage,
    ChoiceSet,
    ModelAPI,
)
from llm_agents.evaluation.config import (
    ChoiceSettings,
    FailureSettings,
    GroundingSettings,
    TextSelection,
)
from llm_agents.evaluation.runner import BackendFailure, check_commit, hub_commit
from llm_agents.run_data.grounding_metrics import GroundingSummary, Scored, summarize_groundings
from llm_agents.run_data.provenance import code_version
from llm_agents.run_data.readings import GoalReading, Grounding, reading_of
from llm_agents.run_data.store import (
    RESULTS_FILE,
    ResultsBase,
    RunIdentity,
    RunStatus,
    append_records,
    check_output_dir,
    make_output_dir,
    read_records,
    read_results_as,
    results_kind,
    rewrite_lines,
    split_digests,
    write_results,
)
from prompts import template_digests

GROUNDINGS_FILE = "groundings.jsonl"


class GroundConfig(TextSelection, ChoiceSettings, GroundingSettings, FailureSettings):
    """What `craftext-llm ground` does (its `--difficulty` also picks the goal kinds the prompt
    offers; `--choice` picks among the chosen categories' distinct goals)."""

    paraphrases: Annotated[bool, CHANGES_RESULTS] = True
    """Ground every paraphrase of each goal as well as its original instruction."""
    output_dir: str = "runs/ground"
    """Where groundings and results are written; rerunning on it resumes the run."""
    requests_per_call: int = Field(16, ge=1)
    """Conversations sent to the backend in one call (a server gets them concurrently)."""

    @model_validator(mode="after")
    def _no_letters(self) -> GroundConfig:
        if self.choice == "loglik" and self.choice_scoring == "letters":
            raise ValueError(
                "choice_scoring letters letters an eval step's actions; ground's options are "
                "goals, never lettered (use sum, mean, bytes or pmi)"
            )
        return self


class GroundingRecord(BaseModel):
    """One instruction text, the goal its dataset record states and the goal the model read."""

    key: str
    """`split/goal_id/variant`, unique in the run."""
    goal_id: str
    """The goal's id in its split."""
    split: str
    """The dataset split."""
    category: str
    """The goal's category."""
    scenario_class: str = "Achievements"
    """The paper's Table 2 row of the goal (Achievements, Conditional, Localization, Build)."""
    instruction_variant: int = Field(ge=0)
    """0 for the original instruction, 1..n for a paraphrase."""
    instruction: str
    """The text the model read."""
    truth: GoalReading
    """The goal as the dataset states it."""
    grounding: Grounding
    """What the model's answer was read as."""
    correct: bool
    """The reading is exactly the goal."""
    prompt_tokens: int = Field(0, ge=0)
    """Tokens in the prompt."""
    computed_prompt_tokens: int | None = Field(None, ge=0)
    """Prompt tokens the backend computed, the rest reused from its prefix cache; None where
    the backend does not say."""
    completion_tokens: int = Field(0, ge=0)
    """Tokens generated."""
    latency_s: float = Field(0.0, ge=0.0)
    """Wall time of the call that carried the request."""
    cached: bool = False
    """True when the answer came from the response cache."""
    code: str | None = None
    """The version of the code that read the answer (`code_version`); None in records written
    before it was stored."""


class GroundResults(ResultsBase):
    """What a grounding run was and how it went, in `results.json`."""

    kind: Literal["ground"] = "ground"
    """What made the run: instructions read as goals."""
    scheduled: int = 0
    """Instruction texts the run asks about (after `limit`)."""
    finished: int = 0
    """Of those, answered."""
    failed_calls: int = 0
    """Answers the backend could not produce in the process that wrote this file."""
    last_error: str | None = None
    """The most recent backend failure's message."""
    status: RunStatus = "partial"
    """`complete` when every scheduled text is answered; `failed` when the backend failed too
    often in a row; else `partial` (a rerun resumes either)."""
    failure: str | None = None
    """Why a `failed` run stopped."""
    summary: GroundingSummary | None = None
    """Scores over the answered texts; None before the first answer."""
    seconds_per_instruction: float | None = None
    """Wall time per text answered in the process that wrote this file."""
    started_at: datetime
    """When the run started."""
    finished_at: datetime | None = None
    """When the run completed; None until then."""


@dataclass
class PreparedGrounding:
    """A grounding run checked and ready: nothing has been written yet."""

    config: GroundConfig
    output_dir: Path
    instructions: list[Instruction]
    choices: ChoiceSet | None
    identity: RunIdentity
    dataset_source: dict[str, Any]
    previous: GroundResults | None
    examples: tuple[GroundingExample, ...] = ()
    """The difficulty's worked examples, when the config shows any."""

    def messages(self, instruction: Instruction) -> list[ChatMessage]:
        """The grounding request for `instruction`, after its worked examples (never one
        answered with its own goal)."""
        config = self.config
        return grounding_messages(
            instruction.text,
            config.variant,
            config.templates_dir,
            config.difficulty,
            self.examples,
            config.grounding_shots,
            answer=reading_of(instruction.goal),
        )


ProgressFactory = Callable[[int, int], Any]


def prepare_grounding(config: GroundConfig) -> PreparedGrounding:
    """Check everything that needs no model; write nothing. A chosen category the dataset has
    no goals in, a goal the variant has no names for, a template that does not render, an
    unusable directory or one holding another run: a `UserError`."""
    out = Path(config.output_dir)
    check_output_dir(out)
    dataset = load_dataset(config.dataset)
    difficulty = config.difficulty
    empty = [
        category
        for category in config.categories
        if not dataset.select_goals([category], difficulty)
    ]
    if empty:
        raise UserError(
            f"the dataset ({dataset.source.path}) has no {difficulty} goals in "
            f"{', '.join(empty)}; choose other --categories, or pass the official data with "
            "--dataset"
        )
    goals = dataset.select_goals(config.categories, difficulty)
    unoffered = [goal for goal in goals if goal.kind not in DIFFICULTY_KINDS[difficulty]]
    if unoffered:
        raise UserError(
            f"goal {unoffered[0].id!r} ({unoffered[0].split}) is a {unoffered[0].kind} goal, "
            f"which {difficulty} grounding does not offer: {', '.join(DIFFICULTY_KINDS[difficulty])}"
        )
    # A goal naming a block the variant lacks could never be read right: refused as eval does.
    encode_goals(goals, config.variant)
    instructions = dataset.instructions(
        config.categories, include_paraphrases=config.paraphrases, difficulty=difficulty
    )
    truths = [reading_of(goal) for goal in goals]
    if config.limit is not None:
        instructions = instructions[: config.limit]
    examples = training_examples(dataset, difficulty) if config.grounding_shots else ()
    identity = RunIdentity(
        settings=config.result_settings(),
        templates=template_digests([GROUND_TEMPLATE], config.templates_dir),
        dataset=dataset.source.sha256,
        goals=split_digests(dataset, config.categories, difficulty),
        examples=examples_digest(examples) if examples else None,
        model_revision=hub_commit(config),
    )
    prepared = PreparedGrounding(
        config=config,
        output_dir=out,
        instructions=instructions,
        # The options are every goal of the chosen categories, so a text can be misread as
        # any goal of the run, never only as its own.
        choices=ChoiceSet(
            options=reading_options(truths, difficulty),
            rule=config.choice,
            scoring=config.choice_scoring,
        )
        if config.choice
        else None,
        identity=identity,
        dataset_source=dataset.source.model_dump(mode="json")
        | {"split_sha256": dataset.split_sha256()},
        previous=_previous(out, identity),
        examples=examples,
    )
    prepared.messages(instructions[0])
    return prepared


def _previous(out: Path, identity: RunIdentity) -> GroundResults | None:
    path = out / RESULTS_FILE
    if not path.exists():
        if (out / GROUNDINGS_FILE).exists():
            raise UserError(
                f"{out} holds {GROUNDINGS_FILE} but no {RESULTS_FILE}, so it cannot be told "
                "whether it belongs to this run; use another --output-dir or remove it"
            )
        return None
    if results_kind(path) != "ground":
        raise UserError(
            f"{out} holds an evaluation run, not a grounding run; use another --output-dir"
        )
    previous = read_ground_results(path)
    previous.check_resumed_by(
        identity, out, GroundConfig.predated(previous.identity.settings), "a grounding run"
    )
    return previous


def read_ground_results(path: Path) -> GroundResults:
    """Read a grounding run's `results.json`."""
    return read_results_as(path, GroundResults, "a grounding results file")


def read_groundings(out: Path) -> list[GroundingRecord]:
    """The answered texts of a run directory; when a key repeats, the later line wins."""
    by_key = {r.key: r for r in read_records(out / GROUNDINGS_FILE, GroundingRecord)}
    return list(by_key.values())


def _record(instruction: Instruction, grounding: Grounding, output: Any) -> GroundingRecord:
    truth = reading_of(instruction.goal)
    return GroundingRecord(
        key=instruction.key,
        goal_id=instruction.goal.id,
        split=instruction.goal.split,
        category=run_category(instruction.goal),
        scenario_class=instruction.goal.scenario_class,
        instruction_variant=instruction.variant,
        instruction=instruction.text,
        truth=truth,
        grounding=grounding,
        correct=grounding.matches(truth),
        prompt_tokens=output.prompt_tokens,
        computed_prompt_tokens=output.computed_prompt_tokens,
        completion_tokens=output.completion_tokens,
        latency_s=output.latency_s,
        cached=output.cached,
        code=code_version(),
    )


def summarize_records(records: Sequence[GroundingRecord]) -> GroundingSummary | None:
    """The scores of answered texts."""
    return summarize_groundings(
        [
            Scored(r.split, r.category, r.truth, r.grounding, r.scenario_class, r.goal_id)
            for r in records
        ]
    )


def _versions(model: ModelAPI) -> dict[str, str]:
    try:
        found = {"craftext-llm": importlib.metadata.version("craftext-llm")}
    except importlib.metadata.PackageNotFoundError:
        found = {"craftext-llm": "not installed"}
    found["code"] = code_version()
    return found | {f"model.{key}": value for key, value in model.info().items()}


def execute_grounding(
    prepared: PreparedGrounding, model: ModelAPI, *, progress: ProgressFactory | None = None
) -> GroundResults:
    """Ask for every text not yet answered, writing as answers arrive; return the results.
    Raises `BackendFailure` (after saving, status `failed`) when the backend failed
    `max_consecutive_failures` times in a row."""
    config, out = prepared.config, prepared.output_dir
    difficulty = config.difficulty
    check_commit(prepared.identity, model.info())
    make_output_dir(out)
    path = out / GROUNDINGS_FILE
    wanted = {i.key for i in prepared.instructions}
    kept = [r for r in read_groundings(out) if r.key in wanted] if path.exists() else []
    if path.exists():
        # Rewritten without torn lines or duplicates, so appends extend a clean file.
        rewrite_lines(path, [r.model_dump_json() for r in read_groundings(out)])
    done = {r.key for r in kept}
    pending = [i for i in prepared.instructions if i.key not in done]
    results = GroundResults(
        config=config.model_dump(mode="json"),
        identity=prepared.identity,
        versions=_versions(model),
        dataset=prepared.dataset_source,
        scheduled=len(prepared.instructions),
        started_at=prepared.previous.started_at if prepared.previous else datetime.now(UTC),
    )

    def save(records: list[GroundingRecord], elapsed: float, answered: int) -> None:
        results.finished = len(records)
        results.summary = summarize_records(records)
        if results.failure is not None:
            results.status = "failed"
        else:
            results.status = "complete" if results.finished == results.scheduled else "partial"
        results.finished_at = datetime.now(UTC) if results.status == "complete" else None
        results.seconds_per_instruction = round(elapsed / answered, 4) if answered else None
        write_results(out / RESULTS_FILE, results)

    save(kept, 0.0, 0)
    bar = progress(len(prepared.instructions), len(kept)) if progress else None
    started, answered, in_a_row = time.perf_counter(), 0, 0
    try:
        for start in range(0, len(pending), config.requests_per_call):
            group = pending[start : start + config.requests_per_call]
            outputs = model.generate(
                [prepared.messages(i) for i in group],
                choices=prepared.choices,
                schema=reading_schema(config.variant, difficulty)
                if config.structured_output
                else None,
            )
            fresh = []
            for instruction, output in zip(group, outputs, strict=True):
                if output.finish_reason == "error":
                    results.failed_calls += 1
                    results.last_error = output.error or "unknown backend error"
                    in_a_row += 1
                    if in_a_row >= config.max_consecutive_failures and results.failure is None:
                        results.failure = results.last_error
                    continue
                in_a_row = 0
                grounding = parse_grounding(output.text, config.variant, difficulty)
                fresh.append(_record(instruction, grounding, output))
            append_records(path, fresh)
            kept.extend(fresh)
            answered += len(fresh)
            save(kept, time.perf_counter() - started, answered)
            if bar is not None:
                bar.update(len(fresh))
            if results.failure is not None:
                raise BackendFailure(
                    f"stopped after {config.max_consecutive_failures} failed model answers in "
                    f"a row (last: {results.failure}); the answers so far are kept in {out}: "
                    "fix the cause and rerun the same command to resume"
                )
    finally:
        if bar is not None:
            bar.close()
    return results


__all__ = [
    "GROUNDINGS_FILE",
    "GroundConfig",
    "GroundResults",
    "GroundingRecord",
    "PreparedGrounding",
    "execute_grounding",
    "prepare_grounding",
    "read_ground_results",
    "read_groundings",
    "summarize_records",
]
