"""The static HTML report of a run: a run page and one page per episode with its replay.

`build_view` writes `RUN_DIR/report/index.html`, and `RUN_DIR/report/episodes/` a page and a
frame sheet (PNG) per episode. Styles and scripts are inline and links relative, so the report
folder opens from disk, offline, with no server.
"""

from __future__ import annotations

import functools
import logging
import os
import random
import shutil
import statistics
import time
import uuid
from collections import Counter, deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jinja2
import markupsafe
import numpy as np

from env.errors import UserError
from llm_agents.evaluation.config import EvalConfig
from llm_agents.judging.comparison import (
    ComparedRun,
    compared_run,
    comparison_columns,
    comparison_notes,
)
from llm_agents.judging.goal_flags import DEFAULT_WORLDS, run_goal_status
from llm_agents.judging.published import PUBLISHED_KIND, paper_differences, published_for
from llm_agents.judging.report_tables import (
    CATEGORY_LABELS,
    GoalStatusTables,
    chart_categories,
    goal_status_tables,
    our_rate,
    published_cell,
    rates_legend,
    scenario_rows,
    table_columns,
)
from llm_agents.judging.rescoring import model_name_of, rescore, run_scores, run_summary
from llm_agents.run_data.metrics import DOMINANT_SHARE, action_histogram, goal_key
from llm_agents.run_data.records import StepRecord
from llm_agents.viewer.frames import SpriteSheet, export_animation, sprite_sheet
from llm_agents.viewer.goals import block_words, rendering_of
from llm_agents.viewer.run import EpisodeView, LoadedRun, load_run

logger = logging.getLogger(__name__)

REPORT_DIR = "report"
EPISODES_DIR = "episodes"
#: Width in CSS pixels the replay frame is enlarged to, about (whole multiples of the frame).
_FRAME_DISPLAY_HEIGHT = 420


@dataclass
class ReplayStatus:
    """How an episode's replay went."""

    state: str
    """`reproduced`, `mismatch` or `not replayed`."""
    problems: list[str] = field(default_factory=list)
    """What differs from the record (mismatch), or why there is no replay."""
    frames: int = 0
    """Frames the replay drew (actions + 1); 0 without a replay."""
    checker: dict[str, Any] | None = None
    """What the goal's checker read over the replay (`_checker_data`); None without one."""


@dataclass
class ViewOutcome:
    """What `build_view` wrote and found."""

    index: Path
    statuses: dict[str, ReplayStatus]
    render_seconds: float
    """Wall time of replaying, rendering and encoding the episodes and writing their pages (the
    run page and reading the run excluded)."""
    frames: int
    """Frames rendered."""
    size_bytes: int
    """Total size of the report's files."""
    listed: int = 0
    """Episodes listed on the run page without a page of their own (not in the sample)."""

    @property
    def mismatches(self) -> dict[str, ReplayStatus]:
        return {key: s for key, s in self.statuses.items() if s.state == "mismatch"}


@dataclass(frozen=True)
class Selection:
    """Which episodes of a run get a page: those matching every given filter, or a seeded
    sample of them; the rest are listed on the run page only."""

    sample: int | None = None
    """How many episodes to render, drawn at random (seeded) from those matching; None: all."""
    seed: int = 0
    categories: tuple[str, ...] = ()
    classes: tuple[str, ...] = ()
    outcomes: tuple[str, ...] = ()
    episode: str | None = None
    """One episode (id or index) to render alone."""

    def pick(self, run: LoadedRun) -> list[EpisodeView]:
        """The episodes to render, in schedule order; a `UserError` when the selection cannot be
        met (an episode not in the run, a sample larger than what matches)."""
        if self.episode is not None:
            return [run.find(self.episode)]
        matching = [
            view
            for view in run.episodes
            if (not self.categories or view.record.category in self.categories)
            and (not self.classes or view.record.scenario_class in self.classes)
            and (not self.outcomes or view.record.termination in self.outcomes)
        ]
        filtered = self.categories or self.classes or self.outcomes
        if not matching:
            raise UserError(f"no episode of {run.path} matches the filters given")
        if self.sample is None:
            return matching
        if self.sample < 1:
            raise UserError(f"--sample must be at least 1, not {self.sample}")
        if self.sample > len(matching):
            raise UserError(
                f"--sample {self.sample} is larger than the {len(matching)} episodes of "
                f"{run.path}{' that match the filters' if filtered else ''}"
            )
        chosen = random.Random(self.seed).sample(range(len(matching)), self.sample)
        return [matching[i] for i in sorted(chosen)]


def build_view(
    run_dir: str | Path,
    *,
    progress: bool = True,
    batch_size: int = 16,
    compare: Sequence[str | Path] = (),
    goal_status: bool = False,
    worlds: int = DEFAULT_WORLDS,
    selection: Selection | None = None,
) -> ViewOutcome:
    """Replay the episodes of `run_dir` (all, or `selection`'s) and write its HTML report;
    returns where and how it went.

    A replay that does not reproduce its record is logged as a warning and flagged on its page
    and on the run page. The runs in `compare` (e.g. the expert's) get a row each beside the
    run's in the results table, as `report --compare` prints them. With `goal_status`, the run
    page also shows the tables without trivial and impossible goals (`report --goal-status`).
    The report is written into a temporary folder beside the run's and moved into place once
    complete: a failure leaves the previous report (or none), never half of a new one.
    """
    run = load_run(run_dir)
    rendered = (selection or Selection()).pick(run)
    for view in rendered:
        if view.goal is not None:
            rendering_of(view.goal.kind)
    # Read before the long rendering, so a wrong path fails at once.
    compared = [compared_run(other) for other in compare]
    flagged = _goal_status(run, worlds) if goal_status else None
    final = run.path / REPORT_DIR
    out = run.path / f".{REPORT_DIR}.{os.getpid()}.{uuid.uuid4().hex}.tmp"
    pages = out / EPISODES_DIR
    try:
        pages.mkdir(parents=True)
    except OSError as exc:
        raise UserError(f"cannot create {pages}: {exc.strerror}") from exc
    try:
        outcome = _write_report(run, rendered, out, progress, batch_size, compared, flagged)
        _move_into_place(out, final)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    outcome.index = final / outcome.index.relative_to(out)
    return outcome


def _move_into_place(built: Path, final: Path) -> None:
    old = final.with_name(f"{built.name}.old")
    try:
        if final.exists():
            final.rename(old)
        built.rename(final)
    except OSError as exc:
        raise UserError(f"cannot move the report into {final}: {exc.strerror}") from exc
    shutil.rmtree(old, ignore_errors=True)


def _write_report(
    run: LoadedRun,
    rendered: list[EpisodeView],
    out: Path,
    progress: bool,
    batch_size: int,
    compared: Sequence[ComparedRun],
    flagged: GoalStatusTables | None,
) -> ViewOutcome:
    pages = out / EPISODES_DIR
    templates = _templates()
    neighbours = _neighbours(rendered)
    statuses: dict[str, ReplayStatus] = {}
    frames = 0
    started = time.perf_counter()
    render_seconds = 0.0
    bar = _progress(progress, len(rendered))
    variant = EvalConfig.recorded(run.config).env_config().variant
    try:
        for view, sheet, status in _replays(run, rendered, batch_size, bar):
            frames += status.frames
            render_seconds = time.perf_counter() - started
            statuses[view.record.episode_id] = status
            if sheet is not None:
                _write_bytes(pages / view.sheet, sheet.png)
            _write(
                pages / view.page,
                templates.get_template("episode.html.j2").render(
                    **_episode_context(run, view, sheet, status, neighbours, variant)
                ),
            )
    finally:
        if bar is not None:
            bar.close()
    index = out / "index.html"
    _write(
        index,
        templates.get_template("index.html.j2").render(
            **_run_context(run, statuses, compared),
            goal_status=flagged,
            **_scores_context(run, compared),
        ),
    )
    size = sum(path.stat().st_size for path in out.rglob("*") if path.is_file())
    return ViewOutcome(
        index=index,
        statuses=statuses,
        render_seconds=render_seconds,
        frames=frames,
        size_bytes=size,
        listed=len(run.episodes) - len(rendered),
    )


def export_episode(run_dir: str | Path, episode: str, path: str | Path) -> ReplayStatus:
    """Replay one episode of `run_dir` and write it as an animated GIF (or MP4) at `path`."""
    run = load_run(run_dir)
    view = run.find(episode)
    if view.unreplayable:
        raise UserError(f"episode {view.record.episode_id} cannot be replayed: {view.unreplayable}")
    replayer = _replayer(run, batch_size=1)
    replay = next(iter(replayer.replay([_replay_input(view, replayer.env.variant)])))
    export_animation(replay.frames, Path(path))
    return _status(view, replay)


def _replays(
    run: LoadedRun, rendered: list[EpisodeView], batch_size: int, bar: Any
) -> Iterator[tuple[EpisodeView, SpriteSheet | None, ReplayStatus]]:
    for view in rendered:
        if view.unreplayable:
            if bar is not None:
                bar.update(1)
            yield view, None, ReplayStatus("not replayed", [view.unreplayable])
    playable = [view for view in rendered if not view.unreplayable]
    if not playable:
        return
    # Episodes of similar length share a batch, so little of a batch is padding.
    playable.sort(key=lambda view: view.record.steps)
    replayer = _replayer(run, batch_size=batch_size)
    replays = replayer.replay([_replay_input(view, replayer.env.variant) for view in playable])
    # Sheets are encoded on worker threads (Pillow lets go of the GIL while it quantizes and
    # compresses), in order, a batch or so ahead of the pages written from them.
    encoding: deque[tuple[EpisodeView, ReplayStatus, Future[SpriteSheet]]] = deque()
    with ThreadPoolExecutor(2, thread_name_prefix="encode") as pool:
        for view, replay in zip(playable, replays, strict=True):
            status = _status(view, replay)
            status.checker = _checker_data(view, replay, replayer.env.variant)
            if status.state == "mismatch":
                logger.warning(
                    "the replay of episode %s does not reproduce its record: %s",
                    view.record.episode_id,
                    "; ".join(status.problems),
                )
            encoding.append((view, status, pool.submit(sprite_sheet, replay.frames)))
            if len(encoding) > batch_size:
                yield _encoded(*encoding.popleft(), bar)
        while encoding:
            yield _encoded(*encoding.popleft(), bar)


def _encoded(
    view: EpisodeView, status: ReplayStatus, sheet: Future[SpriteSheet], bar: Any
) -> tuple[EpisodeView, SpriteSheet, ReplayStatus]:
    done = sheet.result()
    if bar is not None:
        bar.update(1)
    return view, done, status


def _replayer(run: LoadedRun, *, batch_size: int) -> Any:
    env_config = EvalConfig.recorded(run.config).env_config()
    return _compiled_replayer(env_config.model_dump_json(), batch_size)


# Tracing and compiling the replay costs seconds: a process that views several runs (tests,
# benchmarks, a notebook) does it once per env.
@functools.cache
def _compiled_replayer(env_config_json: str, batch_size: int) -> Any:
    from env import EnvConfig, shared_env
    from env.replay import Replayer

    return Replayer(
        shared_env(EnvConfig.model_validate_json(env_config_json)), batch_size=batch_size
    )


def _replay_input(view: EpisodeView, variant: Any) -> Any:
    from env.replay import ReplayInput
    from env.scenario_tasks import encode_goals

    assert view.goal is not None
    task = encode_goals([view.goal], variant)
    return ReplayInput(
        reset_key=view.reset_key(),
        required=task.required[0],
        forbidden=task.forbidden[0],
        actions=[step.action_id for step in view.steps],
        kind=int(task.kind[0]),
        params=tuple(int(value) for value in task.params[0]),
    )


def _checker_data(view: EpisodeView, replay: Any, variant: Any) -> dict[str, Any]:
    """What the goal's checker read over the replay: the player's cell on every frame, the
    tracked counts (conditional placing), and its marks on the last map it read."""
    from env.frames import VIEW_CELLS
    from env.replay import BLOCK_SIZES

    assert view.goal is not None
    rendering = rendering_of(view.goal.kind)
    trace = replay.trace
    last = replay.ended_at if replay.ended_at is not None else len(trace) - 1
    position = (int(trace[last, 0]), int(trace[last, 1]))
    rows, columns = VIEW_CELLS[variant]
    data: dict[str, Any] = {
        "positions": trace[:, :2].tolist(),
        "view": {"rows": rows, "columns": columns, "block": BLOCK_SIZES[variant]},
        "last": last,
    }
    if rendering.chart:
        data["held"] = trace[:, 2].tolist()
        data["standing"] = trace[:, 3].tolist()
    marks = rendering.marks(view.goal, replay.end_map, position, variant)
    if marks is not None:
        data["marks"] = {
            "region": list(marks.region),
            "met": marks.met,
            "blocks": [list(cell) for cell in marks.blocks],
            "completed": [list(cell) for cell in marks.completed],
            "references": [list(cell) for cell in marks.references],
            "targets": [list(cell) for cell in marks.targets],
            "notes": list(marks.notes),
        }
        data["minimap"] = _minimap(marks, replay.end_map, position, variant.block_names)
    return data


#: Ground colours of the small map, by a word of the block's name (the goal's blocks are drawn
#: over them); a block matching none is light grey.
_GROUND = {
    "WATER": "#9cc3e6",
    "GRASS": "#b7dfb0",
    "TREE": "#6fa86a",
    "SAND": "#eee3b8",
    "PATH": "#d9cbb0",
    "LAVA": "#f2a36b",
    "STONE": "#b8b8b8",
    "DARKNESS": "#57606a",
}


def _ground(name: str) -> str:
    return next((colour for word, colour in _GROUND.items() if word in name), "#d8dee4")


def _minimap(
    marks: Any, board: np.ndarray, position: tuple[int, int], block_names: Sequence[str]
) -> dict[str, Any]:
    """The checker's region for the small map: its size, the cell size in pixels, and its cells
    as SVG squares with their ground colour, classes and a title naming the block."""
    shape = board.shape
    row0, column0, rows, columns = marks.region
    # Smaller cells for a tall region, so the map fits beside the frames.
    size = 9 if rows > 15 else 14
    classes = {
        **{tuple(cell): "block" for cell in marks.blocks},
        **{tuple(cell): "reference" for cell in marks.references},
    }
    targets = {tuple(cell) for cell in marks.targets}
    completed = {tuple(cell) for cell in marks.completed}
    # Written here, not looped over in the template: a region has hundreds of cells, and the
    # template's loop over them took most of a page's rendering.
    squares = []
    for r in range(row0, row0 + rows):
        for c in range(column0, column0 + columns):
            inside = 0 <= r < shape[0] and 0 <= c < shape[1]
            names = [classes.get((r, c), "ground") if inside else "outside"]
            if (r, c) in targets:
                names.append("target")
            if (r, c) in completed:
                names.append("completed")
            if (r, c) == position:
                names.append("player")
            name = block_names[int(board[r, c])] if inside else "outside the map"
            fill = _ground(name) if inside else "#ffffff"
            title = markupsafe.escape(f"row {r}, column {c}: {name.lower().replace('_', ' ')}")
            squares.append(
                f'<rect x="{1 + (c - column0) * size}" y="{1 + (r - row0) * size}" '
                f'width="{size - 1}" height="{size - 1}" class="{" ".join(names)}" '
                f'style="fill: {fill}"><title>{title}</title></rect>'
            )
    return {
        "rows": rows,
        "columns": columns,
        "cell": size,
        "squares": markupsafe.Markup("".join(squares)),
        "origin": [row0, column0],
    }


def _status(view: EpisodeView, replay: Any) -> ReplayStatus:
    record = view.record
    problems = []
    if replay.ended_at != record.steps:
        ended = "never ended" if replay.ended_at is None else f"ended after {replay.ended_at}"
        problems.append(f"the replay {ended} of the recorded {record.steps} actions")
    if replay.termination != record.termination:
        problems.append(f"termination {replay.termination!r}, recorded {record.termination!r}")
    if replay.achievements != record.achievements:
        problems.append(
            f"achievements {replay.achievements or 'none'}, recorded {record.achievements or 'none'}"
        )
    if not np.isclose(replay.episode_return, record.episode_return, atol=1e-4):
        problems.append(f"return {replay.episode_return:.4f}, recorded {record.episode_return:.4f}")
    return ReplayStatus(
        "mismatch" if problems else "reproduced", problems, frames=len(replay.frames)
    )


def _progress(enabled: bool, total: int) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="episode", desc="rendering", dynamic_ncols=True)


def _templates() -> jinja2.Environment:
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("llm_agents.viewer", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    environment.filters["rate"] = lambda value: "-" if value is None else f"{value:.2f}"
    environment.filters["breakable"] = _breakable
    return environment


def _breakable(text: str) -> markupsafe.Markup:
    """`text`, escaped, with a line-break opportunity after each `/` and `_`: episode ids and goal
    names are long words that would otherwise widen their table past the page."""
    escaped = str(markupsafe.escape(text))
    return markupsafe.Markup(escaped.replace("/", "/<wbr>").replace("_", "_<wbr>"))


def _write(path: Path, text: str) -> None:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror}") from exc


def _write_bytes(path: Path, data: bytes) -> None:
    try:
        path.write_bytes(data)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror}") from exc


def _neighbours(episodes: list[EpisodeView]) -> dict[str, tuple[str | None, str | None]]:
    pages = [view.page for view in episodes]
    return {
        view.record.episode_id: (
            pages[i - 1] if i > 0 else None,
            pages[i + 1] if i + 1 < len(pages) else None,
        )
        for i, view in enumerate(episodes)
    }


# ---------------------------------------------------------------- run page


def _run_context(
    run: LoadedRun, statuses: dict[str, ReplayStatus], compared: Sequence[ComparedRun] = ()
) -> dict[str, Any]:
    records = [view.record for view in run.episodes]
    results = run.results
    actions = (
        {
            view.record.episode_id: Counter(s.action_name for s in view.steps)
            for view in run.episodes
        }
        if run.has_steps
        else None
    )
    summary = run_summary(results, records, run.run.rule, actions)
    model = model_name_of(results)
    partial = results.status != "complete"
    differences = paper_differences(results, run.run.rule)
    difficulty = run.run.difficulty
    published = published_for(difficulty)
    ours = ComparedRun(
        f"{model} (this run{', partial' if partial else ''})", summary, results, records
    )
    # With runs to compare, the columns are the comparison's (`report --compare`'s).
    columns = (
        comparison_columns([ours, *compared]) if compared else table_columns(summary, difficulty)
    )
    table = {
        "header": ["Model", *(CATEGORY_LABELS[column] for column in columns)],
        "ours": ours.cells(columns),
        "compared": [other.cells(columns) for other in compared],
        "compare_notes": comparison_notes([ours, *compared]) if compared else [],
        "published": [
            [f"{result.model} (published)", *(published_cell(result, c) for c in columns)]
            for result in published
        ],
        "published_kind": PUBLISHED_KIND[difficulty],
        "differences": differences,
        # The paper's Table 2 layout: scenario class x goal set (Medium and Hard runs).
        "scenarios": scenario_rows(summary, difficulty) if difficulty != "easy" else [],
    }
    rates = {
        category: our_rate(summary, category) for category in chart_categories(summary, difficulty)
    }
    categories = [
        {
            "label": CATEGORY_LABELS[category],
            "ours": rate,
            "published": [(result.model, result.rate(category)) for result in published],
        }
        for category, rate in rates.items()
    ]
    # The y range of report_chart.plot_success: the tallest interval or published bar, plus headroom.
    tallest = max(
        [rate.high for rate in rates.values() if rate is not None]
        + [rate for result in published for rate in result.rates.values()]
        + [0.0]
    )
    goals = sorted(summary.by_goal.items(), key=lambda item: (-item[1].rate, item[0]))
    steps_total = sum(record.steps for record in records)
    errors = sum(len(view.errors) for view in run.episodes)
    latencies = sorted(run.latencies)
    states = Counter(status.state for status in statuses.values())
    listed = ReplayStatus("listed only", ["not in this report's sample (see `view --sample`)"])
    everyone = [(view, statuses.get(view.record.episode_id, listed)) for view in run.episodes]
    # Goal ids are long (MAKE_STONE_SWORD_AND_COLLECT_SAPLING_NO_MAKE_IRON_SWORD): the chart's
    # label column is as wide as the longest, at 8 px a character of its 11 px font (upper-case
    # letters measure about 7.5 in Chromium's sans-serif).
    label_width = 16 + 8 * max((len(name) for name in summary.by_goal), default=10)
    return {
        "title": f"{model} on CrafText",
        "model": model,
        "partial": partial,
        "results": results,
        "summary": summary,
        "table": table,
        "categories": categories,
        "chart_top": min(1.0, tallest * 1.25 + 0.02),
        "goals": goals,
        "published_models": [result.model for result in published],
        "steps_total": steps_total,
        "invalid_total": sum(record.invalid_actions for record in records),
        "prompt_tokens": sum(record.prompt_tokens for record in records),
        "completion_tokens": sum(record.completion_tokens for record in records),
        "parse_stages": run.parse_stages,
        "has_steps": run.has_steps,
        "errors": errors,
        "error_episodes": sum(1 for view in run.episodes if view.errors),
        "latency": _latency(latencies),
        "config": _flatten(results.config),
        "replay_states": {
            state: states.get(state, 0) for state in ("reproduced", "mismatch", "not replayed")
        }
        | ({"listed only": len(everyone) - len(statuses)} if len(everyone) > len(statuses) else {}),
        "mismatched": [(view, status) for view, status in everyone if status.state == "mismatch"],
        "episodes": everyone,
        "rendered": len(statuses),
        "label_width": label_width,
        "category_names": sorted({record.category for record in records}),
        "class_names": sorted({record.scenario_class for record in records}),
        "kind_names": sorted({view.goal.kind for view in run.episodes if view.goal}),
        "goal_names": sorted({goal_key(record) for record in records}),
        "episodes_dir": EPISODES_DIR,
        # Issue 31: the legend of the rates (clustered by goal) and the actions taken.
        "rates_legend": rates_legend(summary),
        "dominant_share": DOMINANT_SHARE,
    }


def _goal_status(run: LoadedRun, worlds: int) -> GoalStatusTables:
    """Issue 31: the run's tables without trivial and impossible goals, and doing nothing."""
    results = run.results
    records = [view.record for view in run.episodes]
    rule = run.run.rule
    status = run_goal_status(results.config, records, rule=rule, worlds=worlds)
    return goal_status_tables(
        run_summary(results, records, rule),
        rescore(records, rule),
        status,
        agent=run.run.agent,
        difficulty=run.run.difficulty,
    )


def _scores_context(run: LoadedRun, compared: Sequence[ComparedRun]) -> dict[str, Any]:
    """The field's achievement scores of the run (overall, per category, per episode, the
    unlock table) and of each compared run, from their records, as `report` prints them."""
    scores = run_scores(run.results, [view.record for view in run.episodes])
    others = [
        (other.label, run_scores(other.results, other.episodes).overall) for other in compared
    ]
    return {"scores": scores, "compared_scores": others}


def _latency(latencies: list[float]) -> dict[str, float] | None:
    if not latencies or not any(latencies):
        return None
    return {
        "mean": statistics.fmean(latencies),
        "median": statistics.median(latencies),
        "p95": latencies[min(len(latencies) - 1, round(0.95 * (len(latencies) - 1)))],
        "max": latencies[-1],
    }


def _flatten(config: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    items: list[tuple[str, Any]] = []
    for key, value in config.items():
        if isinstance(value, dict) and value:
            items.extend(_flatten(value, f"{prefix}{key}."))
        else:
            items.append((f"{prefix}{key}", value))
    return items


# ---------------------------------------------------------------- episode page


def sent_images(
    steps: Sequence[StepRecord], frame_history: int
) -> tuple[dict[int, str], dict[int, list[int]]]:
    """`--observation image|both`: each step's recorded frame as the data URL of its very PNG,
    and per step the steps whose frames its message carried, oldest first (its own last):
    exactly the images the model was sent, as the episode page shows them."""
    frames = {
        step.step: f"data:image/png;base64,{step.frame_png}" for step in steps if step.frame_png
    }
    sent = {step: list(range(max(0, step - frame_history), step + 1)) for step in sorted(frames)}
    return frames, sent


def _episode_context(
    run: LoadedRun,
    view: EpisodeView,
    sheet: SpriteSheet | None,
    status: ReplayStatus,
    neighbours: dict[str, tuple[str | None, str | None]],
    variant: Any,
) -> dict[str, Any]:
    record = view.record
    previous, following = neighbours[record.episode_id]
    scale = max(1, round(_FRAME_DISPLAY_HEIGHT / sheet.frame_height)) if sheet else 1
    frames, sent = sent_images(view.steps, int(run.config.get("frame_history") or 0))
    steps = [
        {
            "step": step.step,
            "raw": step.raw_output,
            "reasoning": step.reasoning,
            "action": step.action_name,
            "stage": step.parse_stage,
            "fallback": step.fallback_used,
            "reward": round(step.reward, 4),
            "new": step.new_achievements,
            "done": step.done,
            "latency": round(step.latency_s, 3),
            "sent": sent.get(step.step, []),
        }
        for step in view.steps
    ]
    checker = status.checker
    data = {
        "steps": steps,
        # Each step's recorded PNG once; a step's `sent` lists the frames its message carried.
        "frames": frames,
        # The small map is drawn here, in the page; its script reads only the checker's marks.
        "checker": None
        if checker is None
        else {key: value for key, value in checker.items() if key != "minimap"},
        "termination": record.termination,
        "sheet": None
        if sheet is None
        else {
            "width": sheet.frame_width,
            "height": sheet.frame_height,
            "columns": sheet.columns,
            "index": sheet.index,
            "scale": scale,
        },
    }
    return {
        "title": f"Episode {record.episode_id}",
        "model": model_name_of(run.results),
        "record": record,
        "goal": view.goal,
        "panel": _goal_panel(view),
        "checker": checker,
        "chart": _count_chart(view, checker) if checker and "held" in checker else None,
        "errors": view.errors,
        "status": status,
        "sheet": sheet,
        "sheet_file": view.sheet,
        "scale": scale,
        "data": data,
        "steps": steps,
        "previous": previous,
        "next": following,
        "actions": action_histogram(Counter(step.action_name for step in view.steps))
        if view.steps
        else None,
    }


def _goal_panel(view: EpisodeView) -> dict[str, Any]:
    """The goal in words and as the dataset's JSON, when the checker fired, and the model's
    reading of the instruction beside it (guided runs)."""
    record = view.record
    goal = view.goal
    panel: dict[str, Any] = {
        "kind": goal.kind if goal else None,
        "words": rendering_of(goal.kind).describe(goal) if goal else None,
        "json": goal.model_dump_json(indent=1, exclude={"paraphrases"}) if goal else None,
        "fired": f"after step {record.steps - 1} (frame {record.steps})"
        if record.success and record.steps
        else ("before the first step" if record.success else "never"),
        "reading": None,
    }
    grounding = record.grounding
    if grounding is not None:
        reading = grounding.reading
        panel["reading"] = {
            "outcome": grounding.outcome,
            "correct": record.grounding_correct,
            "words": rendering_of(reading.kind).describe(reading) if reading else None,
            "json": reading.model_dump_json(indent=1) if reading else None,
            "reason": grounding.reason,
        }
    return panel


def _count_chart(view: EpisodeView, checker: dict[str, Any]) -> dict[str, Any]:
    """An inline chart of a conditional-placing goal's two counts over the frames: the item
    held (its threshold to spend past) and the blocks standing (the count to reach)."""
    goal: Any = view.goal
    width, height, left, top = 520, 150, 36, 10
    frames = len(checker["held"])
    series = [
        (goal.collect, checker["held"], goal.collect_count, "held"),
        (
            f"{block_words(goal.place, 2)} on the map",
            checker["standing"],
            goal.place_count,
            "standing",
        ),
    ]
    top_value = max(
        [1, goal.collect_count, goal.place_count, *checker["held"], *checker["standing"]]
    )

    def x(frame: int) -> float:
        return left + (frame / max(1, frames - 1)) * (width - left - 10)

    def y(value: float) -> float:
        return top + (1 - value / top_value) * (height - top - 24)

    lines = [
        {
            "label": label,
            "css": css,
            "points": " ".join(f"{x(i):.1f},{y(v):.1f}" for i, v in enumerate(values)),
            "threshold": round(y(threshold), 1),
            "value": threshold,
        }
        for label, values, threshold, css in series
    ]
    fired = view.record.steps if view.record.success else None
    return {
        "width": width,
        "height": height,
        "left": left,
        "bottom": height - 24,
        "right": width - 10,
        "top_value": top_value,
        "top": top,
        "lines": lines,
        "fired": None if fired is None else round(x(fired), 1),
        "frames": frames,
    }
