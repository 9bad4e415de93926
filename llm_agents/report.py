"""The results table and chart of a run, beside the published zero-shot CrafText numbers.

The table follows the paper's layout (success rate on the `one`, `combo` and `New objects`
goal sets), adding the `paraphrased` set and the overall rate when the run has them.
"""

from __future__ import annotations

import math
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from llm_agents.metrics import SuccessRate, Summary, summarize
from llm_agents.records import RunResults, read_episodes, read_results

__all__ = [
    "PUBLISHED",
    "PublishedResult",
    "compare_runs",
    "format_table",
    "plot_success",
    "report_run",
]

EPISODES_FILE = "episodes.jsonl"
RESULTS_FILE = "results.json"
CHART_FILE = "success.png"


class PublishedResult(BaseModel):
    """Zero-shot success rates of one model as published for CrafText (EASY split)."""

    model_config = ConfigDict(frozen=True)

    model: str
    """Model name as the paper gives it."""
    one: float
    """Success rate on single-achievement goals."""
    combo: float
    """Success rate on goals that combine achievements."""
    new_objects: float
    """Success rate on goals about objects unseen in the other sets."""

    def rate(self, category: str) -> float | None:
        """The published rate of a category; None where the paper gives none (`paraphrased`)."""
        return {"one": self.one, "combo": self.combo, "new_objects": self.new_objects}.get(category)


PUBLISHED: tuple[PublishedResult, ...] = (
    PublishedResult(model="Qwen QwQ-32B", one=0.21, combo=0.10, new_objects=0.07),
    PublishedResult(model="Mistral-Small-24B", one=0.21, combo=0.10, new_objects=0.09),
    PublishedResult(model="DeepSeek-R1-Distill-Qwen-32B", one=0.15, combo=0.07, new_objects=0.06),
)

_PAPER_CATEGORIES = ("one", "combo", "new_objects")
_LABELS = {
    "one": "one",
    "combo": "combo",
    "new_objects": "New objects",
    "paraphrased": "paraphrased",
    "overall": "overall",
}


def _chart_categories(summary: Summary) -> list[str]:
    extra = ["paraphrased"] if "paraphrased" in summary.by_category else []
    return [*_PAPER_CATEGORIES, *extra]


def _table_columns(summary: Summary) -> list[str]:
    # With a single category the overall column would only repeat it.
    overall = ["overall"] if len(summary.by_category) > 1 else []
    return [*_chart_categories(summary), *overall]


def _ours(summary: Summary, column: str) -> SuccessRate | None:
    return summary.overall if column == "overall" else summary.by_category.get(column)


def _our_cell(rate: SuccessRate | None) -> str:
    if rate is None:
        return "-"
    return f"{rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}] n={rate.episodes}"


def _published_cell(result: PublishedResult, column: str) -> str:
    rate = result.rate(column)
    return "-" if rate is None else f"{rate:.2f}"


def format_table(summary: Summary, model_name: str, *, partial: bool = False) -> str:
    """Our success rates (95% Wilson interval, episodes) beside the published ones, as text."""
    columns = _table_columns(summary)
    ours_label = f"{model_name} (this run{', partial' if partial else ''})"
    rows = [
        ["Model", *(_LABELS[column] for column in columns)],
        [ours_label, *(_our_cell(_ours(summary, column)) for column in columns)],
        *(
            [f"{result.model} (published)", *(_published_cell(result, c) for c in columns)]
            for result in PUBLISHED
        ),
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]

    def line(cells: list[str]) -> str:
        return " | ".join(
            cell.ljust(width) for cell, width in zip(cells, widths, strict=True)
        ).rstrip()

    rule = "-+-".join("-" * width for width in widths)
    table = [line(rows[0]), rule, *(line(row) for row in rows[1:])]
    ends = summary.terminations
    steps = (
        f"mean {summary.steps_to_success_mean:.1f}, median {summary.steps_to_success_median:.1f}"
        if summary.steps_to_success_mean is not None and summary.steps_to_success_median is not None
        else "no successes"
    )
    notes = [
        "Success rate [95% Wilson interval] n=episodes. Published: zero-shot, EASY split.",
        f"Episodes: {summary.overall.episodes} (success {ends['success']}, "
        f"death {ends['death']}, timeout {ends['timeout']}).",
        f"Invalid-action rate: {summary.invalid_action_rate:.3f}. Steps to success: {steps}.",
        f"Tokens per step: {summary.prompt_tokens_per_step:.0f} prompt, "
        f"{summary.completion_tokens_per_step:.0f} completion.",
    ]
    return "\n".join([*table, "", *notes])


def _tick_label(category: str, ours: SuccessRate | None) -> str:
    notes = [f"n={ours.episodes}" if ours is not None else "not run"]
    if category not in _PAPER_CATEGORIES:
        notes.append("none published")
    return f"{_LABELS[category]}\n({', '.join(notes)})"


def plot_success(summary: Summary, model_name: str, path: Path) -> None:
    """Save a PNG bar chart of success per category: our run with its intervals, and the paper's."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    categories = _chart_categories(summary)
    series: list[tuple[str, list[float], list[float], list[float]]] = []
    ours = [_ours(summary, category) for category in categories]
    series.append(
        (
            f"{model_name} (this run)",
            [math.nan if rate is None else rate.rate for rate in ours],
            [0.0 if rate is None else rate.rate - rate.low for rate in ours],
            [0.0 if rate is None else rate.high - rate.rate for rate in ours],
        )
    )
    for result in PUBLISHED:
        published = [result.rate(category) for category in categories]
        zeros = [0.0] * len(categories)
        series.append(
            (
                f"{result.model} (published)",
                [math.nan if rate is None else rate for rate in published],
                zeros,
                zeros,
            )
        )

    figure = Figure(figsize=(8, 5), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    width = 0.8 / len(series)
    for index, (label, heights, below, above) in enumerate(series):
        positions = [
            group + (index - (len(series) - 1) / 2) * width for group in range(len(categories))
        ]
        has_errors = any(below) or any(above)
        axes.bar(
            positions,
            heights,
            width,
            label=label,
            yerr=[below, above] if has_errors else None,
            capsize=4 if has_errors else 0,
        )
    axes.set_xticks(
        range(len(categories)),
        [_tick_label(category, rate) for category, rate in zip(categories, ours, strict=True)],
    )
    # Bars with no height (nothing published) do not count for autoscaling.
    axes.set_xlim(-0.5, len(categories) - 0.5)
    axes.set_ylabel("success rate")
    axes.set_title("CrafText zero-shot success (ours: 95% Wilson interval)")
    tallest = max(
        [rate.high for rate in ours if rate is not None]
        + [rate for result in PUBLISHED for rate in (result.one, result.combo, result.new_objects)]
    )
    axes.set_ylim(0, min(1.0, tallest * 1.25 + 0.02))
    axes.grid(axis="y", alpha=0.3)
    axes.set_axisbelow(True)
    figure.legend(loc="outside lower center", ncols=2, fontsize="small", frameon=False)
    try:
        figure.savefig(path, format="png", dpi=120)
    except OSError as exc:
        raise UserError(f"cannot write chart {path}: {exc.strerror}") from exc


def _model_name(results: RunResults | None) -> str:
    if results is not None and results.config.get("agent") == "expert":
        return "expert (scripted, no model)"
    model = results.config.get("model") if results is not None else None
    return model if isinstance(model, str) and model else "this model"


def report_run(run_dir: str | Path) -> str:
    """Rebuild the table (returned) and `success.png` of a run directory, finished or not."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"run directory {run_dir} does not exist")
    episodes_path = run_dir / EPISODES_FILE
    if not episodes_path.is_file():
        raise UserError(f"{run_dir} has no {EPISODES_FILE}: no episode has finished there")
    episodes = read_episodes(episodes_path)
    if not episodes:
        raise UserError(f"{episodes_path} holds no finished episode")
    results_path = run_dir / RESULTS_FILE
    results = read_results(results_path) if results_path.is_file() else None
    summary = summarize(episodes)
    model_name = _model_name(results)
    plot_success(summary, model_name, run_dir / CHART_FILE)
    return format_table(summary, model_name, partial=results is None or not results.complete)


def _run_row(run_dir: Path) -> tuple[str, Summary, RunResults | None]:
    if not (run_dir / EPISODES_FILE).is_file():
        raise UserError(f"{run_dir} has no {EPISODES_FILE}: no episode has finished there")
    episodes = read_episodes(run_dir / EPISODES_FILE)
    if not episodes:
        raise UserError(f"{run_dir / EPISODES_FILE} holds no finished episode")
    results_path = run_dir / RESULTS_FILE
    results = read_results(results_path) if results_path.is_file() else None
    agent = results.config.get("agent", "zero-shot") if results is not None else "zero-shot"
    label = _model_name(results) if agent == "expert" else f"{_model_name(results)} ({agent})"
    partial = results is None or not results.complete
    return f"{label}{', partial' if partial else ''}", summarize(episodes), results


def compare_runs(run_dir: str | Path, other_dir: str | Path) -> str:
    """A run's table with another run's row beside it (e.g. the expert's on the same dataset),
    and the published rows; says so when the two runs read different datasets."""
    rows_data = [_run_row(Path(run_dir)), _run_row(Path(other_dir))]
    categories = {c for _, summary, _ in rows_data for c in summary.by_category}
    columns = [
        c for c in (*_PAPER_CATEGORIES, "paraphrased") if c in categories or c in _PAPER_CATEGORIES
    ]
    columns.append("overall")
    rows = [["Run", *(_LABELS[c] for c in columns)]]
    rows += [[label, *(_our_cell(_ours(s, c)) for c in columns)] for label, s, _ in rows_data]
    rows += [
        [f"{result.model} (published)", *(_published_cell(result, c) for c in columns)]
        for result in PUBLISHED
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(columns) + 1)]
    lines = [
        " | ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
        for row in rows
    ]
    lines.insert(1, "-+-".join("-" * w for w in widths))
    notes = ["", "Success rate [95% Wilson interval] n=episodes. Published: zero-shot, EASY split."]
    datasets = [r.dataset.get("sha256") if r is not None else None for _, _, r in rows_data]
    if datasets[0] != datasets[1]:
        notes.append("Note: the two runs read different datasets (or one is unknown).")
    return "\n".join(lines + notes)
