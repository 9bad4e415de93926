"""The static HTML report of a run: a run page and one page per episode with its replay.

`build_view` writes `RUN_DIR/report/index.html`, and `RUN_DIR/report/episodes/` a page and a
frame sheet (PNG) per episode. Styles and scripts are inline and links relative, so the report
folder opens from disk, offline, with no server.
"""

from __future__ import annotations

import functools
import logging
import statistics
import time
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
from llm_agents.evaluation.report import (
    CATEGORY_LABELS,
    PUBLISHED_KIND,
    ComparedRun,
    chart_categories,
    compared_run,
    comparison_columns,
    comparison_notes,
    difficulty_of_run,
    model_name_of,
    our_rate,
    paper_differences,
    published_cell,
    published_for,
    recorded_rule,
    run_summary,
    scenario_rows,
    table_columns,
)
from llm_agents.run_data.metrics import goal_key
from llm_agents.viewer.frames import SpriteSheet, export_animation, sprite_sheet
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

    @property
    def mismatches(self) -> dict[str, ReplayStatus]:
        return {key: s for key, s in self.statuses.items() if s.state == "mismatch"}


def build_view(
    run_dir: str | Path,
    *,
    progress: bool = True,
    batch_size: int = 16,
    compare: Sequence[str | Path] = (),
) -> ViewOutcome:
    """Replay every episode of `run_dir` and write its HTML report; returns where and how it went.

    A replay that does not reproduce its record is logged as a warning and flagged on its page
    and on the run page. The runs in `compare` (e.g. the expert's) get a row each beside the
    run's in the results table, as `report --compare` prints them.
    """
    run = load_run(run_dir)
    # Read before the long rendering, so a wrong path fails at once.
    compared = [compared_run(other) for other in compare]
    out = run.path / REPORT_DIR
    pages = out / EPISODES_DIR
    try:
        pages.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create {pages}: {exc.strerror}") from exc
    templates = _templates()
    neighbours = _neighbours(run.episodes)
    statuses: dict[str, ReplayStatus] = {}
    frames = 0
    started = time.perf_counter()
    render_seconds = 0.0
    bar = _progress(progress, len(run.episodes))
    try:
        for view, sheet, status in _replays(run, batch_size, bar):
            frames += status.frames
            render_seconds = time.perf_counter() - started
            statuses[view.record.episode_id] = status
            if sheet is not None:
                _write_bytes(pages / view.sheet, sheet.png)
            _write(
                pages / view.page,
                templates.get_template("episode.html.j2").render(
                    **_episode_context(run, view, sheet, status, neighbours)
                ),
            )
    finally:
        if bar is not None:
            bar.close()
    index = out / "index.html"
    _write(
        index,
        templates.get_template("index.html.j2").render(**_run_context(run, statuses, compared)),
    )
    size = sum(path.stat().st_size for path in out.rglob("*") if path.is_file())
    return ViewOutcome(
        index=index,
        statuses=statuses,
        render_seconds=render_seconds,
        frames=frames,
        size_bytes=size,
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
    run: LoadedRun, batch_size: int, bar: Any
) -> Iterator[tuple[EpisodeView, SpriteSheet | None, ReplayStatus]]:
    for view in run.episodes:
        if view.unreplayable:
            if bar is not None:
                bar.update(1)
            yield view, None, ReplayStatus("not replayed", [view.unreplayable])
    playable = [view for view in run.episodes if not view.unreplayable]
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
    from env import CrafTextEnv, EnvConfig
    from env.replay import Replayer

    return Replayer(
        CrafTextEnv(EnvConfig.model_validate_json(env_config_json)), batch_size=batch_size
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
    summary = run_summary(results, records, recorded_rule(results))
    model = model_name_of(results)
    partial = results.status != "complete"
    differences = paper_differences(results, recorded_rule(results))
    difficulty = difficulty_of_run(results)
    published = published_for(difficulty)
    ours = ComparedRun(f"{model} (this run{', partial' if partial else ''})", summary, results)
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
    # The y range of report.plot_success: the tallest interval or published bar, plus headroom.
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
        },
        "mismatched": [
            (view, statuses[view.record.episode_id])
            for view in run.episodes
            if statuses[view.record.episode_id].state == "mismatch"
        ],
        "episodes": [(view, statuses[view.record.episode_id]) for view in run.episodes],
        "category_names": sorted({record.category for record in records}),
        "goal_names": sorted({goal_key(record) for record in records}),
        "episodes_dir": EPISODES_DIR,
    }


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


def _episode_context(
    run: LoadedRun,
    view: EpisodeView,
    sheet: SpriteSheet | None,
    status: ReplayStatus,
    neighbours: dict[str, tuple[str | None, str | None]],
) -> dict[str, Any]:
    record = view.record
    previous, following = neighbours[record.episode_id]
    scale = max(1, round(_FRAME_DISPLAY_HEIGHT / sheet.frame_height)) if sheet else 1
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
        }
        for step in view.steps
    ]
    data = {
        "steps": steps,
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
        "errors": view.errors,
        "status": status,
        "sheet": sheet,
        "sheet_file": view.sheet,
        "scale": scale,
        "data": data,
        "steps": steps,
        "previous": previous,
        "next": following,
    }
