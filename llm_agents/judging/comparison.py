"""`report --compare`: several runs' rows in one table (and their achievement scores), with the
published rows and notes on what differs between the runs."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from env.dataset import PAPER_CATEGORIES
from env.errors import UserError
from env.goals import DIFFICULTY_CATEGORIES
from llm_agents.evaluation.run_view import read_run, recorded_rule
from llm_agents.judging.published import PUBLISHED_KIND, published_for
from llm_agents.judging.report_tables import (
    CATEGORY_LABELS,
    SCORES_HEADER,
    action_lines,
    our_cell,
    our_rate,
    published_cell,
    rates_legend,
    render_rows,
    scores_cells,
)
from llm_agents.judging.rescoring import (
    difficulty_of_run,
    model_name_of,
    run_actions,
    run_scores,
    run_summary,
)
from llm_agents.run_data.metrics import Summary
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import RESULTS_FILE, RunResults


@dataclass(frozen=True)
class ComparedRun:
    """A run shown as one row of a comparison: its label, its summary and its results."""

    label: str
    summary: Summary
    results: RunResults
    episodes: Sequence[EpisodeRecord]
    """The run's scheduled episodes, as read for the summary (the scores come from them too)."""

    def cells(self, columns: Sequence[str]) -> list[str]:
        """The row's cells under `columns`, label first."""
        return [self.label, *(our_cell(our_rate(self.summary, c)) for c in columns)]


def compared_run(run_dir: str | Path) -> ComparedRun:
    """A run directory's row for `--compare`: labelled with its model and agent strategy."""
    if not (Path(run_dir) / RESULTS_FILE).is_file():
        raise UserError(f"{run_dir} has no {RESULTS_FILE}: it is not a run directory")
    run = read_run(run_dir)
    results, episodes = run.results, run.episodes
    name = model_name_of(results)
    label = name if run.agent == "expert" else f"{name} ({run.agent})"
    partial = results.status != "complete"
    summary = run_summary(results, episodes, run.rule, run_actions(run))
    return ComparedRun(f"{label}{', partial' if partial else ''}", summary, results, episodes)


def comparison_columns(runs: Sequence[ComparedRun]) -> list[str]:
    """The columns of a comparison: the paper's categories of the first run's difficulty
    (EASY's with `paraphrased` when a run has it), and the overall rate."""
    difficulty = difficulty_of_run(runs[0].results)
    if difficulty != "easy":
        return [*DIFFICULTY_CATEGORIES[difficulty], "overall"]
    categories = {c for run in runs for c in run.summary.by_category}
    columns: list[str] = [
        c for c in (*PAPER_CATEGORIES, "paraphrased") if c in categories or c in PAPER_CATEGORIES
    ]
    return [*columns, "overall"]


#: Settings that change a run's numbers without changing what it plays, named as a comparison
#: names them when runs differ in them (a setting a run predates reads as unset).
_COMPARED_SETTINGS = {
    "choice": "choice",
    "choice_scoring": "choice scoring",
    "variant": "variant",
    "protocol": "protocol",
}


def comparison_notes(runs: Sequence[ComparedRun]) -> list[str]:
    """What a reader of the comparison must know: the runs read different datasets, played
    different difficulties, or differ in a setting that changes the numbers (choice, choice
    scoring, success rule, variant, protocol)."""
    notes = []
    if len({run.results.dataset.get("sha256") for run in runs}) > 1:
        notes.append("Note: the compared runs read different datasets (or one is unknown).")
    if len({difficulty_of_run(run.results) for run in runs}) > 1:
        notes.append("Note: the compared runs played different difficulties.")
    values = {
        label: [run.results.config.get(key) for run in runs]
        for key, label in _COMPARED_SETTINGS.items()
    }
    values["success rule"] = [recorded_rule(run.results.config) for run in runs]
    differing = [
        f"{label} ({', '.join('unset' if value is None else str(value) for value in seen)})"
        for label, seen in values.items()
        if len({json.dumps(value, sort_keys=True) for value in seen}) > 1
    ]
    if differing:
        notes.append(
            f"Note: the compared runs differ in {'; '.join(differing)} (in the rows' order)."
        )
    return notes


def compare_runs(run_dir: str | Path, *others: str | Path) -> str:
    """A run's table with other runs' rows beside it (e.g. the expert's on the same dataset),
    and the published rows; says so when the runs read different datasets."""
    runs = [compared_run(run_dir), *(compared_run(other) for other in others)]
    columns = comparison_columns(runs)
    rows = [["Run", *(CATEGORY_LABELS[c] for c in columns)]]
    rows += [run.cells(columns) for run in runs]
    difficulty = difficulty_of_run(runs[0].results)
    rows += [
        [f"{result.model} (published)", *(published_cell(result, c) for c in columns)]
        for result in published_for(difficulty)
    ]
    notes = [
        "",
        f"{rates_legend(runs[0].summary)} Published: {PUBLISHED_KIND[difficulty]}.",
        *(
            f"{run.label}: {line}"
            for run in runs
            for line in action_lines(run.summary)
            if line.startswith("WARNING")
        ),
    ]
    lines = render_rows(rows) + notes + comparison_notes(runs)
    scores = compare_scores(runs)
    return "\n".join([*lines, "", scores])


def compare_scores(runs: Sequence[ComparedRun]) -> str:
    """The achievement scores of compared runs, a row each (`report --compare`)."""
    rows = [["Run", "Achievements", *SCORES_HEADER]]
    for run in runs:
        overall = run_scores(run.results, run.episodes).overall
        rows.append([run.label, overall.achievement_list, *scores_cells(overall)])
    return "\n".join(
        ["Achievement scores (classic: Crafter's 22; full: Craftax's 67):", *render_rows(rows)]
    )
