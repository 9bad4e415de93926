"""The one owner of files that a run writes: names, durable appends, atomic rewrites, torn-line
recovery, and the run's identity.

A run directory holds `steps.jsonl` (a line per agent step), `episodes.jsonl` (a line per
finished episode) and `results.json` (what the run is and how far it got). JSON-lines files are
only ever appended to and fsynced, so a kill leaves at worst a torn last line, which readers cut
off; whole files are replaced atomically, so a reader sees the old version or the new one.

The identity of a run is by content: the settings that change results, plus hashes of every
template, the plans file, the dataset, the parsed goals of the splits it reads and the
worked-example list it shows, and the import path and version of an agent from outside this
package. A directory is resumed only under the same identity. The code
that ran is not part of it: a resume under other code is allowed, and each episode records the
code version that played it (`code_version`), so the report can say so.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Collection, Iterable, Iterator, Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import IO, Any, Literal, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    computed_field,
    field_validator,
)

from env.errors import UserError
from env.goals import Dataset, Difficulty, category_split
from llm_agents.backends.endpoints import EndpointStats
from llm_agents.backends.redaction import redact_settings
from llm_agents.run_data.metrics import ActionHistogram, Summary
from llm_agents.run_data.provenance import note_other_code
from llm_agents.run_data.readings import Grounding
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.scores import RunScores

logger = logging.getLogger(__name__)

STEPS_FILE = "steps.jsonl"
EPISODES_FILE = "episodes.jsonl"
RESULTS_FILE = "results.json"

Record = TypeVar("Record", bound=BaseModel)


# ------------------------------------------------------------------------------ file primitives


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of some bytes."""
    return hashlib.sha256(data).hexdigest()


@contextlib.contextmanager
def _replacing(path: Path, mode: Literal["w", "wb"]) -> Iterator[IO[Any]]:
    """A new file that replaces `path`, fsynced, when the block ends without an error, so that a
    reader (or a crash) sees the old file or the new one."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, mode, encoding=None if "b" in mode else "utf-8") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """Replace `path` with `text` so that a reader (or a crash) sees the old file or the new one."""
    with _replacing(path, "w") as file:
        file.write(text)


def atomic_write_json(path: Path, data: Any) -> None:
    """`atomic_write_text` of indented JSON."""
    atomic_write_text(path, json.dumps(data, indent=2, ensure_ascii=False) + "\n")


def append_lines(path: Path, lines: Iterable[str], *, durable: bool = True) -> None:
    """Append lines to a JSON-lines file; with `durable`, on disk (fsynced) before returning,
    together with every earlier append to the file."""
    with path.open("a", encoding="utf-8") as file:
        file.writelines(line + "\n" for line in lines)
        file.flush()
        if durable:
            os.fsync(file.fileno())


def append_records(path: Path, records: Iterable[BaseModel], *, durable: bool = True) -> None:
    """Append pydantic records to a JSON-lines file, one per line (`append_lines`)."""
    append_lines(path, (record.model_dump_json() for record in records), durable=durable)


def complete_lines(path: Path, *, repair: bool = True) -> list[str]:
    """The lines of a JSON-lines file that were written whole.

    An append killed mid-write leaves a last line without its newline: it is dropped (and, with
    `repair`, cut off the file so the next append starts on a fresh line).
    """
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as err:
        raise UserError(f"cannot read {path}: {err.strerror}") from err
    whole = data[: data.rfind(b"\n") + 1]
    if len(whole) < len(data):
        logger.warning("%s: dropping a torn last line (%d bytes)", path, len(data) - len(whole))
        if repair:
            with path.open("r+b") as file:
                file.truncate(len(whole))
    try:
        text = whole.decode("utf-8")
    except UnicodeDecodeError as err:
        raise UserError(f"{path} is not UTF-8 text: {err}") from err
    return [line for line in text.splitlines() if line.strip()]


def read_records(path: Path, model: type[Record], *, repair: bool = True) -> list[Record]:
    """Every record of a JSON-lines file; a line that does not validate is an error (UserError)."""
    records = []
    for number, line in enumerate(complete_lines(path, repair=repair), start=1):
        try:
            records.append(model.model_validate_json(line))
        except ValidationError as err:
            raise UserError(
                f"{path}, line {number}: not a {model.__name__}: {err.errors()[0]['msg']}"
            ) from err
    return records


def rewrite_lines(path: Path, lines: Sequence[str]) -> None:
    """Replace a JSON-lines file atomically."""
    atomic_write_text(path, "".join(line + "\n" for line in lines))


# ------------------------------------------------------------------------------ directories


def check_output_dir(directory: Path) -> None:
    """Refuse, before anything is written, a directory that cannot hold a run.

    A path that is a file, lies under a file, or is not writable is a user mistake. Nothing is
    created here: a missing directory is checked through its nearest existing ancestor.
    """
    existing = directory
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        if existing == directory:
            raise UserError(f"output directory {directory} is a file")
        raise UserError(f"output directory {directory} lies under {existing}, which is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "output directory" if existing == directory else "the parent directory"
        raise UserError(f"{what} {existing} is not writable")
    for name in (STEPS_FILE, EPISODES_FILE, RESULTS_FILE):
        file = directory / name
        if file.exists() and not (file.is_file() and os.access(file, os.R_OK | os.W_OK)):
            raise UserError(f"{file} is not a readable and writable file")


def make_output_dir(directory: Path) -> None:
    """Create the output directory (after `check_output_dir` accepted it)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserError(f"cannot create output directory {directory}: {err.strerror}") from err


# ------------------------------------------------------------------------------ identity


#: Settings renamed since runs were first recorded: old name -> current name. A run recorded
#: under an old name still resumes, reports and replays.
RENAMED_SETTINGS = {"splits": "categories"}


def with_current_names(
    settings: dict[str, Any], renamed: dict[str, str] = RENAMED_SETTINGS
) -> dict[str, Any]:
    """`settings` with every renamed setting under its current name (a current name given as
    well wins)."""
    current = {key: value for key, value in settings.items() if key not in renamed}
    for old, new in renamed.items():
        if old in settings:
            current.setdefault(new, settings[old])
    return current


AgentVersionSource = Literal["distribution", "attribute", "source"]
"""Where an outside agent's version was read: its installed distribution's version, the class's
`version` attribute, or a digest of the source of the module that defines it."""


class AgentIdentity(BaseModel):
    """Which agent from outside this package played a run: what a resumed run must match."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: str
    """The class, as `package.module:Class` (an entry-point name resolved to what it points at)."""
    version: str
    """Its version, read from `version_from`."""
    version_from: AgentVersionSource
    """See `AgentVersionSource`."""
    distribution: str | None = None
    """The installed distribution the version is that of (`version_from` `distribution`)."""

    def described(self) -> str:
        """`path` and its version, as a line names them."""
        if self.version_from == "distribution":
            return f"{self.path} (distribution {self.distribution} {self.version})"
        if self.version_from == "attribute":
            return f"{self.path} (version {self.version})"
        return f"{self.path} (source {self.version[:12]})"


class RunIdentity(BaseModel):
    """What must be equal for two processes to write into one run directory."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    @field_validator("settings", mode="before")
    @classmethod
    def _current_names(cls, value: Any) -> Any:
        return with_current_names(value) if isinstance(value, dict) else value

    settings: dict[str, Any]
    """Every setting that changes results (not batching, caching or the output path)."""
    templates: dict[str, str]
    """Template name -> SHA-256 of the source actually used (packaged or overridden)."""
    plans: str | None = None
    """SHA-256 of the plans file's bytes; None without plans."""
    dataset: str | None = None
    """SHA-256 the dataset source reports for its content."""
    goals: dict[str, str] = Field(default_factory=dict)
    """Split -> digest of its goals as parsed (`Dataset.split_sha256`), for the splits the run
    reads: the same source parsed by other code can give other goals."""
    examples: str | None = None
    """Digest of the worked-example list the run shows (`examples_digest`; the skills agent's
    demonstrations, `demos_digest`); None when it shows none."""
    model_revision: str | None = None
    """The hub commit a hub-id model (`hf:ORG/NAME`, `vllm:ORG/NAME`) resolved to when the run
    started (`backends.model_revision`): a branch moved since is another model. None for every
    other model (named, local, served)."""
    grammar: str | None = None
    """Digest of the grammar the run's answers are held to (the skills agent's catalogue under
    `--choice guided`, `grammar_digest`); None when none holds them."""
    agent: AgentIdentity | None = None
    """The agent's import path and version when it comes from outside this package (`--agent
    package.module:Class` or an entry point's name); None for a built-in agent, whose code is
    this package's (recorded as the code version, never compared)."""

    def differences(
        self,
        other: RunIdentity,
        added: Mapping[str, Any] | None = None,
        recorded_goals: Mapping[str, Any] | None = None,
    ) -> list[str]:
        """Human-readable differences from `other` (the identity on disk), empty when equal.
        A setting `other` predates counts as its value in `added` (its default: how that run
        played before the setting existed), so adding a setting does not strand older runs. A
        template `other` hashed that this run does not render is no difference. A split whose
        goals `other` predates digesting in its identity is compared with `recorded_goals` (the
        digests its results recorded beside it); one digested nowhere is no difference. A run
        that shows worked examples differs from one that recorded no list (which list it
        showed is unknown)."""
        found = []
        predated = added or {}
        for key in sorted(self.settings.keys() | other.settings.keys()):
            # Compared and shown without secrets: a run recorded before its options were
            # redacted holds them in plain text, and is still the same run.
            ours = redact_settings(self.settings.get(key))
            theirs = redact_settings(
                other.settings[key] if key in other.settings else predated.get(key)
            )
            if ours != theirs:
                found.append(f"{key} ({_short(theirs)} before, {_short(ours)} now)")
        # Only the templates this run renders: runs once hashed every packaged template, and
        # an edit to one this agent never renders must not strand them.
        for name in sorted(self.templates):
            if self.templates[name] != other.templates.get(name):
                found.append(f"template {name} (its content changed)")
        if self.plans != other.plans:
            found.append("plans file content")
        if self.dataset != other.dataset:
            found.append("dataset content")
        earlier = {**(recorded_goals or {}), **other.goals}
        changed = [s for s in sorted(self.goals) if earlier.get(s, self.goals[s]) != self.goals[s]]
        if changed:
            found.append(f"parsed goals of {', '.join(changed)} (their digests changed)")
        if self.examples != other.examples:
            # Runs recorded before the list was digested showed one all the same.
            unrecorded = other.examples is None and other.settings.get("grounding_shots")
            before = "not recorded" if unrecorded else _digest(other.examples)
            found.append(f"worked-example list ({before} before, {_digest(self.examples)} now)")
        if self.model_revision != other.model_revision:
            before = other.model_revision or "none recorded"
            found.append(
                f"model revision (commit {before} before, {self.model_revision or 'none'} now)"
            )
        if self.grammar != other.grammar:
            found.append(
                f"answer grammar ({_digest(other.grammar)} before, {_digest(self.grammar)} now)"
            )
        if self.agent != other.agent:
            before = other.agent.described() if other.agent else "built-in"
            now = self.agent.described() if self.agent else "built-in"
            found.append(f"agent ({before} before, {now} now)")
        return found


def _digest(value: str | None) -> str:
    return "none" if value is None else value[:12]


def split_digests(
    dataset: Dataset, categories: Iterable[str], difficulty: Difficulty
) -> dict[str, str]:
    """Split -> digest of its parsed goals (`RunIdentity.goals`), for the splits that
    `categories` of `difficulty` read and the dataset has."""
    digests = dataset.split_sha256()
    splits = sorted({category_split(category, difficulty) for category in categories})  # type: ignore[arg-type]
    return {split: digests[split] for split in splits if split in digests}


def _short(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 40 else text[:37] + "..."


def file_sha256(path: Path, what: str) -> str:
    """SHA-256 of a file the run depends on, as a UserError when it cannot be read."""
    try:
        return sha256_bytes(path.read_bytes())
    except OSError as err:
        raise UserError(f"cannot read {what} {path}: {err.strerror}") from err


# ------------------------------------------------------------------------------ results


RunStatus = Literal["complete", "partial", "failed"]
"""`complete`: every scheduled episode finished. `partial`: the run is going on, or stopped
(interrupted, or some episodes were cut short by backend errors) and a rerun resumes it.
`failed`: the run was stopped by a failure (the backend kept failing); `failure` says why, and
a rerun resumes it once the cause is fixed."""


class BackendErrors(BaseModel):
    """How often the backend failed during the run (each failure is after its own retries)."""

    failed_calls: int = 0
    """Answers the backend could not produce."""
    aborted_episodes: list[str] = Field(default_factory=list)
    """Episodes cut short by a failed answer: not summarised, re-run on resume."""
    last_error: str | None = None
    """The most recent failure's message."""


ResultsKind = Literal["eval", "ground"]
"""What made a run directory: `eval` (episodes played) or `ground` (instructions read as goals)."""


def results_kind(path: Path) -> ResultsKind:
    """The kind of run a `results.json` records (files written before kinds existed: `eval`)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise UserError(f"cannot read run results {path}: {err.strerror}") from err
    except json.JSONDecodeError as err:
        raise UserError(f"{path} is not JSON: {err.msg}") from err
    kind = data.get("kind", "eval") if isinstance(data, dict) else None
    if kind not in ("eval", "ground"):
        raise UserError(f"{path} records a run of unknown kind {kind!r}")
    return kind


class ResultsBase(BaseModel):
    """What every run's `results.json` starts with, `eval` and `ground` alike: what made the run,
    its config, identity, versions and data source."""

    kind: ResultsKind
    """What made the run (each kind's results narrow it to its own)."""
    config: dict[str, Any]
    """The resolved run configuration, every default filled in."""
    identity: RunIdentity
    """What a resumed run must match (settings that change results, content hashes)."""
    versions: dict[str, str] = Field(default_factory=dict)
    """Versions of the packages and backend that produced the run."""
    dataset: dict[str, Any] = Field(default_factory=dict)
    """Where the instruction dataset came from (path or revision, checksum)."""

    def check_resumed_by(
        self, identity: RunIdentity, out: Path, added: Mapping[str, Any], what: str
    ) -> None:
        """Refuse (a `UserError` naming `what` the directory holds) to resume this run, found in
        `out`, as a run of `identity`, unless they are the same run; a setting this run predates
        counts as its value in `added`. Warns when other code recorded it."""
        changed = identity.differences(
            self.identity, added=added, recorded_goals=self.dataset.get("split_sha256")
        )
        if changed:
            raise UserError(
                f"{out} holds {what} with other settings: {'; '.join(changed)}; "
                "use another --output-dir, or delete that directory to start over"
            )
        note_other_code(out, self.versions)


class RunResults(ResultsBase):
    """What an evaluation run was (config, identity, versions, data) and how it went, in
    `results.json`."""

    kind: Literal["eval"] = "eval"
    """What made the run: episodes played."""
    schedule: list[str] = Field(default_factory=list)
    """Ids of the episodes this run's schedule holds (after `limit`), in schedule order."""
    finished: int = 0
    """Of those, finished episodes (the ones the summary counts)."""

    @computed_field  # type: ignore[prop-decorator]
    @property
    def scheduled(self) -> int:
        """How many episodes the schedule holds."""
        return len(self.schedule)

    summary: Summary | None = None
    """Metrics over the scheduled episodes finished so far; None before the first one ends."""
    scores: RunScores | None = None
    """The field's achievement scores (Crafter score, BALROG progression, craftaxlm) of the same
    episodes; None before the first one ends (and in runs recorded before they were kept)."""
    groundings: dict[str, Grounding] = Field(default_factory=dict)
    """Episode id -> the goal the agent read before playing it (`guided`), per finished episode."""
    actions: dict[str, ActionHistogram] = Field(default_factory=dict)
    """Episode id -> the actions it took (from its step records), per finished episode; empty
    when the run keeps no step log (`summary.actions` pools them)."""
    status: RunStatus = "partial"
    """See `RunStatus`."""
    failure: str | None = None
    """Why a `failed` run stopped."""
    backend_errors: BackendErrors = Field(default_factory=BackendErrors)
    """Backend failures seen by the process that wrote this file (since it resumed)."""
    endpoints: list[EndpointStats] = Field(default_factory=list)
    """Per-server counts of an HTTP backend (one entry per URL of the model spec, summed over
    Ray workers), since the run resumed; empty for in-process backends."""
    started_at: datetime
    """When the run started."""
    finished_at: datetime | None = None
    """When the run completed; None until then."""
    played_seconds: float | None = None
    """Wall seconds the run spent playing, summed over its sittings: a resumed run's stops are
    not counted, unlike `finished_at - started_at`. None in runs whose first sitting was
    recorded before it was kept."""
    hardware: dict[str, str] = Field(default_factory=dict)
    """The machine that last played episodes of the run (`provenance.hardware`): CPU, cores,
    memory, GPUs; on Ray, its workers' machines pooled (`provenance.pooled_hardware`); empty
    in runs recorded before it was kept."""
    worker_hardware: list[dict[str, str]] = Field(default_factory=list)
    """On Ray, each worker's machine as it last reported it (`provenance.hardware` on the
    worker), in worker order; empty for a run played in one process."""


_Results = TypeVar("_Results", bound=ResultsBase)


def read_results_as(path: Path, model: type[_Results], what: str) -> _Results:
    """Read a `results.json` as `model`; a `UserError` saying it is not `what` when it is not."""
    try:
        return model.model_validate_json(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise UserError(f"cannot read run results {path}: {err.strerror}") from err
    except ValidationError as err:
        raise UserError(f"{path} is not {what}: {err.errors()[0]['msg']}") from err


def read_results(path: Path) -> RunResults:
    """Read an evaluation run's `results.json`."""
    return read_results_as(path, RunResults, "a results file of this version")


def write_results(path: Path, results: ResultsBase) -> None:
    """Write `results.json` atomically."""
    atomic_write_text(path, results.model_dump_json(indent=2) + "\n")


def read_episodes(path: Path, *, repair: bool = False) -> list[EpisodeRecord]:
    """The finished episodes of `episodes.jsonl`; when an id repeats, the later line wins."""
    by_id: dict[str, EpisodeRecord] = {}
    for record in read_records(path, EpisodeRecord, repair=repair):
        by_id[record.episode_id] = record
    return list(by_id.values())


def read_steps(path: Path, episodes: Collection[str] | None = None) -> Iterator[StepRecord]:
    """The step records of `steps.jsonl` in file order, only those of `episodes` when given.

    The file is read line by line (a long run's steps need not fit in memory) and never
    changed: a torn last line, left by a run killed mid-append, is skipped; any other line that
    is not a step record is an error (UserError).
    """
    try:
        handle = path.open(encoding="utf-8")
    except OSError as err:
        raise UserError(f"cannot read {path}: {err.strerror}") from err
    with handle:
        try:
            for number, line in enumerate(handle, start=1):
                if not line.endswith("\n") or not line.strip():
                    continue
                try:
                    raw = json.loads(line)
                    if episodes is not None and raw.get("episode_id") not in episodes:
                        continue
                    record = StepRecord.model_validate(raw)
                except (json.JSONDecodeError, AttributeError, ValidationError) as err:
                    raise UserError(f"{path}, line {number}: not a step record: {err}") from err
                yield record
        except UnicodeDecodeError as err:
            raise UserError(f"{path} is not UTF-8 text: {err}") from err


def _episode_lines(handle: IO[bytes], path: Path) -> Iterator[tuple[str | None, bytes]]:
    """(episode id, line) for each line of the step log open in `handle`, read one at a time;
    None for a torn last line (no newline: an append killed mid-write)."""
    for number, line in enumerate(handle, start=1):
        if not line.endswith(b"\n"):
            yield None, line
        elif line.strip():
            try:
                yield str(json.loads(line)["episode_id"]), line
            except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as err:
                raise UserError(f"{path}, line {number}: not a step record: {err}") from err


def keep_steps_of(path: Path, episodes: Collection[str]) -> int:
    """Drop from the step log `path` the lines of every episode not in `episodes` and a torn last
    line; returns the lines dropped. The log is read a line at a time, never whole (a Medium
    run's holds gigabytes: reading it whole took more memory than the machine had), each line
    parsed once, and rewritten atomically, only when a line goes: the lines before the first
    that goes are copied as they are."""
    if not path.exists():
        return 0
    try:
        source = path.open("rb")
    except OSError as err:
        raise UserError(f"cannot read {path}: {err.strerror}") from err
    with source:
        lines = _episode_lines(source, path)
        head = 0
        for id_, line in lines:
            if id_ not in episodes:
                break
            head += len(line)
        else:
            return 0
        dropped = 1
        with _replacing(path, "wb") as file, path.open("rb") as copy:
            while head:
                head -= file.write(copy.read(min(head, 1 << 20)))
            for id_, line in lines:
                if id_ in episodes:
                    file.write(line)
                else:
                    dropped += 1
    return dropped
