"""The read / plan / act ladder: one model on one set of episodes, side by side.

    reads   grounding exact match   `ground`: the model reads each text as a typed goal
    plans   skills success          `eval --agent skills`: the model picks a skill per subgoal
    acts    zero-shot success       `eval --agent zero-shot --choice loglik`: a call per step
    guided  guided success          the model reads, the expert acts (a ceiling on planning)
    expert  expert success          the true goal, the expert acts (the ceiling)

Each rung is played (or resumed) per category with the library's runner, in this process, on
one compiled env; every rate has the 95% Wilson interval clustered by goal
(`run_data.metrics.clustered_rate`). Model calls per episode count the steps that asked the
model (a text, for `reads`); CPU seconds per episode are this process's CPU time while the
rung's runs played, loading the model and compiling included, over the episodes they played
(kept in `cpu.json`, so a resumed rung keeps its first measurement). Zero-shot, a call per step,
plays a subset by default (`--zero-shot-episodes`, spread over the categories), and the table
says so. Below the table, what the skills agent got wrong in each failed episode, from its
records (`judging.skill_errors`): the address of a failure between reading and acting.

    python benchmarks/ladder.py --model hf:qwen2.5-coder-0.5b
        [--categories one combo new_objects] [--limit N] [--zero-shot-episodes 16]
        [--max-steps 250] [--grounding-shots 4] [--rungs reads plans acts guided expert]
        [--dataset PATH] [--out runs/ladder-MODEL]

The dataset defaults to the official repository at 1c518ae when `../shared/data` holds its
archive (unpacked into the output folder), else the CLI's default. A rerun with the same
settings resumes each run and prints the table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks.official_clone import official_clone  # noqa: E402
from llm_agents.agents.registry import AGENTS  # noqa: E402
from llm_agents.run_data.metrics import CLUSTERED_LABEL, SuccessRate, clustered_rate  # noqa: E402

CPU_LEDGER = "cpu.json"
DEFAULT_CATEGORIES = ("one", "combo", "new_objects")


@dataclass(frozen=True)
class Rung:
    key: str
    label: str
    agent: str | None  # None: grounding (`ground`), not an episode
    uses_model: bool = True


RUNGS: tuple[Rung, ...] = (
    Rung("reads", "grounding exact match", None),
    Rung("plans", "skills success", "skills"),
    Rung("acts", "zero-shot success", "zero-shot"),
    Rung("guided", "guided success (ceiling)", "guided"),
    Rung("expert", "expert success (ceiling)", "expert", uses_model=False),
)
RUNG_KEYS = tuple(rung.key for rung in RUNGS)


@dataclass(frozen=True)
class LadderSettings:
    """One ladder: the model, the episodes and where the runs go."""

    model: str
    out: Path
    categories: tuple[str, ...] = DEFAULT_CATEGORIES
    limit: int | None = None  # episodes (texts) per category; None: all
    zero_shot_episodes: int = 16  # over all categories; 0: the full set
    max_steps: int = 250
    grounding_shots: int = 4
    max_tokens: int = 64
    rungs: tuple[str, ...] = RUNG_KEYS
    dataset: str | None = None
    batch_size: int = 8
    extra: dict[str, Any] = field(default_factory=dict)  # settings every run shares

    def per_category_limit(self, rung: Rung) -> dict[str, int | None]:
        """The episodes each category's run of `rung` plays (None: all): the zero-shot subset
        is spread evenly over the categories (the first ones get the remainder; a category
        left 0 is not played)."""
        limits: dict[str, int | None] = dict.fromkeys(self.categories, self.limit)
        if rung.key == "acts" and self.zero_shot_episodes:
            share, extra = divmod(self.zero_shot_episodes, len(self.categories))
            for index, category in enumerate(self.categories):
                subset = share + (index < extra)
                limits[category] = subset if self.limit is None else min(subset, self.limit)
        return limits


def taken(rung: Rung) -> bool:
    """A rung is played only when its agent is registered."""
    return rung.agent is None or rung.agent in AGENTS


def run_dir(settings: LadderSettings, rung: Rung, category: str) -> Path:
    return settings.out / f"{rung.key}-{category}"


# ------------------------------------------------------------------------------------ running


def _common(settings: LadderSettings, category: str, limit: int | None) -> dict[str, Any]:
    common: dict[str, Any] = {
        "variant": "classic",
        "difficulty": "easy",
        "categories": [category],
        "paraphrases": False,
        **settings.extra,
    }
    if settings.dataset:
        common["dataset"] = settings.dataset
    if limit is not None:
        common["limit"] = limit
    return common


def _model_settings(settings: LadderSettings, rung: Rung) -> dict[str, Any]:
    if not rung.uses_model:
        return {}
    chosen: dict[str, Any] = {
        "model": settings.model,
        "generation": {"max_tokens": settings.max_tokens},
    }
    if rung.key in ("reads", "guided"):
        chosen["grounding_shots"] = settings.grounding_shots
    if rung.key == "acts":
        # Scored action names: a small model's free text is mostly no action at all.
        chosen["choice"] = "loglik"
    return chosen


def rung_configs(settings: LadderSettings, rung: Rung) -> list[tuple[str, Any]]:
    """(category, config) of each run of `rung`, in category order."""
    from llm_agents.evaluation.config import build_config, build_settings
    from llm_agents.evaluation.grounding_run import GroundConfig

    configs: list[tuple[str, Any]] = []
    for category, limit in settings.per_category_limit(rung).items():
        if limit == 0:
            continue
        chosen = {
            **_common(settings, category, limit),
            **_model_settings(settings, rung),
            "output_dir": str(run_dir(settings, rung, category)),
        }
        if rung.agent is None:
            configs.append((category, build_settings(GroundConfig, chosen)))
        else:
            chosen |= {
                "agent": rung.agent,
                "max_steps": settings.max_steps,
                "batch_size": settings.batch_size,
            }
            if not rung.uses_model:
                chosen["model"] = "mock:"
            configs.append((category, build_config(chosen)))
    return configs


def _items_done(rung: Rung, out: Path) -> int:
    from llm_agents.evaluation.grounding_run import read_groundings
    from llm_agents.run_data.store import read_episodes

    if rung.agent is None:
        return len(read_groundings(out)) if (out / "groundings.jsonl").exists() else 0
    path = out / "episodes.jsonl"
    return len(read_episodes(path)) if path.exists() else 0


def _read_ledger(out: Path) -> dict[str, dict[str, float]]:
    path = out / CPU_LEDGER
    return json.loads(path.read_text()) if path.exists() else {}


def play_rung(settings: LadderSettings, rung: Rung, env: Any = None) -> Any:
    """Run (or resume) each category's run of `rung` with one model; record the CPU time the
    rung took and the episodes it played in the ledger, also when it is stopped. Returns the
    env it played on."""
    from env import CrafTextEnv
    from llm_agents.evaluation.grounding_run import execute_grounding, prepare_grounding
    from llm_agents.evaluation.runner import open_model, run_eval

    configs = rung_configs(settings, rung)
    outs = [Path(config.output_dir) for _, config in configs]
    before = [_items_done(rung, out) for out in outs]
    started_cpu = time.process_time()
    # Recorded however the rung ends: a stopped rung's CPU time belongs to the episodes it
    # played, which a resumed rung will not play again.
    try:
        with open_model(configs[0][1]) as model:
            for _, config in configs:
                if rung.agent is None:
                    execute_grounding(prepare_grounding(config), model)
                else:
                    if env is None:
                        env = CrafTextEnv(config.env_config())
                    run_eval(config, model, env=env)
    finally:
        played = sum(_items_done(rung, out) - done for out, done in zip(outs, before, strict=True))
        if played:
            settings.out.mkdir(parents=True, exist_ok=True)
            ledger = _read_ledger(settings.out)
            entry = ledger.setdefault(rung.key, {"cpu_s": 0.0, "items": 0})
            entry["cpu_s"] += time.process_time() - started_cpu
            entry["items"] += played
            (settings.out / CPU_LEDGER).write_text(json.dumps(ledger, indent=1, sort_keys=True))
    return env


# ---------------------------------------------------------------------------------- the table


@dataclass(frozen=True)
class LadderRow:
    """One rung as read from its runs."""

    rung: Rung
    skipped: str | None = None  # why the rung has no runs
    rate: SuccessRate | None = None
    by_category: dict[str, SuccessRate] = field(default_factory=dict)
    calls_per_item: float | None = None
    cpu_s_per_item: float | None = None
    subset: dict[str, int] = field(default_factory=dict)  # category -> items, when limited


def episode_calls(episode: Any, steps: Iterable[Any]) -> int:
    """The model calls an episode made: its own count when the agent records one, else the
    steps that asked the model (an agent acting without one, the expert and guided once it has
    read, records the digest of no messages at all), follow-up requests included; a reading
    that left the episode unstarted (an invalid goal) is a call no step records."""
    from llm_agents.agents.types import NO_PROMPT_HASH

    recorded = getattr(episode, "model_calls", None)
    if recorded is not None:
        return int(recorded)
    calls = sum(1 + step.followups for step in steps if step.prompt_hash != NO_PROMPT_HASH)
    return calls if calls or episode.grounding is None else 1


def _rate(outcomes: Sequence[tuple[tuple[str, str], bool]]) -> SuccessRate:
    return clustered_rate((goal, int(success), 1) for goal, success in outcomes)


def ladder_row(settings: LadderSettings, rung: Rung) -> LadderRow:
    """Read `rung`'s runs into a row; a rung with no agent or no runs yet says why."""
    from llm_agents.evaluation.grounding_run import read_groundings
    from llm_agents.run_data.metrics import goal_cluster
    from llm_agents.run_data.store import read_episodes, read_steps

    if not taken(rung):
        return LadderRow(rung, skipped=f"agent `{rung.agent}` is not registered")
    outcomes: dict[str, list[tuple[tuple[str, str], bool]]] = {}
    calls = 0
    for category in settings.categories:
        out = run_dir(settings, rung, category)
        if rung.agent is None:
            if not (out / "groundings.jsonl").exists():
                continue
            records = read_groundings(out)
            outcomes[category] = [((r.category, r.goal_id), r.correct) for r in records]
            calls += len(records)
        else:
            if not (out / "episodes.jsonl").exists():
                continue
            episodes = read_episodes(out / "episodes.jsonl")
            outcomes[category] = [(goal_cluster(e), e.success) for e in episodes]
            # Runs recorded before episodes counted their own model calls: count the steps.
            steps: dict[str, list[Any]] = {
                e.episode_id: [] for e in episodes if getattr(e, "model_calls", None) is None
            }
            if steps and (out / "steps.jsonl").exists():
                for step in read_steps(out / "steps.jsonl", steps.keys()):
                    steps[step.episode_id].append(step)
            calls += sum(episode_calls(e, steps.get(e.episode_id, [])) for e in episodes)
    items = [outcome for rows in outcomes.values() for outcome in rows]
    if not items:
        return LadderRow(rung, skipped="not run yet")
    ledger = _read_ledger(settings.out).get(rung.key)
    limited = rung.key == "acts" and settings.zero_shot_episodes > 0
    return LadderRow(
        rung,
        rate=_rate(items),
        by_category={category: _rate(rows) for category, rows in outcomes.items() if rows},
        calls_per_item=calls / len(items),
        cpu_s_per_item=ledger["cpu_s"] / ledger["items"] if ledger and ledger["items"] else None,
        subset={c: len(rows) for c, rows in outcomes.items()} if limited else {},
    )


def format_ladder(settings: LadderSettings, rows: Sequence[LadderRow]) -> str:
    """The ladder as a text table, one rung a line, the categories side by side."""
    limit = f", the first {settings.limit} per category" if settings.limit else ""
    lines = [
        f"Ladder: {settings.model}, EASY {' '.join(settings.categories)} (original instructions, "
        f"one world each{limit}), Classic, {settings.max_steps} steps",
        f"{'rung':<7} {'measure':<25} {'n':>4} {'g':>3} {'rate':>5} {'interval':>12} "
        f"{'calls/ep':>8} {'CPU s/ep':>8}  " + "  ".join(f"{c:>11}" for c in settings.categories),
    ]
    notes = []
    for row in rows:
        head = f"{row.rung.key:<7} {row.rung.label:<25}"
        if row.rate is None:
            lines.append(f"{head} skipped: {row.skipped}")
            continue
        rate = row.rate
        mark = "*" if row.subset else " "
        calls = "-" if row.calls_per_item is None else f"{row.calls_per_item:.1f}"
        cpu = "-" if row.cpu_s_per_item is None else f"{row.cpu_s_per_item:.1f}"
        cells = "  ".join(
            f"{row.by_category[c].rate:>11.2f}" if c in row.by_category else f"{'-':>11}"
            for c in settings.categories
        )
        lines.append(
            f"{head} {rate.episodes:>3}{mark} {rate.clusters or '-':>3} {rate.rate:>5.2f} "
            f"{f'[{rate.low:.2f}, {rate.high:.2f}]':>12} {calls:>8} {cpu:>8}  {cells}"
        )
        if row.subset:
            spread = ", ".join(f"{n} {c}" for c, n in row.subset.items())
            notes.append(
                f"* {row.rung.key}: a subset of {rate.episodes} "
                f"episode{'s' if rate.episodes != 1 else ''} ({spread}), "
                "a model call per step makes the full set too slow"
            )
    lines += notes
    lines.append(
        f"n = episodes (texts, for reads); g = goals. Intervals: {CLUSTERED_LABEL}. "
        "CPU s/ep: this process's CPU time over the rung's episodes, model loading and "
        "compiling included."
    )
    return "\n".join(lines)


@dataclass(frozen=True)
class SkillErrors:
    """What the `plans` episodes got wrong, and what stopping to ask saved."""

    counts: dict[str, int]  # failed episodes per label of `judging.skill_errors`
    stopped: int  # episodes whose agent stopped asking (invalid answers, stuck)
    calls_saved: int  # the model calls those stops saved, one per step left


def skill_errors(settings: LadderSettings) -> SkillErrors | None:
    """The `plans` episodes' errors (`judging.skill_errors`); None before any ran."""
    from env.dataset import load_dataset
    from env.goals import AnyGoal, run_category
    from env.variant import Variant
    from llm_agents.judging.skill_errors import (
        model_calls_saved,
        skill_error_table,
        stopped_asking,
    )
    from llm_agents.run_data.store import read_episodes

    [plans] = [rung for rung in RUNGS if rung.key == "plans"]
    episodes = [
        episode
        for category in settings.categories
        if (run_dir(settings, plans, category) / "episodes.jsonl").exists()
        for episode in read_episodes(run_dir(settings, plans, category) / "episodes.jsonl")
    ]
    if not episodes:
        return None
    instructions = load_dataset(settings.dataset).instructions(
        settings.categories, include_paraphrases=False, difficulty="easy"
    )
    goals: dict[tuple[str, str], AnyGoal] = {
        (run_category(i.goal), i.goal.id): i.goal for i in instructions
    }
    table = skill_error_table(episodes, goals, Variant.CLASSIC, "easy")
    return SkillErrors(
        counts={str(label): count for label, count in table.items()},
        stopped=sum(stopped_asking(episode) for episode in episodes),
        calls_saved=sum(model_calls_saved(episode) for episode in episodes),
    )


def format_skill_errors(errors: SkillErrors) -> str:
    from llm_agents.judging.skill_errors import SKILL_ERROR_TITLES

    failed = sum(errors.counts.values())
    lines = [f"What the skills agent got wrong ({failed} failed episodes):"]
    lines += [
        f"  {label:<22} {count:>4}  {SKILL_ERROR_TITLES[label]}"
        for label, count in errors.counts.items()
    ]
    lines.append(
        f"The agent stopped asking in {errors.stopped} episode"
        f"{'s' if errors.stopped != 1 else ''}: {errors.calls_saved} model calls saved "
        "(one per step left)."
    )
    return "\n".join(lines)


def ladder(settings: LadderSettings, *, play: bool = True) -> str:
    """Run or resume every chosen rung (when `play`), then the table of all of them."""
    chosen = [rung for rung in RUNGS if rung.key in settings.rungs]
    env = None
    if play:
        for rung in chosen:
            if taken(rung):
                print(f"ladder: {rung.key} ({rung.label})", file=sys.stderr)
                env = play_rung(settings, rung, env)
    table = format_ladder(settings, [ladder_row(settings, rung) for rung in chosen])
    errors = skill_errors(settings) if "plans" in settings.rungs else None
    return table if errors is None else f"{table}\n\n{format_skill_errors(errors)}"


# ------------------------------------------------------------------------------------- command


def _dataset(given: str | None, out: Path) -> str | None:
    return given or official_clone(out)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="e.g. hf:qwen2.5-coder-0.5b")
    parser.add_argument("--categories", nargs="+", default=list(DEFAULT_CATEGORIES))
    parser.add_argument("--limit", type=int, help="episodes (texts) per category; unset: all")
    parser.add_argument(
        "--zero-shot-episodes",
        type=int,
        default=16,
        help="zero-shot plays this many episodes, spread over the categories (0: all of them)",
    )
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--grounding-shots", type=int, default=4, help="reads and guided")
    parser.add_argument("--max-tokens", type=int, default=64)
    parser.add_argument("--rungs", nargs="+", default=list(RUNG_KEYS), choices=RUNG_KEYS)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--dataset")
    parser.add_argument("--out", help="default: runs/ladder-<model name>")
    parser.add_argument("--no-play", action="store_true", help="only print what the runs hold")
    args = parser.parse_args(argv)
    if args.limit is not None and args.limit < 1:
        parser.error("--limit must be at least 1")
    if args.zero_shot_episodes < 0:
        parser.error("--zero-shot-episodes must be 0 (all) or more")

    from env.errors import UserError

    label = args.model.split(":", 1)[-1].rstrip("/").rsplit("/", 1)[-1]
    out = Path(args.out or REPO / "runs" / f"ladder-{label}")
    settings = LadderSettings(
        model=args.model,
        out=out,
        categories=tuple(args.categories),
        limit=args.limit,
        zero_shot_episodes=args.zero_shot_episodes,
        max_steps=args.max_steps,
        grounding_shots=args.grounding_shots,
        max_tokens=args.max_tokens,
        rungs=tuple(args.rungs),
        dataset=_dataset(args.dataset, out),
        batch_size=args.batch_size,
    )
    try:
        print(ladder(settings, play=not args.no_play))
    except UserError as error:
        sys.exit(f"ladder: error: {error}")


if __name__ == "__main__":
    main()
