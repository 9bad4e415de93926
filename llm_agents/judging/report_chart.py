"""The report's chart: a PNG bar chart of a run's success per goal set with its intervals, beside
the paper's published rates when the run is comparable with them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY, Difficulty
from llm_agents.judging.published import PublishedResult, published_for
from llm_agents.judging.report_tables import CATEGORY_LABELS, chart_categories, our_rate
from llm_agents.run_data.metrics import SuccessRate, Summary

CHART_FILE = "success.png"


def _tick_label(
    category: str, ours: SuccessRate | None, published: Sequence[PublishedResult]
) -> str:
    notes = [f"n={ours.episodes}" if ours is not None else "not run"]
    if all(result.rate(category) is None for result in published):
        notes.append("none published")
    return f"{CATEGORY_LABELS[category]}\n({', '.join(notes)})"


def plot_success(
    summary: Summary,
    model_name: str,
    path: Path,
    *,
    with_published: bool = True,
    difficulty: Difficulty = DEFAULT_DIFFICULTY,
) -> None:
    """Save a PNG bar chart of success per category: our run with its intervals, and the paper's
    (left out with `with_published=False`, for a run not comparable with it)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    categories = chart_categories(summary, difficulty)
    published_rows = published_for(difficulty)
    series: list[tuple[str, list[float], list[float], list[float]]] = []
    ours = [our_rate(summary, category) for category in categories]
    series.append(
        (
            f"{model_name} (this run)",
            [math.nan if rate is None else rate.rate for rate in ours],
            [0.0 if rate is None else rate.rate - rate.low for rate in ours],
            [0.0 if rate is None else rate.high - rate.rate for rate in ours],
        )
    )
    shown = published_rows if with_published else ()
    for result in shown:
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
        [
            _tick_label(category, rate, published_rows)
            for category, rate in zip(categories, ours, strict=True)
        ],
    )
    # Bars with no height (nothing published) do not count for autoscaling.
    axes.set_xlim(-0.5, len(categories) - 0.5)
    axes.set_ylabel("success rate")
    interval = "interval clustered by goal" if summary.overall.clusters else "Wilson interval"
    axes.set_title(
        f"CrafText {difficulty} success (ours: 95% {interval})"
        if with_published or not published_rows
        else f"CrafText {difficulty} success (ours: 95% {interval}; published: not comparable)"
    )
    tallest = max(
        [rate.high for rate in ours if rate is not None]
        + [rate for result in shown for rate in result.rates.values()]
        + [0.0]
    )
    axes.set_ylim(0, min(1.0, tallest * 1.25 + 0.02))
    axes.grid(axis="y", alpha=0.3)
    axes.set_axisbelow(True)
    figure.legend(loc="outside lower center", ncols=2, fontsize="small", frameon=False)
    try:
        figure.savefig(path, format="png", dpi=120)
    except OSError as exc:
        raise UserError(f"cannot write chart {path}: {exc.strerror}") from exc
