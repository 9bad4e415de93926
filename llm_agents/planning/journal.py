"""The planner's journal (every answer appended as it arrives) and the plans file rebuilt
from it atomically."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from env.errors import UserError
from env.variant import Variant
from llm_agents.planning.checks import PlanIssue, PlanLimits, PlanStatus
from llm_agents.run_data.store import (
    append_lines,
    complete_lines,
    make_output_dir,
)


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
    candidates: int | None = None
    """Plans sampled per instruction (`--candidates`); None: one plan each, the official shape."""


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
    sample: int = 0
    """Which of the instruction's samples this is (`--candidates`), from 0."""
    seed: int | None = None
    """The sampling seed it was drawn with (`--candidates`); None: the configured one."""


def journal_paths(output: Path) -> tuple[Path, Path]:
    """(journal, sidecar) beside the plans file."""
    return output.with_name(f"{output.stem}.journal.jsonl"), output.with_name(
        f"{output.stem}.meta.json"
    )


class Journal:
    """The append-only JSONL log: a settings header, then one `PlanRecord` per line."""

    def __init__(self, path: Path, settings: PlanSettings, restart: bool):
        self.path = path
        self.records: dict[str, PlanRecord] = {}
        """Each instruction's first sample."""
        self.samples: dict[tuple[str, int], PlanRecord] = {}
        """Every sample, by instruction and sample index."""
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
            self._keep(record)

    def _keep(self, record: PlanRecord) -> None:
        self.samples[(record.instruction, record.sample)] = record
        if record.sample == 0:
            self.records[record.instruction] = record

    def add(self, records: Sequence[PlanRecord]) -> None:
        append_lines(self.path, [record.model_dump_json() for record in records])
        for record in records:
            self._keep(record)

    def candidates(self, drop_failed: bool) -> tuple[dict[str, list[str]], int]:
        """Instruction -> its distinct plans in sample order, and how many samples repeated
        an earlier one (counted, not kept)."""
        plans: dict[str, list[str]] = {}
        duplicates = 0
        for (instruction, _), record in sorted(self.samples.items()):
            if not record.plan or (drop_failed and record.status == "failed"):
                continue
            kept = plans.setdefault(instruction, [])
            if record.plan in kept:
                duplicates += 1
            else:
                kept.append(record.plan)
        order = dict.fromkeys(instruction for instruction, _ in self.samples)
        return {text: plans[text] for text in order if text in plans}, duplicates

    def plans(self, drop_failed: bool) -> dict[str, str]:
        return {
            instruction: record.plan
            for instruction, record in self.records.items()
            if record.plan and not (drop_failed and record.status == "failed")
        }
