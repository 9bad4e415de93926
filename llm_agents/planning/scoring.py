"""`plan-score`: plans scored by playing them (`execution`), per plan and per split, with the
best candidate of each text and training data exported from the scores.

Reads an official plans file (`{text: plan}`) or a candidates file (`{text: [plan, ...]}`),
reads every step into skills (`steps`), plays each plan in `worlds` seeded worlds and writes,
into the output folder:
- `episodes.jsonl`: the journal, one line per finished episode after a settings header; a rerun
  with the same settings plays only what it lacks;
- `scores.json`: per plan its steps as read, success rate with its interval and first failures;
  per split the rates of the texts' first and best candidates, clustered by goal;
- `best.json`: each text's best candidate (ties to the shorter plan), the official shape;
- with `export`, `sft.jsonl` and `dpo.jsonl` (`export`).
Every input is checked before anything is written.
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
from llm_agents.planning.export import dpo_rows, planner_prompt_text, rank_key, sft_rows
from llm_agents.planning.records import FirstFailure, PlanScore
from llm_agents.planning.steps import read_plan
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

ExportKind = Literal["sft", "dpo"]
JOURNAL = "episodes.jsonl"
SCORES = "scores.json"
BEST = "best.json"
EXPORT_FILES: dict[str, str] = {"sft": "sft.jsonl", "dpo": "dpo.jsonl"}
_SHOWN = 5


class ScoreConfig(BaseModel):
    """What `craftext-llm plan-score` does."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    plans: Path
    """An official plans file or a candidates file."""
    out: Path
    """The folder to write."""
    worlds: int = Field(4, ge=1)
    """Seeded worlds each plan is played in."""
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

    plans_sha256: str
    worlds: int
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


def _episode_key(text: str, candidate: int, world: int) -> str:
    return json.dumps([text, candidate, world], ensure_ascii=False)


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
            previous = _Settings.model_validate(json.loads(lines[0])["settings"])
        except (json.JSONDecodeError, KeyError, TypeError, ValidationError) as err:
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


def _check_exports(config: ScoreConfig, plans: dict[str, list[str]], texts: Sequence[str]) -> None:
    if "dpo" in config.export and not any(len(set(plans[t])) >= 2 for t in texts):
        raise UserError(
            "--export dpo pairs candidates of one text, and no scored text has two: score a "
            "candidates file (craftext-llm plan --candidates N)"
        )


def score_plans(
    config: ScoreConfig,
    *,
    progress: Callable[[int, int], Any] | None = None,
) -> ScoreSummary:
    """Score every plan (see the module); `progress(total, initial)` makes a progress bar."""
    from env import EnvConfig, shared_env
    from env.dataset import load_dataset as _load

    started = time.perf_counter()
    plans = load_candidates(config.plans)
    texts = _texts(config, plans)
    _check_exports(config, plans, list(texts))
    dataset = _load(config.dataset)
    settings = _Settings(
        plans_sha256=hashlib.sha256(config.plans.read_bytes()).hexdigest(),
        worlds=config.worlds,
        seed=config.seed,
        variant=config.variant,
        dataset=dataset.source.model_dump(mode="json"),
        skill_steps=config.skill_steps,
    )
    readings = {}
    episodes: list[PlanEpisode] = []
    for text, (goal, index) in texts.items():
        offer = skill_offer(config.variant, goal.difficulty)
        for candidate, plan in enumerate(plans[text]):
            steps = read_plan(parse_plan(plan)[0], offer)
            readings[(text, candidate)] = steps
            skills = tuple(
                (step.number, read_skill(skill, offer)) for step in steps for skill in step.skills
            )
            episodes += [
                PlanEpisode(_episode_key(text, candidate, world), goal, index, world, skills)
                for world in range(config.worlds)
            ]
    make_output_dir(config.out)
    journal = _Journal(config.out / JOURNAL, settings, config.restart)
    todo = [ep for ep in episodes if ep.key not in journal.done]
    bar = progress(len(episodes), len(episodes) - len(todo)) if progress else None

    def done(outcomes: list[EpisodeOutcome]) -> None:
        journal.add(outcomes)
        if bar is not None:
            bar.update(len(outcomes))

    try:
        if todo:
            env = shared_env(EnvConfig(variant=config.variant))
            play_plan_episodes(
                todo,
                env,
                variant=config.variant,
                seed=config.seed,
                batch_size=config.batch_size,
                on_done=done,
                skill_steps=config.skill_steps,
            )
    finally:
        if bar is not None:
            bar.close()
    scores = [
        _plan_score(text, candidate, plans[text][candidate], readings[(text, candidate)],
                    texts[text][0], [journal.done[_episode_key(text, candidate, w)]
                                     for w in range(config.worlds)])
        for text in texts
        for candidate in range(len(plans[text]))
    ]  # fmt: skip
    by_text: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        by_text[score.instruction].append(score)
    best = {text: min(group, key=rank_key) for text, group in by_text.items()}
    atomic_write_json(
        config.out / SCORES,
        {
            "settings": settings.model_dump(mode="json") | {"plans": str(config.plans)},
            "splits": split_summary(scores, best),
            "plans": [s.model_dump(mode="json") for s in scores],
        },
    )
    atomic_write_json(config.out / BEST, {text: score.plan for text, score in best.items()})
    exports = _write_exports(config, scores)
    return ScoreSummary(
        texts=len(texts),
        plans=len(scores),
        episodes=len(episodes),
        resumed=len(episodes) - len(todo),
        wall_s=round(time.perf_counter() - started, 3),
        scores=config.out / SCORES,
        best=config.out / BEST,
        exports=exports,
    )


def _plan_score(
    text: str,
    candidate: int,
    plan: str,
    steps: list[Any],
    goal: AnyGoal,
    outcomes: list[EpisodeOutcome],
) -> PlanScore:
    failures = Counter(
        (o.failed_step, o.failed_skill, o.reason or "") for o in outcomes if not o.success
    )
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
    )


def split_summary(
    scores: Sequence[PlanScore], best: dict[str, PlanScore]
) -> dict[str, dict[str, Any]]:
    """Per split: texts, plans, steps read and unread, and the success of each text's first
    candidate and of its best one, clustered by goal. The best is chosen on the worlds it is
    scored on, so its rate is optimistic as an estimate for new worlds."""
    groups: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        groups[score.split].append(score)
    summary = {}
    for split, group in sorted(groups.items()):
        first = [s for s in group if s.candidate == 0]
        chosen = [best[t] for t in dict.fromkeys(s.instruction for s in group)]
        summary[split] = {
            "texts": len(chosen),
            "plans": len(group),
            "steps_read": sum(s.read for s in group),
            "steps_unread": sum(s.unread for s in group),
            "first": _clustered(first).model_dump(mode="json"),
            "best": _clustered(chosen).model_dump(mode="json"),
        }
    return summary


def _clustered(scores: Sequence[PlanScore]) -> SuccessRate:
    return clustered_rate((s.goal_id, s.success.successes, s.success.episodes) for s in scores)


def _write_exports(config: ScoreConfig, scores: list[PlanScore]) -> dict[str, int]:
    if not config.export:
        return {}
    limits, variant, templates = _planner_settings(config.plans, config.variant)
    cache: dict[str, str] = {}

    def prompt(text: str) -> str:
        if text not in cache:
            cache[text] = planner_prompt_text(text, limits, variant, templates)
        return cache[text]

    written: dict[str, int] = {}
    for kind in config.export:
        rows = (
            sft_rows(scores, config.threshold, prompt)
            if kind == "sft"
            else dpo_rows(scores, config.margin, prompt)
        )
        atomic_write_text(
            config.out / EXPORT_FILES[kind],
            "".join(json.dumps(row, ensure_ascii=False) + "\n" for row in rows),
        )
        written[kind] = len(rows)
    return written


def _planner_settings(plans: Path, variant: Variant) -> tuple[PlanLimits, Variant, str | None]:
    """The limits, variant and templates folder the plans were asked with: from the sidecar
    `plan` writes beside them, else `plan`'s defaults and the scored variant."""
    sidecar = plans.with_name(f"{plans.stem}.meta.json")
    try:
        settings = json.loads(sidecar.read_text(encoding="utf-8"))["settings"]
        return (
            PlanLimits.model_validate(settings["limits"]),
            Variant(settings["variant"]),
            settings.get("templates_dir"),
        )
    except (OSError, ValueError, KeyError, TypeError, ValidationError):
        return PlanLimits(), variant, None
