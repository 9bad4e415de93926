"""Results cards: a finished run's portable result (`card.json`, `card.md`) that anyone holding
the run's records can check.

A card is written only for a complete run played under a named protocol. It holds what the run
was (model and its resolved revision or pinned digest, agent, protocol and the settings that
departed from it, digests of the settings and the dataset, the code version, the hardware) and
its figures (success per goal set and overall with the intervals clustered by goal,
terminations, the Crafter / progression / craftaxlm scores, model calls, tokens and time per
episode, and, when asked for, the goals doing nothing meets or no agent can). Before a card is
written the run's records are checked by replay (`replay_check`): its episodes derived from its
protocol, dataset and seed, each re-simulated from the protocol's world and its actions, its
answers parsed again; a run that does not replay gets no card. The figures are then computed
from the replay's own outcomes over the protocol's episodes, never from the records it checked
(only what no replay can give, tokens and model calls, is read from them), and the card
records the replay and the settings it could not show. `verify_card` replays the run again,
recomputes each figure and names those that differ.

A card carries a digest of its own content: one edited by hand no longer matches it and is
refused on reading (`read_card`), as is a card of another schema version.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from env.errors import UserError
from env.goals import DIFFICULTY_CATEGORIES, Difficulty
from env.rules import SuccessRule
from llm_agents.evaluation.protocol import PROTOCOL_NAMES, ProtocolName, protocol_for
from llm_agents.evaluation.run_view import RunView, read_run
from llm_agents.judging.goal_flags import run_goal_status
from llm_agents.judging.published import paper_differences
from llm_agents.judging.replay_check import ReplayCheck, RunDoesNotReplay, check_run
from llm_agents.judging.rescoring import rescore, run_scores
from llm_agents.run_data.markup import markdown_code, markdown_text
from llm_agents.run_data.metrics import SuccessRate, summarize
from llm_agents.run_data.provenance import code_version
from llm_agents.run_data.store import atomic_write_text

__all__ = [
    "CARD_FILE",
    "CARD_MD_FILE",
    "CARD_SCHEMA_VERSION",
    "Card",
    "build_card",
    "flatten_card",
    "model_size_billions",
    "read_card",
    "verify_card",
    "write_card",
]

#: The version of the card's schema; a reader refuses any other (no silent migration of figures).
CARD_SCHEMA_VERSION: Literal[3] = 3
CARD_FILE = "card.json"
CARD_MD_FILE = "card.md"
#: Figures equal to this relative precision are the same (JSON round trips are exact; sums of
#: floats in another order are not, quite).
_TOLERANCE = 1e-9


class CardModel(BaseModel):
    """Which model played, pinned as far as the run recorded it."""

    model_config = ConfigDict(extra="forbid")

    spec: str | None
    """The model spec (`hf:smollm2-135m`, `vllm:ORG/NAME`, ...); None for agents without one."""
    resolved_revision: str | None = None
    """The hub commit a hub id resolved to when the run started; None for other models."""
    pinned_digest: str | None = None
    """For a named (embedded) model, the SHA-256 of the GGUF weights it is pinned to."""
    size_billions: float | None = None
    """Parameters in billions as the model's name states them (`135m` -> 0.135); None when it
    states none."""


class CardProtocol(BaseModel):
    """The protocol the run followed and where it departed from it."""

    model_config = ConfigDict(extra="forbid")

    name: ProtocolName
    difficulty: Difficulty
    departures: dict[str, dict[str, Any]] = Field(default_factory=dict)
    """Setting -> {"protocol": its value, "run": the run's}: the explicit settings that departed."""
    limit: int | None = None
    """The run played only the first `limit` episodes of the protocol's schedule; None: all."""
    paper_differences: list[str] = Field(default_factory=list)
    """How the run departs from the paper's protocol where that changes the numbers (then the
    published numbers do not sit beside it)."""
    unshown: list[str] = Field(default_factory=list)
    """The protocol's settings whose value the run's records cannot show, each with why (how an
    action was chosen; a step cap no episode reached; a success rule no episode's end tested):
    a departure in one of them would leave the same records (empty for a card not replayed,
    which shows nothing)."""


class CardCost(BaseModel):
    """What an episode cost, on average."""

    model_config = ConfigDict(extra="forbid")

    model_calls_per_episode: float | None
    """Prompts sent to the model; None when some record predates the count."""
    prompt_tokens_per_episode: float
    completion_tokens_per_episode: float
    model_seconds_per_episode: float | None
    """Seconds the episode waited for its answers: the summed latency of its steps (step log;
    None without one). Episodes answered in one batch wait together, so over a batched run this
    exceeds the run's wall time per episode."""
    wall_seconds_per_episode: float | None
    """The wall time the run's sittings played (model loading included) over its episodes; for
    a run recorded before sittings were timed, its start-to-finish time, any pause before a
    resume included; None when neither was recorded."""


class CardScores(BaseModel):
    """The field's achievement scores of every episode of the run."""

    model_config = ConfigDict(extra="forbid")

    achievement_list: str
    progression: float
    progression_stderr: float
    crafter_score: float
    craftaxlm_score: float


class CardGoal(BaseModel):
    """A goal a run's table should also be read without."""

    model_config = ConfigDict(extra="forbid")

    goal: str
    """`category/goal_id`, as the run names it."""
    reason: str


class CardGoalFlags(BaseModel):
    """The goals the run played that doing nothing meets, or no agent can (computed on request:
    it plays the do-nothing worlds)."""

    model_config = ConfigDict(extra="forbid")

    worlds: int
    """Seeded worlds per goal the do-nothing agent played."""
    trivial: list[CardGoal]
    impossible: list[CardGoal]


class CardFigures(BaseModel):
    """Every figure `verify_card` recomputes from the run's records."""

    model_config = ConfigDict(extra="forbid")

    episodes: int
    success: SuccessRate
    """Over every episode, clustered by goal."""
    success_by_category: dict[str, SuccessRate]
    scores: CardScores
    cost: CardCost
    terminations: dict[str, int]
    invalid_action_rate: float
    goal_flags: CardGoalFlags | None = None


class CardReplay(BaseModel):
    """How the run's records were checked by replay before the card was written
    (`llm_agents.judging.replay_check`)."""

    model_config = ConfigDict(extra="forbid")

    code_version: str
    """The code that replayed them."""
    replayed_at: datetime
    episodes: int
    """Episodes re-simulated from their world keys and actions."""
    answers: int
    """Recorded answers parsed again (0 for an agent whose actions are not parsed answers)."""


class Card(BaseModel):
    """A results card (`card.json`)."""

    model_config = ConfigDict(extra="forbid")

    schema_version: Literal[3] = CARD_SCHEMA_VERSION
    run: str
    """The run directory's name when the card was written (a label, not checked)."""
    agent: str
    model: CardModel
    protocol: CardProtocol
    success_rule: SuccessRule
    variant: str
    settings_digest: str
    """SHA-256 of the run's result-changing settings (its identity's), as canonical JSON."""
    dataset_digest: str | None
    """SHA-256 the dataset source reported for its content."""
    split_digests: dict[str, str]
    """Split -> digest of its parsed goals, for the splits the run read."""
    code_version: str | None
    """The code that played the episodes (`code_version`); several joined by `, ` when mixed."""
    hardware: dict[str, str]
    """The machine that played (empty for runs recorded before it was kept)."""
    started_at: datetime
    finished_at: datetime | None
    figures: CardFigures
    replay: CardReplay | None
    """The replay the records passed before the card was written (not compared by
    `verify_card`, which replays them again); None for a run that kept no step log, which
    cannot be replayed (the leaderboard shows such a card only with `--unverified`)."""
    created_at: datetime
    """When the card was written (not checked)."""
    digest: str = ""
    """SHA-256 of the card's content without this field: a card edited by hand no longer
    matches it."""


# ------------------------------------------------------------------------------ building


def model_size_billions(name: str | None) -> float | None:
    """Parameters in billions as a model name states them (`smollm2-135m` -> 0.135,
    `Qwen2.5-7B-it` -> 7); None when it states none."""
    if not name:
        return None
    found = re.findall(r"(?<![\d.])(\d+(?:\.\d+)?)([bBmM])(?![a-zA-Z])", name)
    if not found:
        return None
    number, unit = found[-1]
    return float(number) / (1000 if unit in "mM" else 1)


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def _digest(data: Any) -> str:
    return hashlib.sha256(_canonical(data).encode()).hexdigest()


def _card_digest(card: Card) -> str:
    return _digest(card.model_dump(mode="json", exclude={"digest"}))


def _load_run(run_dir: Path) -> RunView:
    run = read_run(run_dir, require_episodes=False)
    results = run.results
    if results.status != "complete":
        raise UserError(
            f"the run in {run_dir} is {results.status} ({results.finished} of "
            f"{results.scheduled} episodes finished): a card is only for a complete run"
        )
    if run.protocol not in PROTOCOL_NAMES:
        raise UserError(
            f"the run in {run_dir} records no protocol (it predates them): a card is only for "
            f"a run under a named protocol ({', '.join(PROTOCOL_NAMES)})"
        )
    if len(run.episodes) != results.scheduled:
        raise UserError(
            f"{run_dir} holds {len(run.episodes)} finished episodes of the {results.scheduled} "
            "its results call complete: the records are damaged"
        )
    return run


def _model(run: RunView) -> CardModel:
    from llm_agents.backends.embedded import NAMED_MODELS

    # What the agent asked of a model is read from the run, never by importing the agent
    # (an outside agent's package may not be installed where the card is checked).
    if run.model is None:
        return CardModel(spec=None)
    results = run.results
    spec = run.model
    backend, _, name = spec.partition(":")
    named = NAMED_MODELS.get(name) if backend == "hf" else None
    return CardModel(
        spec=spec,
        # Recorded by runs whose identity pins a hub id's commit; absent before that.
        resolved_revision=getattr(results.identity, "model_revision", None),
        pinned_digest=f"sha256:{named.gguf_sha256}" if named else None,
        size_billions=model_size_billions(name),
    )


def _protocol(run: RunView, check: ReplayCheck | None) -> CardProtocol:
    results, rule, config, difficulty = run.results, run.rule, run.config, run.difficulty
    protocol = protocol_for(str(config["protocol"]), difficulty)
    departures = {}
    for setting in config.get("protocol_overrides") or ():
        head, _, leaf = str(setting).rpartition(".")
        table = config.get(head, {}) if head else config
        departures[setting] = {"protocol": protocol.value(setting), "run": table.get(leaf)}
    return CardProtocol(
        name=protocol.name,
        difficulty=difficulty,
        departures=departures,
        limit=config.get("limit"),
        # The open-ended task plays no CrafText goal: the paper's numbers never sit beside it.
        paper_differences=[]
        if config.get("task") == "open_ended"
        else paper_differences(results, rule),
        unshown=[] if check is None else check.unshown,
    )


def _figures(run: RunView, worlds: int | None, check: ReplayCheck | None) -> CardFigures:
    results, rule = run.results, run.rule
    # The replay's outcomes over the protocol's episodes; the records themselves only for a run
    # that kept no step log (whose card says it was not replayed).
    episodes = run.episodes if check is None else check.replayed
    scored = rescore(episodes, rule)
    # Never the summary results.json stored: that is what is checked.
    summary = summarize(scored)
    scores = run_scores(results, episodes).overall
    n = len(episodes)
    calls = [e.model_calls for e in episodes]
    if results.played_seconds is not None:
        wall: float | None = results.played_seconds / n
    elif results.finished_at is not None:
        # Recorded before sittings were timed: the span, a resumed run's stops included.
        wall = (results.finished_at - results.started_at).total_seconds() / n
    else:
        wall = None
    flags = None
    if worlds is not None:
        status = run_goal_status(results.config, episodes, rule=rule, worlds=worlds)
        played = sorted({f"{e.category}/{e.goal_id}" for e in episodes})
        goals = [status.goals[key] for key in played if key in status.goals]
        flags = CardGoalFlags(
            worlds=worlds,
            trivial=[
                CardGoal(
                    goal=f"{g.category}/{g.goal_id}",
                    reason=f"met in {g.do_nothing} of {worlds} worlds by doing nothing",
                )
                for g in goals
                if g.trivial
            ],
            impossible=[
                CardGoal(goal=f"{g.category}/{g.goal_id}", reason=g.impossible)
                for g in goals
                if g.impossible
            ],
        )
    return CardFigures(
        episodes=n,
        success=summary.overall,
        success_by_category=summary.by_category,
        scores=CardScores.model_validate(scores.model_dump(include=set(CardScores.model_fields))),
        cost=CardCost(
            model_calls_per_episode=math.fsum(c for c in calls if c is not None) / n
            if all(c is not None for c in calls)
            else None,
            prompt_tokens_per_episode=sum(e.prompt_tokens for e in episodes) / n,
            completion_tokens_per_episode=sum(e.completion_tokens for e in episodes) / n,
            # Summed as the replay check read the step log: the log is read once.
            model_seconds_per_episode=None if check is None else check.model_seconds / n,
            wall_seconds_per_episode=wall,
        ),
        terminations=summary.terminations,
        invalid_action_rate=summary.invalid_action_rate,
        goal_flags=flags,
    )


def build_card(
    run_dir: str | Path, *, goal_flags_worlds: int | None = None, progress: bool = False
) -> Card:
    """The card of the complete run in `run_dir` (a `UserError` for any other), after its
    records were checked by replay (`RunDoesNotReplay` when they do not replay); with
    `goal_flags_worlds`, the goals doing nothing meets (in that many seeded worlds each, played
    once and cached) or no agent can."""
    return _card_of(_load_run(Path(run_dir)), goal_flags_worlds, progress)


def _card_of(run: RunView, goal_flags_worlds: int | None, progress: bool) -> Card:
    check = _replayed(run, progress) if run.has_steps else None
    codes = sorted({e.code or "not recorded" for e in run.episodes})
    card = Card(
        run=run.path.resolve().name,
        agent=run.agent,
        model=_model(run),
        protocol=_protocol(run, check),
        success_rule=run.rule,
        variant=str(run.config.get("variant")),
        settings_digest=_digest(run.results.identity.settings),
        dataset_digest=run.results.identity.dataset,
        split_digests=dict(sorted(run.results.identity.goals.items())),
        code_version=", ".join(codes),
        hardware=run.results.hardware,
        started_at=run.results.started_at,
        finished_at=run.results.finished_at,
        figures=_figures(run, goal_flags_worlds, check),
        replay=None
        if check is None
        else CardReplay(
            code_version=code_version(),
            replayed_at=datetime.now(UTC),
            episodes=check.episodes,
            answers=check.answers,
        ),
        created_at=datetime.now(UTC),
    )
    card.digest = _card_digest(card)
    return card


def _replayed(run: RunView, progress: bool) -> ReplayCheck:
    """The replay check of `run`; `RunDoesNotReplay` naming each difference when it fails."""
    check = check_run(run, progress=progress)
    if check.differences:
        raise RunDoesNotReplay(run.path, check.differences)
    return check


# ------------------------------------------------------------------------------ reading, checking


def read_card(path: str | Path) -> Card:
    """The card in `path`; a `UserError` for a file that is not one, a card of another schema
    version, or one whose content no longer matches its digest (edited by hand)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise UserError(f"cannot read card {path}: {err.strerror}") from err
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise UserError(f"{path} is not a results card: not JSON ({err})") from err
    if not isinstance(data, dict) or "schema_version" not in data:
        raise UserError(f"{path} is not a results card: it has no schema_version")
    if data["schema_version"] != CARD_SCHEMA_VERSION:
        raise UserError(
            f"{path} is a card of schema version {data['schema_version']!r}; this craftext-llm "
            f"reads version {CARD_SCHEMA_VERSION}: write it again with `craftext-llm card RUN_DIR`"
        )
    try:
        card = Card.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise UserError(f"{path} is not a results card: {where}: {first['msg']}") from err
    if card.digest != _card_digest(card):
        raise UserError(
            f"{path} was changed after it was written (its content no longer matches its "
            "digest): write it again with `craftext-llm card RUN_DIR`"
        )
    return card


def flatten_card(card: Card) -> dict[str, Any]:
    """Every checked value of a card, flattened to `dotted.name -> value` (what `verify_card`
    compares): all but the run's label, its replay's record, the card's writing time and its
    digest."""
    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, Mapping):
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), item)
        elif isinstance(value, list) and value and isinstance(value[0], Mapping):
            for index, item in enumerate(value):
                walk(f"{prefix}[{index}]", item)
        else:
            flat[prefix] = value

    walk("", card.model_dump(mode="json", exclude={"run", "replay", "created_at", "digest"}))
    return flat


def _check_own(card: Card, run: RunView) -> None:
    """A `UserError` when `card` was written for another run than `run` (told apart by when each
    run started: a card checked against another run would only list every figure as differing)."""
    started = run.results.started_at
    if card.started_at != started:
        raise UserError(
            f"the card of run {card.run!r} (started {card.started_at:%Y-%m-%d %H:%M:%S}) is not "
            f"the card of the run in {run.path} (started {started:%Y-%m-%d %H:%M:%S}): give "
            "each card with its own run"
        )


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=_TOLERANCE, abs_tol=_TOLERANCE)
    return bool(a == b)


def verify_card(card: Card, run_dir: str | Path, *, progress: bool = False) -> list[str]:
    """The figures of `card` that the records in `run_dir` do not give, each as `name: card X,
    run Y`; empty when every one agrees. The records are first checked by replay
    (`RunDoesNotReplay` naming each episode and field that differ)."""
    run = _load_run(Path(run_dir))
    _check_own(card, run)
    worlds = card.figures.goal_flags.worlds if card.figures.goal_flags else None
    fresh = _card_of(run, worlds, progress)
    ours, theirs = flatten_card(card), flatten_card(fresh)
    differences = []
    for name in sorted(ours.keys() | theirs.keys()):
        a, b = ours.get(name), theirs.get(name)
        if not _same(a, b):
            differences.append(f"{name}: card {_shown(a)}, run {_shown(b)}")
    return differences


def _shown(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 60 else text[:57] + "..."


# ------------------------------------------------------------------------------ writing


def _rate(rate: SuccessRate) -> str:
    return (
        f"{rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}] (n={rate.episodes}, g={rate.clusters})"
    )


def _number(value: float | None, digits: int = 1) -> str:
    return "—" if value is None else f"{value:,.{digits}f}"


def card_markdown(card: Card) -> str:
    """The short human-readable `card.md` of a card, every recorded text in it escaped
    (`markup`): a card is anyone's file, and its page is rendered as HTML."""
    text, code = markdown_text, markdown_code
    figures = card.figures
    protocol = card.protocol
    model = text(card.model.spec or "none (scripted)")
    pinned = card.model.resolved_revision or card.model.pinned_digest
    departures = (
        ", ".join(
            f"{text(name)} = {text(_canonical(d['run']))} "
            f"(protocol: {text(_canonical(d['protocol']))})"
            for name, d in protocol.departures.items()
        )
        or "none"
    )
    lines = [
        f"# Results card: {text(card.run)}",
        "",
        f"- **Agent**: {text(card.agent)}; **model**: {model}"
        + (f" (pinned: {code(pinned)})" if pinned else ""),
        f"- **Protocol**: `{protocol.name}`, {protocol.difficulty}; departures: {departures}"
        + (f"; first {protocol.limit} episodes of its schedule" if protocol.limit else ""),
        f"- **Game**: {text(card.variant)} Craftax, success rule `{card.success_rule}`",
        f"- **Code**: {code(card.code_version)}; settings digest "
        f"{code(card.settings_digest[:12])}; "
        f"dataset digest {code((card.dataset_digest or 'not recorded')[:12])}",
        "- **Hardware**: "
        + (", ".join(f"{text(k)} {text(v)}" for k, v in card.hardware.items()) or "not recorded"),
        _replay_line(card.replay),
        "",
        "| Goal set | Success [95% interval clustered by goal] |",
        "|---|---|",
        *(
            f"| {text(name)} | {_rate(figures.success_by_category[name])} |"
            for name in dict.fromkeys(
                (*DIFFICULTY_CATEGORIES[protocol.difficulty], *figures.success_by_category)
            )
            if name in figures.success_by_category
        ),
        f"| **overall** | {_rate(figures.success)} |",
        "",
        f"Scores over {text(figures.scores.achievement_list)} achievements: progression "
        f"{figures.scores.progression:.1f} ± {figures.scores.progression_stderr:.1f}, Crafter "
        f"score {figures.scores.crafter_score:.2f}, craftaxlm {figures.scores.craftaxlm_score:.2f}.",
        "",
        f"Per episode: {_number(figures.cost.model_calls_per_episode)} model calls, "
        f"{_number(figures.cost.prompt_tokens_per_episode, 0)} prompt and "
        f"{_number(figures.cost.completion_tokens_per_episode, 0)} completion tokens, "
        f"{_number(figures.cost.model_seconds_per_episode)} s waiting for answers; "
        f"{_number(figures.cost.wall_seconds_per_episode)} s of the run's wall time.",
    ]
    if protocol.paper_differences:
        lines += [
            "",
            "Departs from the paper's protocol: "
            + "; ".join(text(d) for d in protocol.paper_differences),
        ]
    if protocol.unshown:
        lines += [
            "",
            "Not shown by the records (a departure here would leave the same records): "
            + "; ".join(text(u) for u in protocol.unshown),
        ]
    if figures.goal_flags is not None:
        flags = figures.goal_flags
        listed = [f"{text(g.goal)} (trivial: {text(g.reason)})" for g in flags.trivial] + [
            f"{text(g.goal)} (impossible: {text(g.reason)})" for g in flags.impossible
        ]
        lines += ["", "Goals to read the table without: " + ("; ".join(listed) or "none")]
    lines += [
        "",
        f"Check it against the run: `craftext-llm card --verify card.json RUN_DIR` "
        f"(card digest {markdown_code(card.digest[:12])}).",
    ]
    return "\n".join(lines) + "\n"


def _replay_line(replay: CardReplay | None) -> str:
    if replay is None:
        return "- **Replayed**: NOT: the run kept no step log, so its records cannot be replayed"
    return (
        f"- **Replayed**: {replay.episodes} episodes re-simulated from their world keys and "
        "actions"
        + (f", {replay.answers} answers parsed again" if replay.answers else "")
        + f", by code {markdown_code(replay.code_version)} on {replay.replayed_at:%Y-%m-%d}"
    )


def write_card(card: Card, out: str | Path) -> tuple[Path, Path]:
    """Write `card.json` and `card.md` into the directory `out` (each atomically, the JSON last,
    so a card.json on disk always has its card.md); returns both paths."""
    out = Path(out)
    if not out.is_dir():
        raise UserError(f"{out} is not a directory to write the card into")
    json_path, md_path = out / CARD_FILE, out / CARD_MD_FILE
    try:
        atomic_write_text(md_path, card_markdown(card))
        atomic_write_text(json_path, card.model_dump_json(indent=2) + "\n")
    except OSError as err:
        raise UserError(f"cannot write the card into {out}: {err.strerror}") from err
    return json_path, md_path
