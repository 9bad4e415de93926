"""Typed records of an evaluation run, and how they live on disk.

A run directory holds `steps.jsonl` (one `StepRecord` per agent step), `episodes.jsonl` (one
`EpisodeRecord` per finished episode, appended as episodes end so a crash keeps what finished)
and `results.json` (one `RunResults`, rewritten as the run progresses and at its end).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from datetime import datetime
from pathlib import Path
from typing import Any, Literal, get_args

from pydantic import BaseModel, Field, ValidationError, computed_field, model_validator

from env.errors import UserError
from llm_agents.metrics import Summary

__all__ = [
    "CATEGORIES",
    "TERMINATIONS",
    "Category",
    "EpisodeRecord",
    "RunResults",
    "StepRecord",
    "Termination",
    "append_records",
    "read_episodes",
    "read_results",
    "write_results",
]

logger = logging.getLogger(__name__)

Category = Literal["one", "combo", "new_objects", "paraphrased"]
"""CrafText goal sets: single achievements, combinations, unseen objects, paraphrased instructions."""
CATEGORIES: tuple[Category, ...] = get_args(Category)

Termination = Literal["success", "death", "timeout"]
"""Why an episode ended; `success` wins when the goal is met on the step the agent dies."""
TERMINATIONS: tuple[Termination, ...] = get_args(Termination)


class StepRecord(BaseModel):
    """One agent step of one episode: what the model saw, said and did, and what followed."""

    episode_id: str
    """The episode this step belongs to (matches `EpisodeRecord.episode_id`)."""
    step: int = Field(ge=0)
    """Index of the step within its episode, from 0."""
    observation: str
    """The observation text the agent was shown."""
    prompt_hash: str
    """Hash of the full prompt, to spot identical prompts without storing each one."""
    raw_output: str
    """The model's answer text exactly as returned (reasoning removed)."""
    reasoning: str | None = None
    """The model's reasoning text, when the backend returns one."""
    action_name: str
    """Name of the action taken, as in the variant's craftax `Action` enum (`MAKE_WOOD_PICKAXE`)."""
    action_id: int = Field(ge=0)
    """Id of the action taken in the variant's craftax `Action` enum."""
    parse_stage: str
    """Which parser stage produced the action (the parser names its stages)."""
    fallback_used: bool
    """True when no action could be parsed and the fallback action was taken instead."""
    reward: float
    """Environment reward for this step."""
    done: bool
    """True when the episode ended on this step."""
    new_achievements: list[str] = Field(default_factory=list)
    """Achievement names first unlocked on this step."""
    prompt_tokens: int = Field(0, ge=0)
    """Tokens in the prompt."""
    completion_tokens: int = Field(0, ge=0)
    """Tokens generated, reasoning included."""
    latency_s: float = Field(0.0, ge=0.0)
    """Wall time of the model call (for a batched call: the batch's time)."""


class EpisodeRecord(BaseModel):
    """The outcome of one episode: which goal, under which seed, and how it ended."""

    episode_id: str
    """Unique id of the episode within the run."""
    goal_id: str
    """Id of the CrafText goal the instruction states."""
    instruction: str
    """The instruction text the agent was given."""
    instruction_variant: int = Field(ge=0, le=5)
    """Which wording of the goal: 0 the original, 1-5 a paraphrase."""
    category: Category
    """The goal set the episode counts towards."""
    seed: int
    """Environment seed of the episode."""
    episode_index: int = Field(ge=0)
    """Position of the episode in the run's schedule, from 0."""
    success: bool
    """True when the goal was met."""
    steps: int = Field(ge=0)
    """Agent steps taken."""
    termination: Termination
    """Why the episode ended."""
    episode_return: float
    """Sum of environment rewards."""
    invalid_actions: int = Field(0, ge=0)
    """Steps on which no action could be parsed and the fallback action was taken."""
    prompt_tokens: int = Field(0, ge=0)
    """Prompt tokens over all steps."""
    completion_tokens: int = Field(0, ge=0)
    """Generated tokens over all steps, reasoning included."""
    achievements: list[str] = Field(default_factory=list)
    """Achievement names unlocked during the episode, in order."""
    plan_given: bool = False
    """True when the agent was given a plan for the goal."""
    reset_key: list[int] | None = Field(None, min_length=2, max_length=2)
    """The raw PRNG key (two uint32 words) the episode's world was reset with; None in records
    written before it was stored (replays then derive it the way the runner did)."""

    # A computed field is written to JSON but ignored on reading, so the rate can never
    # disagree with the count it comes from.
    @computed_field  # type: ignore[prop-decorator]
    @property
    def invalid_action_rate(self) -> float:
        """Share of steps whose action was the fallback (0 for an episode without steps)."""
        return self.invalid_actions / self.steps if self.steps else 0.0

    @model_validator(mode="after")
    def _consistent(self) -> EpisodeRecord:
        if self.success != (self.termination == "success"):
            raise ValueError(f"success={self.success} contradicts termination={self.termination!r}")
        if self.invalid_actions > self.steps:
            raise ValueError(f"invalid_actions={self.invalid_actions} exceeds steps={self.steps}")
        return self


class RunResults(BaseModel):
    """What a run was (config, versions, data) and how it went (summary), in `results.json`."""

    config: dict[str, Any]
    """The resolved run configuration, every default filled in."""
    versions: dict[str, str] = Field(default_factory=dict)
    """Versions of the packages and backend that produced the run."""
    dataset: dict[str, Any] = Field(default_factory=dict)
    """Where the instruction dataset came from (path or revision, checksum)."""
    summary: Summary | None = None
    """Metrics over the episodes finished so far; None before the first episode ends."""
    started_at: datetime
    """When the run started."""
    finished_at: datetime | None = None
    """When the run ended; None while it runs or after a crash."""
    complete: bool = False
    """True only when every scheduled episode finished."""


def append_records(path: Path, records: Iterable[BaseModel]) -> None:
    """Append records to a JSON-lines file, one per line, flushed to disk before returning."""
    with path.open("a", encoding="utf-8") as handle:
        for record in records:
            handle.write(record.model_dump_json() + "\n")
        handle.flush()
        os.fsync(handle.fileno())


def read_episodes(path: Path) -> list[EpisodeRecord]:
    """Read `episodes.jsonl`, tolerating the torn last line a crash leaves behind.

    A bad last line is skipped with a warning; a bad line anywhere else means the file is
    corrupt and raises `UserError`. When an episode id repeats (a resumed run redid it),
    the later record wins.
    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise UserError(f"cannot read episode records {path}: {exc.strerror}") from exc
    while lines and not lines[-1].strip():
        lines.pop()
    by_id: dict[str, EpisodeRecord] = {}
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = EpisodeRecord.model_validate_json(line)
        except ValidationError as exc:
            if number == len(lines):
                logger.warning("%s: skipping unreadable last line %d (torn write?)", path, number)
                continue
            raise UserError(f"{path}, line {number}: not an episode record: {exc}") from exc
        if record.episode_id in by_id:
            logger.warning(
                "%s: episode %r recorded twice; keeping line %d", path, record.episode_id, number
            )
        by_id[record.episode_id] = record
    return list(by_id.values())


def read_results(path: Path) -> RunResults:
    """Read `results.json`."""
    try:
        return RunResults.model_validate_json(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"cannot read run results {path}: {exc.strerror}") from exc
    except ValidationError as exc:
        raise UserError(f"{path} is not a valid results file: {exc}") from exc


def write_results(path: Path, results: RunResults) -> None:
    """Write `results.json` atomically, so a crash mid-write leaves the previous version."""
    partial = path.with_name(path.name + ".tmp")
    partial.write_text(results.model_dump_json(indent=2) + "\n", encoding="utf-8")
    os.replace(partial, path)
