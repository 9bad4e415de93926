"""The text report of a grounding run (`craftext-llm report` on a `ground` run directory):
understanding by split and category, with 95% Wilson intervals clustered by goal (runs scored
before: plain), and the commonest confusions.

A Medium or Hard run adds kind accuracy, rows per scenario class (its splits are its categories,
so it has no category rows) and a table of each placing-goal parameter read right, by split."""

from __future__ import annotations

from pathlib import Path

from env.errors import UserError
from llm_agents.evaluation.grounding_run import read_ground_results, read_groundings
from llm_agents.evaluation.run_view import recorded_difficulty
from llm_agents.judging.report_tables import render_rows
from llm_agents.run_data.grounding_metrics import GroundingScore
from llm_agents.run_data.metrics import SuccessRate
from llm_agents.run_data.provenance import code_note
from llm_agents.run_data.store import RESULTS_FILE

__all__ = ["report_grounding"]

_HEADER = [
    "Texts",
    "n",
    "exact",
    "invalid",
    "required P",
    "required R",
    "forbidden P",
    "forbidden R",
]


def _rate(rate: SuccessRate | None) -> str:
    return "-" if rate is None else f"{rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}]"


def _row(label: str, score: GroundingScore, kinds: bool = False) -> list[str]:
    required, forbidden = score.fields.get("required"), score.fields.get("forbidden")
    return [
        label,
        str(score.texts),
        _rate(score.exact),
        str(score.invalid),
        *([_rate(score.kind)] if kinds else []),
        _rate(required.precision if required else None),
        _rate(required.recall if required else None),
        _rate(forbidden.precision if forbidden else None),
        _rate(forbidden.recall if forbidden else None),
    ]


def _parameters(overall: GroundingScore, by_split: dict[str, GroundingScore]) -> list[str]:
    """Each placing-goal parameter read right, overall and per split (n after the rate)."""
    if not overall.parameters:
        return []
    rows = [["Parameter", "all", *by_split]]
    for key, rate in overall.parameters.items():
        cells = [by_split[split].parameters.get(key) for split in by_split]
        rows.append(
            [
                key,
                f"{_rate(rate)} n={rate.episodes}",
                *(f"{_rate(cell)} n={cell.episodes}" if cell else "-" for cell in cells),
            ]
        )
    return ["Parameters read right:", "", *render_rows(rows), ""]


def report_grounding(run_dir: str | Path) -> str:
    """The report of the grounding run in `run_dir`."""
    out = Path(run_dir)
    if not (out / RESULTS_FILE).is_file():
        raise UserError(f"{out} holds no {RESULTS_FILE}: not a run directory")
    results = read_ground_results(out / RESULTS_FILE)
    config = results.config
    difficulty = recorded_difficulty(config)
    later = difficulty != "easy"
    head = (
        f"Grounding{' of ' + difficulty + ' goals' if later else ''} by {config.get('model')} "
        f"({config.get('variant')} Craftax"
        f"{', choice ' + str(config['choice']) if config.get('choice') else ''}): "
        f"{results.status} ({results.finished} of {results.scheduled} instruction texts)."
    )
    summary = results.summary
    if summary is None:
        return f"{head}\nNo instruction answered yet."
    if not later:
        rows = [_HEADER, _row("all", summary.overall)]
        rows += [_row(split, score) for split, score in summary.by_split.items()]
        rows += [_row(category, score) for category, score in summary.by_category.items()]
        legend = (
            "exact: read exactly as the dataset's goal; P / R: precision / recall of the "
            f"achievements read into each field; [{summary.overall.exact.label}]."
        )
        lines = [head, "", *render_rows(rows), "", legend]
    else:
        rows = [[*_HEADER[:4], "kind", *_HEADER[4:]], _row("all", summary.overall, kinds=True)]
        rows += [_row(split, score, kinds=True) for split, score in summary.by_split.items()]
        lines = [head, "", *render_rows(rows), "", f"By scenario class ({difficulty}):", ""]
        rows = [["Class", *rows[0][1:]]]
        rows += [_row(c, score, kinds=True) for c, score in summary.by_scenario_class.items()]
        lines += [*render_rows(rows), ""]
        lines += _parameters(summary.overall, summary.by_split)
        lines.append(
            "exact: read exactly as the dataset's goal (every field); kind: read as a goal of "
            "its kind; P / R: precision / recall of the achievements read into each field of "
            "the achievements goals; parameters: read right, of the texts read as the right "
            f"kind; [{summary.overall.exact.label}]."
        )
    if summary.confusions:
        lines += ["", "Commonest confusions (texts):"]
        lines += [f"  {c.count:4d}  {c.kind}: {c.subject}" for c in summary.confusions]
    if summary.invalid_reasons:
        lines += ["", "Invalid answers (texts):"]
        lines += [f"  {count:4d}  {reason}" for reason, count in summary.invalid_reasons.items()]
    if results.seconds_per_instruction is not None:
        lines += ["", f"Seconds per instruction: {results.seconds_per_instruction:.3f}."]
    if results.failed_calls:
        lines.append(
            f"Backend failures: {results.failed_calls} (last: {results.last_error}); "
            "rerun the same command to ask again."
        )
    if results.status == "failed":
        lines.append(f"Stopped: the backend kept failing ({results.failure}).")
    mixed = code_note((record.code for record in read_groundings(out)), "answers")
    if mixed:
        lines.append(mixed)
    return "\n".join(lines)
