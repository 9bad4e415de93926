"""`plan-score`: plans scored by playing them (`execution`), per plan and per split, with the
best candidate of each text and training data exported from the scores.

Reads an official plans file (`{text: plan}`) or a candidates file (`{text: [plan, ...]}`),
reads every step into skills (`steps`), plays each plan in `worlds` selection worlds, chooses
each text's best candidate there, plays the first and the best again in `held_out_worlds` other
worlds, and writes, into the output folder:
- `episodes.jsonl`: the journal, one line per finished episode after a settings header; a rerun
  with the same settings plays only what it lacks;
- `scores.json`: per plan its steps as read, success rate with its interval, first failures and
  verdict (`verdict`: steps that break the instruction, a text met without acting); per split
  the rates of the texts' first and best candidates, in the selection and held-out worlds,
  clustered by goal, and the plans and texts kept out of the exports;
- `best.json`: each text's best candidate (ties to the shorter plan), the official shape;
- with `export`, `sft.jsonl` and `dpo.jsonl` (`export`).
Every input is checked before anything is written.

Worlds: selection and held-out worlds are two named families of keys (`env.episode_key`'s
`stream`), apart from each other and from eval's, so `eval --plans best.json` plays none of the
worlds a plan was chosen in; `eval_worlds` chooses in eval's own worlds instead (as versions
before held-out worlds did).

`PlanJudge` is the same execution for a trainer: plan texts for instructions in, per plan its
success and the shaped parts of a reward out.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from env.dataset import load_dataset
from env.errors import UserError
from env.goals import AnyGoal
from env.variant import DEFAULT_VARIANT, Variant
from llm_agents.agents.skills.catalogue import read_skill, skill_offer
from llm_agents.planning.checks import PlanLimits, parse_plan
from llm_agents.planning.execution import (
    SKILL_STEPS,
    EpisodeOutcome,
    PlanEpisode,
    play_plan_episodes,
)
from llm_agents.planning.export import Prompter, dpo_rows, rank_key, sft_rows
from llm_agents.planning.loop import PLANNER_TEMPLATE, planner_messages
from llm_agents.planning.records import FirstFailure, PlanScore, StepReading
from llm_agents.planning.steps import read_plan
from llm_agents.planning.verdict import breaking_steps, goal_part_reached
from llm_agents.run_data.metrics import SuccessRate, clustered_rate
from llm_agents.run_data.plans import load_candidates
from llm_agents.run_data.store import (
    append_lines,
    atomic_write_json,
    atomic_write_text,
    check_output_dir,
    complete_lines,
    make_output_dir,
)
from prompts import template_digests

ExportKind = Literal["sft", "dpo"]
JOURNAL = "episodes.jsonl"
SCORES = "scores.json"
BEST = "best.json"
EXPORT_FILES: dict[str, str] = {"sft": "sft.jsonl", "dpo": "dpo.jsonl"}
_SHOWN = 5
#: The families of worlds plans are chosen in and reported in (`env.episode_key`'s stream).
SELECTION_WORLDS = "plan-score/selection"
HELD_OUT_WORLDS = "plan-score/held-out"
#: What a journal's lines mean; older journals are refused rather than misread.
_JOURNAL_FORMAT = 2


class ScoreConfig(BaseModel):
    """What `craftext-llm plan-score` does."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    plans: Path
    """An official plans file or a candidates file."""
    out: Path
    """The folder to write."""
    worlds: int = Field(4, ge=1)
    """Selection worlds each plan is played in (each text's best candidate is chosen there)."""
    held_out_worlds: int = Field(4, ge=0)
    """Worlds, apart from the selection worlds and from eval's, each text's first and best
    candidates are played in again (0: none)."""
    eval_worlds: bool = False
    """Choose in eval's own worlds (the seed's, as `eval` plays them) instead of the selection
    worlds: to compare with earlier scores."""
    seed: int = 0
    """The seed the worlds come from."""
    dataset: str | None = None
    """The dataset the texts come from (`load_dataset`)."""
    variant: Variant = DEFAULT_VARIANT
    """The Craftax variant played."""
    splits: tuple[str, ...] = ()
    """Score only texts of these dataset splits; empty: every text."""
    limit: int | None = Field(None, ge=1)
    """Score only the first N texts (after `splits`)."""
    skip_unknown_texts: bool = False
    """Score the texts the dataset has and skip the others, instead of refusing the file."""
    batch_size: int = Field(32, ge=1)
    """Episodes in flight."""
    skill_steps: int = Field(SKILL_STEPS, ge=1)
    """Steps one skill may take before it counts as failed."""
    export: tuple[ExportKind, ...] = ()
    """Training data to write: `sft`, `dpo`."""
    threshold: float = Field(0.5, ge=0.0, le=1.0)
    """SFT: the least success rate a plan needs."""
    margin: float = Field(0.25, gt=0.0, le=1.0)
    """DPO: the least difference of success rates between the chosen and the rejected plan."""
    pairs_per_text: int = Field(4, ge=1)
    """DPO: the most pairs one text gives (the widest margins first)."""
    restart: bool = False
    """Discard the folder's journal instead of resuming it."""

    @field_validator("out")
    @classmethod
    def _folder(cls, value: Path) -> Path:
        if value.is_file():
            raise ValueError(f"{value} is a file; name the folder to write")
        check_output_dir(value)
        return value


class _Settings(BaseModel):
    """What decides every episode's outcome: a journal resumes only under the same."""

    model_config = ConfigDict(frozen=True)

    format: int = _JOURNAL_FORMAT
    plans_sha256: str
    worlds: int
    held_out_worlds: int
    eval_worlds: bool
    seed: int
    variant: Variant
    dataset: dict[str, Any]
    skill_steps: int


def _listed(texts: Sequence[str]) -> str:
    shown = ", ".join(repr(t) for t in texts[:_SHOWN])
    return shown + (f" and {len(texts) - _SHOWN} more" if len(texts) > _SHOWN else "")


def _texts(config: ScoreConfig, plans: dict[str, list[str]]) -> dict[str, tuple[AnyGoal, int]]:
    """Each scored text's goal and phrasing index, in the plans file's order."""
    dataset = load_dataset(config.dataset)
    where: dict[str, tuple[AnyGoal, int]] = {}
    for goal in dataset.goals:
        for index, text in enumerate(goal.texts):
            where.setdefault(text, (goal, index))
    unknown = [text for text in plans if text not in where]
    if unknown and not config.skip_unknown_texts:
        raise UserError(
            f"{len(unknown)} of {len(plans)} texts of {config.plans} are not in the dataset: "
            f"{_listed(unknown)} (pass --skip-unknown-texts to score the others)"
        )
    known_splits = {goal.split for goal in dataset.goals}
    bad = [split for split in config.splits if split not in known_splits]
    if bad:
        raise UserError(
            f"the dataset has no split {', '.join(bad)}; it has {', '.join(sorted(known_splits))}"
        )
    chosen = {
        text: where[text]
        for text in plans
        if text in where and (not config.splits or where[text][0].split in config.splits)
    }
    if config.limit is not None:
        chosen = dict(list(chosen.items())[: config.limit])
    if not chosen:
        raise UserError(f"no text of {config.plans} is left to score")
    return chosen


def _episode_key(text: str, candidate: int, world: int, stream: str, reading: str) -> str:
    return json.dumps([text, candidate, world, stream, reading], ensure_ascii=False)


def _reading(steps: Sequence[StepReading]) -> str:
    """A digest of the skills a plan was read as: a journal's episode of a plan the reader now
    reads otherwise is played again, not reused."""
    skills = [list(step.skills) for step in steps]
    return hashlib.sha256(json.dumps(skills).encode()).hexdigest()[:16]


class _Journal:
    def __init__(self, path: Path, settings: _Settings, restart: bool):
        self.path = path
        self.done: dict[str, EpisodeOutcome] = {}
        if restart:
            path.unlink(missing_ok=True)
        lines = complete_lines(path)
        if not lines:
            path.write_bytes(b"")
            append_lines(path, [json.dumps({"settings": settings.model_dump(mode="json")})])
            return
        try:
            header = json.loads(lines[0])["settings"]
            if header.get("format") != _JOURNAL_FORMAT:
                raise UserError(
                    f"{path} was written by an older plan-score (other worlds and readings): "
                    "write to another --out or pass --restart"
                )
            previous = _Settings.model_validate(header)
        except (json.JSONDecodeError, KeyError, TypeError, AttributeError, ValidationError) as err:
            raise UserError(f"{path} is not a plan-score journal ({err}); pass --restart") from err
        if previous != settings:
            changed = [
                n for n in _Settings.model_fields if getattr(previous, n) != getattr(settings, n)
            ]
            raise UserError(
                f"{path} was written with other {', '.join(changed)}: write to another --out "
                "or pass --restart"
            )
        for number, line in enumerate(lines[1:], 2):
            try:
                outcome = EpisodeOutcome.model_validate_json(line)
            except ValidationError:
                raise UserError(f"{path} line {number} is corrupt; pass --restart") from None
            self.done[outcome.key] = outcome

    def add(self, outcomes: list[EpisodeOutcome]) -> None:
        append_lines(self.path, [o.model_dump_json() for o in outcomes], durable=False)
        self.done.update((o.key, o) for o in outcomes)


class ScoreSummary(BaseModel):
    """What `plan-score` did."""

    texts: int
    plans: int
    episodes: int
    resumed: int
    """Episodes already in the journal."""
    wall_s: float
    scores: Path
    best: Path
    exports: dict[str, int] = Field(default_factory=dict)
    """Export kind -> lines written."""
    kept_out: dict[str, int] = Field(default_factory=dict)
    """Why plans were kept out of the exports -> how many (texts met without acting count
    every plan of theirs)."""


PlannerSettings = tuple[PlanLimits, Variant, str | None]
"""The limits, variant and templates folder a plans file was asked with."""


def _check_exports(
    config: ScoreConfig, plans: dict[str, list[str]], texts: Sequence[str]
) -> PlannerSettings | None:
    """The settings the exports will be asked with, read before anything is played so that a
    changed prompt or an export with nothing to pair is refused first; None without exports."""
    if "dpo" in config.export and not any(len(set(plans[t])) >= 2 for t in texts):
        raise UserError(
            "--export dpo pairs candidates of one text, and no scored text has two: score a "
            "candidates file (craftext-llm plan --candidates N)"
        )
    return _planner_settings(config.plans, config.variant) if config.export else None


def _plan_episodes(
    key_text: str,
    goal: AnyGoal,
    index: int,
    candidate: int,
    steps: list[StepReading],
    offer: Any,
    worlds: int,
    stream: str,
) -> list[PlanEpisode]:
    skills = tuple(
        (step.number, read_skill(skill, offer)) for step in steps for skill in step.skills
    )
    return [
        PlanEpisode(
            _episode_key(key_text, candidate, world, stream, _reading(steps)),
            goal,
            index,
            world,
            skills,
            stream,
        )
        for world in range(worlds)
    ]


def _play(
    todo: list[PlanEpisode],
    journal: _Journal,
    config: ScoreConfig,
    progress: Callable[[int, int], Any] | None,
    total: int,
) -> None:
    from env import EnvConfig, shared_env

    bar = progress(total, total - len(todo)) if progress else None

    def done(outcomes: list[EpisodeOutcome]) -> None:
        journal.add(outcomes)
        if bar is not None:
            bar.update(len(outcomes))

    try:
        if todo:
            play_plan_episodes(
                todo,
                shared_env(EnvConfig(variant=config.variant)),
                variant=config.variant,
                seed=config.seed,
                batch_size=config.batch_size,
                on_done=done,
                skill_steps=config.skill_steps,
            )
    finally:
        if bar is not None:
            bar.close()


def _met_without_acting(goals: Sequence[AnyGoal], config: ScoreConfig) -> set[str]:
    """The goals (`goal_key`) a do-nothing agent meets in at least one of `worlds` worlds."""
    from env import EnvConfig
    from env.goal_status import do_nothing_successes, goal_key

    met = do_nothing_successes(
        goals, EnvConfig(variant=config.variant), worlds=config.worlds, seed=config.seed
    )
    return {goal_key(goal) for goal in goals if met.get(goal_key(goal), 0) > 0}


def score_plans(
    config: ScoreConfig,
    *,
    progress: Callable[[int, int], Any] | None = None,
) -> ScoreSummary:
    """Score every plan (see the module); `progress(total, initial)` makes a progress bar (one
    for the selection worlds, one for the held-out worlds)."""
    from env.dataset import load_dataset as _load
    from env.goal_status import goal_key

    started = time.perf_counter()
    plans = load_candidates(config.plans)
    texts = _texts(config, plans)
    export_settings = _check_exports(config, plans, list(texts))
    dataset = _load(config.dataset)
    settings = _Settings(
        plans_sha256=hashlib.sha256(config.plans.read_bytes()).hexdigest(),
        worlds=config.worlds,
        held_out_worlds=config.held_out_worlds,
        eval_worlds=config.eval_worlds,
        seed=config.seed,
        variant=config.variant,
        dataset=dataset.source.model_dump(mode="json"),
        skill_steps=config.skill_steps,
    )
    selection = "" if config.eval_worlds else SELECTION_WORLDS
    readings: dict[tuple[str, int], list[StepReading]] = {}
    episodes: list[PlanEpisode] = []
    for text, (goal, index) in texts.items():
        offer = skill_offer(config.variant, goal.difficulty)
        for candidate, plan in enumerate(plans[text]):
            steps = read_plan(parse_plan(plan)[0], offer)
            readings[(text, candidate)] = steps
            episodes += _plan_episodes(
                text, goal, index, candidate, steps, offer, config.worlds, selection
            )
    make_output_dir(config.out)
    journal = _Journal(config.out / JOURNAL, settings, config.restart)
    todo = [ep for ep in episodes if ep.key not in journal.done]
    resumed = len(episodes) - len(todo)
    _play(todo, journal, config, progress, len(episodes))
    met = _met_without_acting([goal for goal, _ in texts.values()], config)
    scores: list[PlanScore] = []
    for text, (goal, _) in texts.items():
        offer = skill_offer(config.variant, goal.difficulty)
        for candidate in range(len(plans[text])):
            outcomes = [
                journal.done[
                    _episode_key(
                        text, candidate, w, selection, _reading(readings[(text, candidate)])
                    )
                ]
                for w in range(config.worlds)
            ]
            steps = readings[(text, candidate)]
            score = _plan_score(text, candidate, plans[text][candidate], steps, goal, outcomes)
            scores.append(
                score.model_copy(
                    update={
                        "breaks": breaking_steps(steps, getattr(goal, "forbidden", ()), offer),
                        "met_without_acting": goal_key(goal) in met,
                    }
                )
            )
    by_text: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        by_text[score.instruction].append(score)
    best = {text: min(group, key=rank_key) for text, group in by_text.items()}
    held_out_episodes = _held_out(config, texts, readings, best)
    todo = [ep for ep in held_out_episodes if ep.key not in journal.done]
    resumed += len(held_out_episodes) - len(todo)
    _play(todo, journal, config, progress, len(held_out_episodes))
    if config.held_out_worlds:
        scores = [_with_held_out(score, journal, config) for score in scores]
        best = {text: _with_held_out(score, journal, config) for text, score in best.items()}
    atomic_write_json(
        config.out / SCORES,
        {
            "settings": settings.model_dump(mode="json") | {"plans": str(config.plans)},
            "splits": split_summary(scores, best),
            "kept_out": kept_out(scores),
            "plans": [s.model_dump(mode="json") | {"excluded": s.excluded} for s in scores],
        },
    )
    atomic_write_json(config.out / BEST, {text: score.plan for text, score in best.items()})
    exports = _write_exports(config, scores, export_settings)
    return ScoreSummary(
        texts=len(texts),
        plans=len(scores),
        episodes=len(episodes) + len(held_out_episodes),
        resumed=resumed,
        wall_s=round(time.perf_counter() - started, 3),
        scores=config.out / SCORES,
        best=config.out / BEST,
        exports=exports,
        kept_out=kept_out(scores),
    )


def _held_out(
    config: ScoreConfig,
    texts: dict[str, tuple[AnyGoal, int]],
    readings: dict[tuple[str, int], list[StepReading]],
    best: dict[str, PlanScore],
) -> list[PlanEpisode]:
    """Each text's first and best candidates in the held-out worlds."""
    if not config.held_out_worlds:
        return []
    episodes: list[PlanEpisode] = []
    for text, (goal, index) in texts.items():
        offer = skill_offer(config.variant, goal.difficulty)
        for candidate in sorted({0, best[text].candidate}):
            episodes += _plan_episodes(
                text,
                goal,
                index,
                candidate,
                readings[(text, candidate)],
                offer,
                config.held_out_worlds,
                HELD_OUT_WORLDS,
            )
    return episodes


def _with_held_out(score: PlanScore, journal: _Journal, config: ScoreConfig) -> PlanScore:
    keys = [
        _episode_key(score.instruction, score.candidate, w, HELD_OUT_WORLDS, _reading(score.steps))
        for w in range(config.held_out_worlds)
    ]
    if keys[0] not in journal.done:
        return score
    outcomes = [journal.done[key] for key in keys]
    rate = SuccessRate.of(sum(o.success for o in outcomes), len(outcomes))
    return score.model_copy(update={"held_out": rate})


def kept_out(scores: Sequence[PlanScore]) -> dict[str, int]:
    """Why plans are kept out of the exports -> how many, and the texts met without acting."""
    counts = Counter(s.excluded for s in scores if s.excluded is not None)
    texts = {s.instruction for s in scores if s.met_without_acting}
    return dict(sorted(counts.items())) | {"texts_met_without_acting": len(texts)}


def _plan_score(
    text: str,
    candidate: int,
    plan: str,
    steps: list[StepReading],
    goal: AnyGoal,
    outcomes: list[EpisodeOutcome],
) -> PlanScore:
    failures = Counter(
        (o.failed_step, o.failed_skill, o.reason or "") for o in outcomes if not o.success
    )
    required = getattr(goal, "required", ())
    skills = sum(len(step.skills) for step in steps)
    return PlanScore(
        instruction=text,
        candidate=candidate,
        plan=plan,
        steps=steps,
        goal_id=goal.id,
        split=goal.split,
        success=SuccessRate.of(sum(o.success for o in outcomes), len(outcomes)),
        env_steps=sum(o.steps for o in outcomes),
        failures=[
            FirstFailure(step=step, skill=skill, reason=reason, episodes=count)
            for (step, skill, reason), count in failures.most_common()
        ],
        goal_reached=_mean(goal_part_reached(required, o.reached, o.success) for o in outcomes),
        played=_mean(o.played / skills if skills else 0.0 for o in outcomes),
    )


def _mean(values: Any) -> float:
    values = list(values)
    return round(sum(values) / len(values), 4) if values else 0.0


def split_summary(
    scores: Sequence[PlanScore], best: dict[str, PlanScore]
) -> dict[str, dict[str, Any]]:
    """Per split: texts, plans, steps read and unread, the success of each text's first
    candidate and of its best one (chosen in the selection worlds), clustered by goal, in the
    selection worlds and, where played, the held-out ones (where the choice cannot flatter the
    best), and the plans kept out of the exports."""
    groups: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        groups[score.split].append(score)
    summary = {}
    for split, group in sorted(groups.items()):
        first = [s for s in group if s.candidate == 0]
        chosen = [best[t] for t in dict.fromkeys(s.instruction for s in group)]
        row: dict[str, Any] = {
            "texts": len(chosen),
            "plans": len(group),
            "steps_read": sum(s.read for s in group),
            "steps_unread": sum(s.unread for s in group),
            "first": _clustered(first).model_dump(mode="json"),
            "best": _clustered(chosen).model_dump(mode="json"),
        }
        if all(s.held_out is not None for s in (*first, *chosen)):
            row["first_held_out"] = _clustered(first, held_out=True).model_dump(mode="json")
            row["best_held_out"] = _clustered(chosen, held_out=True).model_dump(mode="json")
        row["kept_out"] = kept_out(group)
        summary[split] = row
    return summary


def _clustered(scores: Sequence[PlanScore], held_out: bool = False) -> SuccessRate:
    def rate(score: PlanScore) -> SuccessRate:
        return score.held_out if held_out and score.held_out is not None else score.success

    return clustered_rate((s.goal_id, rate(s).successes, rate(s).episodes) for s in scores)


def _write_exports(
    config: ScoreConfig, scores: list[PlanScore], settings: PlannerSettings | None
) -> dict[str, int]:
    if settings is None:
        return {}
    limits, variant, templates = settings
    cache: dict[str, list[dict[str, str]]] = {}

    def prompt(text: str) -> list[dict[str, str]]:
        if text not in cache:
            cache[text] = [
                {"role": m.role, "content": m.content}
                for m in planner_messages(text, limits, variant, templates)
            ]
        return cache[text]

    asked: Prompter = prompt
    usable = [score for score in scores if score.excluded is None]
    written: dict[str, int] = {}
    for kind in config.export:
        rows = (
            sft_rows(usable, config.threshold, asked)
            if kind == "sft"
            else dpo_rows(usable, config.margin, asked, config.pairs_per_text)
        )
        atomic_write_text(
            config.out / EXPORT_FILES[kind],
            "".join(json.dumps(row, ensure_ascii=False) + "\n" for row in rows),
        )
        written[kind] = len(rows)
    return written


def _planner_settings(plans: Path, variant: Variant) -> PlannerSettings:
    """The limits, variant and templates folder the plans were asked with: from the sidecar
    `plan` writes beside them, else `plan`'s defaults and the scored variant. A templates folder
    whose planner template is no longer the one the plans were asked with is refused: the
    exports would pair the plans with a prompt that never produced them."""
    sidecar = plans.with_name(f"{plans.stem}.meta.json")
    try:
        written = json.loads(sidecar.read_text(encoding="utf-8"))
        settings = written["settings"]
        limits = PlanLimits.model_validate(settings["limits"])
        asked_variant = Variant(settings["variant"])
        templates_dir = written.get("templates_dir")
        asked_digest = settings["templates"].get(PLANNER_TEMPLATE)
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ValidationError):
        return PlanLimits(), variant, None
    try:
        digest = template_digests((PLANNER_TEMPLATE,), templates_dir)[PLANNER_TEMPLATE]
    except (OSError, UserError):
        digest = None
    if asked_digest is not None and digest != asked_digest:
        where = templates_dir or "the project's templates"
        raise UserError(
            f"{sidecar}: the plans were asked with another {PLANNER_TEMPLATE} than {where} "
            "holds now, so their exported prompts would not be the ones that produced them"
        )
    return limits, asked_variant, templates_dir


class PlanReward(BaseModel):
    """One plan's verdict for a trainer (`PlanJudge.score`): its success first, and the shaped
    parts that still tell plans apart when none succeeds."""

    model_config = ConfigDict(frozen=True)

    instruction: str
    plan: str
    success: float
    """The share of the worlds in which the goal was met."""
    goal_reached: float
    """The share of the goal's required achievements reached, on average over the worlds (a
    placing goal: its success)."""
    played: float
    """The share of the plan's skills that finished, on average over the worlds."""
    breaks: tuple[str, ...] = ()
    """Steps that earn an achievement the instruction forbids, played or not."""
    empty: bool = False
    """No step of the plan was read as a skill (nothing was played)."""


class PlanJudge:
    """Plan texts for dataset instructions, played as `plan-score` plays them, for a trainer's
    reward: build once (it loads the dataset), then `score([(instruction, plan), ...])` plays
    every pair in `worlds` worlds of `stream` on one batched env and returns one `PlanReward`
    per pair, in order.

    `stream` defaults to plan-score's selection worlds: rewards never come from the held-out
    worlds (`HELD_OUT_WORLDS`) or eval's (stream `""`) a tuned planner is reported in. An
    instruction the dataset lacks raises `UserError`; the env compiles once per batch size and
    variant for the whole process (`env.shared_env`)."""

    def __init__(
        self,
        *,
        dataset: str | None = None,
        variant: Variant = DEFAULT_VARIANT,
        worlds: int = 4,
        seed: int = 0,
        stream: str = SELECTION_WORLDS,
        batch_size: int = 32,
        skill_steps: int = SKILL_STEPS,
    ) -> None:
        if worlds < 1:
            raise UserError(f"worlds must be at least 1, got {worlds}")
        self.variant, self.worlds, self.seed, self.stream = variant, worlds, seed, stream
        self.batch_size, self.skill_steps = batch_size, skill_steps
        self._goals: dict[str, tuple[AnyGoal, int]] = {}
        for goal in load_dataset(dataset).goals:
            for index, text in enumerate(goal.texts):
                self._goals.setdefault(text, (goal, index))

    def score(self, pairs: Sequence[tuple[str, str]]) -> list[PlanReward]:
        """One reward per (instruction, plan) pair, in order."""
        from env import EnvConfig, shared_env

        unknown = [text for text, _ in pairs if text not in self._goals]
        if unknown:
            raise UserError(
                f"{len(unknown)} instructions are not in the dataset: {_listed(unknown)}"
            )
        episodes: list[PlanEpisode] = []
        readings = []
        for number, (text, plan) in enumerate(pairs):
            goal, index = self._goals[text]
            offer = skill_offer(self.variant, goal.difficulty)
            steps = read_plan(parse_plan(plan)[0], offer)
            readings.append((goal, offer, steps))
            # The pair's position keys its episodes: two pairs may repeat one plan.
            episodes += _plan_episodes(
                str(number), goal, index, 0, steps, offer, self.worlds, self.stream
            )
        outcomes: dict[str, EpisodeOutcome] = {}
        play_plan_episodes(
            episodes,
            shared_env(EnvConfig(variant=self.variant)),
            variant=self.variant,
            seed=self.seed,
            batch_size=self.batch_size,
            on_done=lambda done: outcomes.update((o.key, o) for o in done),
            skill_steps=self.skill_steps,
        )
        rewards = []
        for number, ((text, plan), (goal, offer, steps)) in enumerate(
            zip(pairs, readings, strict=True)
        ):
            played = [
                outcomes[_episode_key(str(number), 0, w, self.stream, _reading(steps))]
                for w in range(self.worlds)
            ]
            score = _plan_score(text, 0, plan, steps, goal, played)
            rewards.append(
                PlanReward(
                    instruction=text,
                    plan=plan,
                    success=score.success.rate,
                    goal_reached=score.goal_reached,
                    played=score.played,
                    breaks=tuple(breaking_steps(steps, getattr(goal, "forbidden", ()), offer)),
                    empty=score.empty,
                )
            )
        return rewards
