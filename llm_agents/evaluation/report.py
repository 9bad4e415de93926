"""The results table and chart of a run, beside the published CrafText numbers.

The table follows the paper's layout: for an EASY run its zero-shot table (success rate on the
`one`, `combo` and `New objects` goal sets), adding the `paraphrased` set and the overall rate
when the run has them; for a Medium or Hard run its Table 2 (Train / Paraphrased / New objects),
with a second table of success per scenario class (Conditional, Build, Localization,
Achievements) and split. The published numbers of the run's difficulty (zero-shot LLMs for
EASY, the paper's agents' totals for Medium; none for Hard) sit beside a run's only when the run
followed the paper's protocol where it changes the numbers (variant, dataset splits, step cap,
success rule); otherwise they are printed under a heading that lists each difference. A run can
be re-scored under either success rule from its records alone (`report_run(...,
success_rule=...)`).
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from env.dataset import (
    OFFICIAL_COMMIT,
    OFFICIAL_SPLIT_SHA256,
    PAPER_CATEGORIES,
)
from env.errors import UserError
from env.goals import (
    DIFFICULTY_CATEGORIES,
    Difficulty,
    ScenarioClass,
    category_split,
)
from env.rules import SUCCESS_RULES, SuccessRule
from llm_agents.evaluation.goal_flags import (
    DEFAULT_WORLDS,
    EXPERT_PLAYED,
    GoalStatus,
    run_goal_status,
)
from llm_agents.evaluation.protocol import protocol_for
from llm_agents.run_data.metrics import (
    DOMINANT_SHARE,
    SuccessRate,
    Summary,
    action_counts,
    action_histogram,
    summarize,
)
from llm_agents.run_data.provenance import code_note
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import RunScores, Scores, achievement_list_of, score_run
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunResults,
    read_episodes,
    read_results,
    read_steps,
)

__all__ = [
    "PUBLISHED",
    "ComparedRun",
    "GoalStatusTables",
    "PublishedResult",
    "compare_runs",
    "compare_scores",
    "compared_run",
    "comparison_columns",
    "comparison_notes",
    "format_scores",
    "format_table",
    "goal_status_tables",
    "goal_status_text",
    "paper_differences",
    "plot_success",
    "report_run",
    "rescore",
    "run_scores",
]

CHART_FILE = "success.png"


class PublishedResult(BaseModel):
    """Success rates of one model or agent as the CrafText paper publishes them."""

    model_config = ConfigDict(frozen=True)

    model: str
    """Model or agent name as the paper gives it."""
    rates: dict[str, float]
    """Success rate per goal set (`one`, `combo`, `new_objects` for EASY; `train`,
    `paraphrased`, `new_objects` for Medium, each the total over its scenario classes)."""

    def rate(self, category: str) -> float | None:
        """The published rate of a goal set; None where the paper gives none."""
        return self.rates.get(category)


def _published(model: str, *rates: float, difficulty: Difficulty) -> PublishedResult:
    categories = PAPER_CATEGORIES if difficulty == "easy" else DIFFICULTY_CATEGORIES[difficulty]
    return PublishedResult(model=model, rates=dict(zip(categories, rates, strict=True)))


PUBLISHED: tuple[PublishedResult, ...] = (
    _published("Qwen QwQ-32B", 0.21, 0.10, 0.07, difficulty="easy"),
    _published("Mistral-Small-24B", 0.21, 0.10, 0.09, difficulty="easy"),
    _published("DeepSeek-R1-Distill-Qwen-32B", 0.15, 0.07, 0.06, difficulty="easy"),
)
"""The paper's zero-shot LLM numbers (EASY)."""
PUBLISHED_MEDIUM: tuple[PublishedResult, ...] = (
    _published("PPO-T", 0.40, 0.36, 0.22, difficulty="medium"),
    _published("PPO-T+", 0.45, 0.35, 0.28, difficulty="medium"),
    _published("FiLM", 0.43, 0.35, 0.26, difficulty="medium"),
    _published("Dynalang", 0.15, 0.05, 0.10, difficulty="medium"),
)
"""The paper's Medium totals (its Table 2, 50 worlds per instruction), trained agents."""
PUBLISHED_BY_DIFFICULTY: dict[Difficulty, tuple[PublishedResult, ...]] = {
    "easy": PUBLISHED,
    "medium": PUBLISHED_MEDIUM,
    "hard": (),
}
PUBLISHED_KIND: dict[Difficulty, str] = {
    "easy": "zero-shot, EASY split",
    "medium": "the paper's trained agents, Medium totals, 50 worlds per instruction",
    "hard": "none for Hard",
}
#: The paper's Table 2 rows, in its order.
SCENARIO_ROWS: tuple[ScenarioClass, ...] = ("Conditional", "Build", "Localization", "Achievements")

# Runs recorded before the difficulty was a setting played EASY.
_RECORDED_DIFFICULTY_BEFORE_SETTING: Difficulty = "easy"
# Runs recorded before the success rule was a setting scored the game-over step as a success.
_RECORDED_RULE_BEFORE_SETTING: SuccessRule = "game_over_counts"
NOT_IN_DATASET = "not in this dataset"
CATEGORY_LABELS = {
    "one": "one",
    "combo": "combo",
    "new_objects": "New objects",
    "paraphrased": "Paraphrased",
    "train": "Train",
    "overall": "overall",
}


def difficulty_of_run(results: RunResults) -> Difficulty:
    """The difficulty a run played."""
    difficulty = results.config.get("difficulty", _RECORDED_DIFFICULTY_BEFORE_SETTING)
    return difficulty if difficulty in DIFFICULTY_CATEGORIES else "easy"


def published_for(difficulty: Difficulty) -> tuple[PublishedResult, ...]:
    """The paper's numbers for runs of `difficulty`."""
    return PUBLISHED_BY_DIFFICULTY[difficulty]


def chart_categories(summary: Summary, difficulty: Difficulty = "easy") -> list[str]:
    if difficulty != "easy":
        return list(DIFFICULTY_CATEGORIES[difficulty])
    extra = ["paraphrased"] if "paraphrased" in summary.by_category else []
    return [*PAPER_CATEGORIES, *extra]


def table_columns(summary: Summary, difficulty: Difficulty = "easy") -> list[str]:
    # With a single category the overall column would only repeat it.
    overall = ["overall"] if len(summary.by_category) > 1 else []
    return [*chart_categories(summary, difficulty), *overall]


def scenario_rows(summary: Summary, difficulty: Difficulty) -> list[list[str]]:
    """The paper's Table 2 for a run: a header, then one row per scenario class the run played,
    success per goal set of the difficulty."""
    columns = DIFFICULTY_CATEGORIES[difficulty]
    rows = [["Scenario", *(CATEGORY_LABELS[c] for c in columns)]]
    for scenario in SCENARIO_ROWS:
        rates = summary.by_scenario.get(scenario)
        if rates:
            rows.append([scenario, *(our_cell(rates.get(c)) for c in columns)])
    return rows


def our_rate(summary: Summary, column: str) -> SuccessRate | None:
    return summary.overall if column == "overall" else summary.by_category.get(column)


def our_cell(rate: SuccessRate | None, absent: bool = False) -> str:
    if rate is None:
        return NOT_IN_DATASET if absent else "-"
    return rate.cell()


def episode_actions_line(actions: Mapping[str, Mapping[str, int]] | None) -> list[str]:
    """Per episode: how far the commonest action dominates (median and most), and in how many
    episodes one action takes more than `DOMINANT_SHARE` of the steps."""
    histograms = [action_histogram(counts) for counts in (actions or {}).values()]
    shares = sorted(h.commonest_share for h in histograms if h.steps)
    if not shares:
        return []
    dominated = sum(share > DOMINANT_SHARE for share in shares)
    return [
        f"Per episode, the commonest action's share: median {statistics.median(shares):.2f}, "
        f"highest {shares[-1]:.2f}; one action over {DOMINANT_SHARE:.0%} of the steps in "
        f"{dominated} of {len(shares)} episodes."
    ]


def rates_legend(summary: Summary) -> str:
    """What the table's cells are: rate [interval] n=episodes (g=goals when clustered)."""
    return f"Success rate [{summary.overall.label}] n=episodes."


def action_lines(summary: Summary, top: int = 5) -> list[str]:
    """The run's commonest actions, and a warning when one takes most of its steps."""
    actions = summary.actions
    if actions is None:
        return ["Actions: not recorded (no step log)."]
    if not actions.steps:
        return ["Actions: no steps."]
    shares = ", ".join(
        f"{name} {count / actions.steps:.2f}" for name, count in list(actions.counts.items())[:top]
    )
    lines = [f"Actions ({actions.steps} steps, share of each, commonest first): {shares}."]
    if actions.dominated:
        lines.append(
            f"WARNING: one action ({actions.commonest}) takes {actions.commonest_share:.0%} of "
            f"this run's steps (more than {DOMINANT_SHARE:.0%}): the agent barely chooses."
        )
    return lines


def published_cell(result: PublishedResult, column: str) -> str:
    rate = result.rate(column)
    return "-" if rate is None else f"{rate:.2f}"


def _render(rows: list[list[str]]) -> list[str]:
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]

    def line(cells: list[str]) -> str:
        return " | ".join(
            cell.ljust(width) for cell, width in zip(cells, widths, strict=True)
        ).rstrip()

    rule = "-+-".join("-" * width for width in widths)
    return [line(rows[0]), rule, *(line(row) for row in rows[1:])]


def format_table(
    summary: Summary,
    model_name: str,
    *,
    partial: bool = False,
    differences: Sequence[str] = (),
    absent: Collection[str] = (),
    notes: Sequence[str] = (),
    difficulty: Difficulty = "easy",
) -> str:
    """Our success rates (95% interval, clustered by goal, episodes) beside the published ones,
    as text;
    for Medium and Hard, then per scenario class and goal set.

    With `differences` (how the run departs from the paper's protocol) the published numbers
    go under a heading listing them instead. Categories in `absent` are not in the run's dataset.
    """
    columns = table_columns(summary, difficulty)
    published_rows = published_for(difficulty)
    ours_label = f"{model_name} (this run{', partial' if partial else ''})"
    header = ["Model", *(CATEGORY_LABELS[column] for column in columns)]
    ours = [
        ours_label,
        *(our_cell(our_rate(summary, column), column in absent) for column in columns),
    ]
    published = [
        [f"{result.model} (published)", *(published_cell(result, c) for c in columns)]
        for result in published_rows
    ]
    if differences and published:
        table = [
            *_render([header, ours]),
            "",
            f"Published numbers ({PUBLISHED_KIND[difficulty]}), NOT comparable with this run:",
            *(f"  - {difference}" for difference in differences),
            *_render([header, *published]),
        ]
    else:
        table = _render([header, ours, *published])
    if difficulty != "easy":
        table += [
            "",
            f"By scenario class ({difficulty}):",
            *_render(scenario_rows(summary, difficulty)),
        ]
    ends = summary.terminations
    steps = (
        f"mean {summary.steps_to_success_mean:.1f}, median {summary.steps_to_success_median:.1f}"
        if summary.steps_to_success_mean is not None and summary.steps_to_success_median is not None
        else "no successes"
    )
    unstarted = f", not started {ends['not_started']}" if "not_started" in ends else ""
    footer = [
        f"{rates_legend(summary)} Published: {PUBLISHED_KIND[difficulty]}.",
        f"Episodes: {summary.overall.episodes} (success {ends['success']}, "
        f"death {ends['death']}, timeout {ends['timeout']}{unstarted}).",
        *understanding_lines(summary),
        f"Invalid-action rate: {summary.invalid_action_rate:.3f}. Steps to success: {steps}.",
        f"Tokens per step: {summary.prompt_tokens_per_step:.0f} prompt, "
        f"{summary.completion_tokens_per_step:.0f} completion.",
        *(
            [f"Model calls per episode: {summary.model_calls_per_episode:.1f}."]
            if summary.model_calls_per_episode is not None
            else []
        ),
        *action_lines(summary),
        *notes,
    ]
    return "\n".join([*table, "", *footer])


def understanding_lines(summary: Summary) -> list[str]:
    """Understanding beside success, for runs whose agent read each goal first (`guided`)."""
    read = summary.understanding
    if read is None:
        return []

    def rate(value: SuccessRate | None) -> str:
        return "no episodes" if value is None else our_cell(value)

    return [
        f"Understanding: goal read exactly right in {our_cell(read.grounded)} "
        f"{'texts' if read.grounded.clusters is not None else 'episodes'} "
        f"(could not start: {read.not_started} episodes). Success when read right: "
        f"{rate(read.success_when_right)}; read wrong: {rate(read.success_when_wrong)}.",
    ]


@dataclass(frozen=True)
class GoalStatusTables:
    """A run's tables with and without the goals a do-nothing agent meets or no agent (or not
    the expert its moves are) can meet, the do-nothing agent's row, and the goals left out."""

    heading: str
    tables: list[tuple[str, list[list[str]]]]
    """(title, rows: a header, then rows of cells), in order."""
    left_out: list[str]
    """One line per goal left out, with why."""


def goal_status_tables(
    summary: Summary,
    episodes: Sequence[EpisodeRecord],
    status: GoalStatus,
    *,
    agent: str,
    difficulty: Difficulty,
) -> GoalStatusTables:
    """The run (`episodes`, scored as `summary`) with and without its flagged goals, beside the
    do-nothing agent on the same goals."""
    expert = agent in EXPERT_PLAYED
    kept = status.kept(episodes, expert)
    names = {f"{e.category}/{e.goal_id}" for e in episodes}
    played = [flags for key, flags in status.goals.items() if key in names]
    flagged = {flags.key: flags for flags in played if flags.left_out(expert)}
    without = summarize(kept) if kept else None
    columns = table_columns(summary, difficulty)

    def nothing(column: str, scenario: str | None = None) -> SuccessRate | None:
        return status.do_nothing_rate(
            [
                f
                for f in played
                if column in ("overall", f.category)
                and (scenario is None or f.scenario_class == scenario)
            ]
        )

    label_without = f"this run, without the {len(flagged)} goals below"
    label_nothing = f"do nothing (NOOP only, {status.worlds} worlds per goal)"
    header = ["Model", *(CATEGORY_LABELS[c] for c in columns)]
    main = [
        header,
        ["this run, every goal", *(our_cell(our_rate(summary, c)) for c in columns)],
        [
            label_without,
            *(our_cell(our_rate(without, c) if without else None) for c in columns),
        ],
        [label_nothing, *(our_cell(nothing(c)) for c in columns)],
    ]
    tables = [("", main)]
    if difficulty != "easy":
        tables.append(("By scenario class, every goal:", scenario_rows(summary, difficulty)))
        if without is not None:
            tables.append(
                (f"By scenario class, {label_without}:", scenario_rows(without, difficulty))
            )
        categories = DIFFICULTY_CATEGORIES[difficulty]
        rows = [["Scenario", *(CATEGORY_LABELS[c] for c in categories)]]
        for scenario in SCENARIO_ROWS:
            if any(f.scenario_class == scenario for f in played):
                rows.append([scenario, *(our_cell(nothing(c, scenario)) for c in categories)])
        tables.append((f"By scenario class, {label_nothing}:", rows))
    left_out = [
        f"{flags.key}: {flags.left_out(expert)}"
        + (f" ({flags.do_nothing}/{status.worlds} worlds)" if flags.trivial else "")
        for flags in sorted(flagged.values(), key=lambda f: (f.left_out(expert) or "", f.key))
    ]
    heading = (
        f"Trivial and impossible goals ({len(flagged)} of {len(played)} played; do nothing: "
        f"NOOP only, {status.worlds} seeded worlds per goal, seed {status.seed}, "
        f"{status.max_steps} steps, {status.success_rule} rule; impossible: from the goal and "
        f"{status.variant} Craftax's tables"
        + ("; the scripted expert's reach too, as this run's moves are its" if expert else "")
        + "):"
    )
    return GoalStatusTables(heading=heading, tables=tables, left_out=left_out)


def goal_status_text(tables: GoalStatusTables) -> str:
    lines = [tables.heading]
    for title, rows in tables.tables:
        lines += ["", *([title] if title else []), *_render(rows)]
    lines += ["", f"Left out ({len(tables.left_out)}):", *(f"  {line}" for line in tables.left_out)]
    return "\n".join(lines)


def rescore(episodes: Sequence[EpisodeRecord], rule: SuccessRule) -> list[EpisodeRecord]:
    """The episodes scored under `rule`. An episode whose game ended with its goal met, as the
    game ended or in the new world, succeeds under `game_over_counts` when it was met as the
    game ended and under `official` when it was met in the new world; otherwise it ends as the
    game did."""
    scored = []
    for episode in episodes:
        ending = episode.goal_at_game_over or episode.goal_in_new_world
        if ending is None:
            scored.append(episode)
            continue
        met = episode.goal_at_game_over if rule == "game_over_counts" else episode.goal_in_new_world
        success = met is not None
        bonus = float(success) - float(episode.success)
        scored.append(
            episode.model_copy(
                update={
                    "success": success,
                    "termination": "success" if success else ending,
                    "episode_return": episode.episode_return + bonus,
                }
            )
        )
    return scored


def recorded_rule(results: RunResults) -> SuccessRule:
    """The success rule a run was scored under when played."""
    rule = results.config.get("success_rule")
    return rule if rule in SUCCESS_RULES else _RECORDED_RULE_BEFORE_SETTING


def run_summary(
    results: RunResults,
    episodes: Sequence[EpisodeRecord],
    rule: SuccessRule,
    actions: Mapping[str, Mapping[str, int]] | None = None,
) -> Summary:
    """The metrics of a run's finished `episodes` under `rule`: the summary the runner stored
    with them when it covers exactly these under the rule they were played by, else (a re-score,
    episodes written after the runner's last save, or a summary written before clustered
    intervals and action histograms) computed from the episodes and `actions` (episode id ->
    action -> steps)."""
    stored = results.summary
    if (
        stored is not None
        and rule == recorded_rule(results)
        and results.finished == len(episodes)
        and stored.overall.clusters is not None
        and (stored.actions is not None or actions is None)
    ):
        return stored
    return summarize(rescore(episodes, rule), actions)


def run_actions(
    run_dir: Path, results: RunResults, episodes: Sequence[EpisodeRecord]
) -> dict[str, dict[str, int]] | None:
    """Episode id -> action -> steps of `episodes`: from `results.json` when it holds every
    one, else from the step log; None without one."""
    if all(e.episode_id in results.actions for e in episodes):
        return {e.episode_id: results.actions[e.episode_id].counts for e in episodes}
    path = run_dir / STEPS_FILE
    if not path.is_file():
        return None
    counts = action_counts(read_steps(path, {e.episode_id for e in episodes}))
    return {episode_id: dict(actions) for episode_id, actions in counts.items()}


def paper_differences(results: RunResults, rule: SuccessRule) -> list[str]:
    """How a run departs from the paper's protocol of its difficulty where that changes the
    numbers: variant, dataset splits, step cap, and the success rule it is scored under
    (`rule`)."""
    config = results.config
    difficulty = difficulty_of_run(results)
    paper = protocol_for("paper", difficulty)
    paper_variant: str = paper.value("variant")
    paper_max_steps: int = paper.value("max_steps")
    paper_rule: SuccessRule = paper.value("success_rule")
    differences = []
    variant = config.get("variant")
    if variant != paper_variant:
        differences.append(f"variant: {variant} Craftax (paper: {paper_variant})")
    digests = results.dataset.get("split_sha256")
    source = f"{results.dataset.get('kind', '?')} {results.dataset.get('path', '?')}"
    if not isinstance(digests, dict):
        differences.append(f"dataset: split digests not recorded (source: {source})")
    else:
        splits = dict.fromkeys(category_split(c, difficulty) for c in paper.value("categories"))
        other = [split for split in splits if digests.get(split) != OFFICIAL_SPLIT_SHA256[split]]
        if other:
            differences.append(
                f"dataset: {', '.join(other)} not the official data at {OFFICIAL_COMMIT[:7]} "
                f"(source: {source})"
            )
    max_steps = config.get("max_steps")
    if max_steps != paper_max_steps:
        differences.append(f"step cap: {max_steps} steps (paper: {paper_max_steps})")
    if rule != paper_rule:
        differences.append(
            f"success rule: {rule}, a goal completed on the step the game ends counts "
            f"(paper: {paper_rule}, it does not; try --success-rule official)"
        )
    return differences


def _absent_categories(results: RunResults) -> set[str]:
    goals = results.dataset.get("goals")
    if not isinstance(goals, dict):
        return set()
    return {category for category, count in goals.items() if count == 0}


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
    difficulty: Difficulty = "easy",
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


def model_name_of(results: RunResults) -> str:
    if results.config.get("agent") == "expert":
        return "expert (scripted, no model)"
    model = results.config.get("model")
    return model if isinstance(model, str) and model else "this model"


def run_status(results: RunResults) -> str:
    """One paragraph on how far the run got and what the backend did, for the report."""
    lines = [f"Run status: {results.status} ({results.finished} of {results.scheduled} episodes)."]
    errors = results.backend_errors
    if errors.failed_calls:
        lines.append(
            f"Backend errors: {errors.failed_calls} failed answers, "
            f"{len(errors.aborted_episodes)} episodes cut short (not counted; a rerun plays them)"
            f"; last: {errors.last_error}"
        )
    if results.failure:
        lines.append(f"Stopped by: {results.failure}")
    return "\n".join(lines)


def scheduled_episodes(run_dir: Path, results: RunResults) -> list[EpisodeRecord]:
    """The finished episodes of the run's current schedule (what its summary counts)."""
    path = run_dir / EPISODES_FILE
    if not path.is_file():
        return []
    wanted = set(results.schedule)
    return [episode for episode in read_episodes(path) if episode.episode_id in wanted]


def success_rule_note(
    episodes: Sequence[EpisodeRecord], rule: SuccessRule, played: SuccessRule
) -> str:
    """The report's line on the success rule: which one scores, and the episodes whose game
    ended with the goal met (where the two rules can disagree), counted apart."""
    at_game_over = sum(episode.goal_at_game_over is not None for episode in episodes)
    in_new_world = sum(episode.goal_in_new_world is not None for episode in episodes)
    counted = "a success" if rule == "official" else "not counted"
    return (
        f"Success rule: {rule}"
        + (f" (re-scored; the run was played under {played})" if rule != played else "")
        + f". Goals completed on the step the game ended: {at_game_over}. "
        f"Succeeded on the game-over step, in the new world: {in_new_world} ({counted} "
        "under this rule)."
    )


def report_run(
    run_dir: str | Path,
    *,
    success_rule: SuccessRule | None = None,
    goal_status: bool = False,
    worlds: int = DEFAULT_WORLDS,
) -> str:
    """Rebuild the table (returned) and `success.png` of a run directory, finished or not,
    scored under `success_rule` (None: the rule the run was played under); with `goal_status`,
    then the tables without the goals a do-nothing agent meets (in `worlds` seeded worlds
    each, played once and cached) or that cannot be met, and the do-nothing row."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"run directory {run_dir} does not exist")
    if success_rule is not None and success_rule not in SUCCESS_RULES:
        raise UserError(f"unknown success rule {success_rule!r}; known: {', '.join(SUCCESS_RULES)}")
    results_path = run_dir / RESULTS_FILE
    if not results_path.is_file():
        raise UserError(f"{run_dir} has no {RESULTS_FILE}: it is not a run directory")
    results = read_results(results_path)
    episodes = scheduled_episodes(run_dir, results)
    if not episodes:
        raise UserError(f"no episode of the run in {run_dir} has finished yet")
    played = recorded_rule(results)
    rule = success_rule or played
    notes = [success_rule_note(episodes, rule, played)]
    mixed = code_note(episode.code for episode in episodes)
    if mixed:
        notes.append(mixed)
    actions = run_actions(run_dir, results, episodes)
    summary = run_summary(results, episodes, rule, actions)
    notes += episode_actions_line(actions)
    model_name = model_name_of(results)
    differences = paper_differences(results, rule)
    difficulty = difficulty_of_run(results)
    plot_success(
        summary,
        model_name,
        run_dir / CHART_FILE,
        with_published=not differences,
        difficulty=difficulty,
    )
    table = format_table(
        summary,
        model_name,
        partial=results.status != "complete",
        differences=differences,
        absent=_absent_categories(results) if difficulty == "easy" else (),
        notes=notes,
        difficulty=difficulty,
    )
    achievement_scores = run_scores(results, episodes)
    scores = format_scores(achievement_scores)
    if results.config.get("task") == "open_ended":
        scores += "\n\n" + balrog_rows(achievement_scores.overall, results)
    if not goal_status:
        return f"{table}\n{run_status(results)}\n\n{scores}"
    status = run_goal_status(results.config, episodes, rule=rule, worlds=worlds)
    flagged = goal_status_tables(
        summary,
        rescore(episodes, rule),
        status,
        agent=str(results.config.get("agent", "zero-shot")),
        difficulty=difficulty,
    )
    return f"{table}\n{run_status(results)}\n\n{scores}\n\n{goal_status_text(flagged)}"


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
    run_dir = Path(run_dir)
    if not (run_dir / RESULTS_FILE).is_file():
        raise UserError(f"{run_dir} has no {RESULTS_FILE}: it is not a run directory")
    results = read_results(run_dir / RESULTS_FILE)
    episodes = scheduled_episodes(run_dir, results)
    if not episodes:
        raise UserError(f"no episode of the run in {run_dir} has finished yet")
    agent = results.config.get("agent", "zero-shot")
    name = model_name_of(results)
    label = name if agent == "expert" else f"{name} ({agent})"
    partial = results.status != "complete"
    summary = run_summary(
        results, episodes, recorded_rule(results), run_actions(run_dir, results, episodes)
    )
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
    values["success rule"] = [recorded_rule(run.results) for run in runs]
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
    lines = _render(rows) + notes + comparison_notes(runs)
    scores = compare_scores(runs)
    return "\n".join([*lines, "", scores])


# ------------------------------------------------------------------------------ field scores

#: Runs with at most this many episodes list each episode's scores in the text report (more
#: would drown the table; results.json and `view` hold every episode's).
EPISODE_ROWS_MAX = 20


def run_scores(results: RunResults, episodes: Sequence[EpisodeRecord]) -> RunScores:
    """The field's achievement scores of a run's finished episodes, from their records (no
    replay), over its variant's achievement list; the success rule does not touch them."""
    return score_run(episodes, achievement_list_of(results.config.get("variant")))


def scores_cells(scores: Scores) -> list[str]:
    """Progression ± standard error, Crafter score, craftaxlm score, episodes."""
    return [
        f"{scores.progression:.1f} ± {scores.progression_stderr:.1f}",
        f"{scores.crafter_score:.2f}",
        f"{scores.craftaxlm_score:.2f}",
        str(scores.episodes),
    ]


SCORES_HEADER = ["Progression % ± SE", "Crafter score", "craftaxlm", "n"]


def format_scores(scores: RunScores) -> str:
    """The achievement scores section of the report: overall and per category, the unlock
    table (achievements some episode unlocked), and each episode's for a short run."""
    overall = scores.overall
    groups = (
        {"overall": overall, **scores.by_category}
        if len(scores.by_category) > 1
        else {"overall": overall}
    )
    rows = [["Episodes", *SCORES_HEADER]]
    rows += [[CATEGORY_LABELS.get(k, k), *scores_cells(v)] for k, v in groups.items()]
    unlocked = [name for name, rate in overall.unlock_percent.items() if rate > 0]
    unlock_rows = [["Achievement", *(CATEGORY_LABELS.get(k, k) for k in groups)]]
    unlock_rows += [
        [name.lower(), *(f"{group.unlock_percent[name]:.0f}%" for group in groups.values())]
        for name in unlocked
    ]
    never = len(overall.unlock_percent) - len(unlocked)
    lines = [
        f"Achievement scores, over {overall.label} (BALROG progression, mean ± standard error "
        "as BALROG computes it; Crafter score; craftaxlm score):",
        *_render(rows),
        "",
        f"Unlocked in % of episodes (never unlocked, not listed: {never} of "
        f"{len(overall.unlock_percent)}):",
        *(_render(unlock_rows) if unlocked else ["  none"]),
    ]
    if len(scores.by_episode) <= EPISODE_ROWS_MAX:
        episode_rows = [["Episode", "Unlocked", "Progression %", "Crafter score", "craftaxlm"]]
        episode_rows += [
            [
                episode_id,
                str(e.unlocked),
                f"{e.progression:.1f}",
                f"{e.crafter_score:.2f}",
                f"{e.craftaxlm_score:.2f}",
            ]
            for episode_id, e in scores.by_episode.items()
        ]
        lines += ["", "Per episode:", *_render(episode_rows)]
    else:
        lines.append("Per episode: results.json `scores.by_episode` and `view`.")
    return "\n".join(lines)


def compare_scores(runs: Sequence[ComparedRun]) -> str:
    """The achievement scores of compared runs, a row each (`report --compare`)."""
    rows = [["Run", "Achievements", *SCORES_HEADER]]
    for run in runs:
        overall = run_scores(run.results, run.episodes).overall
        rows.append([run.label, overall.achievement_list, *scores_cells(overall)])
    return "\n".join(
        ["Achievement scores (classic: Crafter's 22; full: Craftax's 67):", *_render(rows)]
    )


#: BALROG's Crafter leaderboard (LLM track; balrog-ai/experiments at 989931c), progression %
#: and its standard error over 10 episodes of up to 2,000 steps: its best rows and its
#: smallest models'.
BALROG_PUBLISHED: tuple[tuple[str, float, float], ...] = (
    ("Grok-4", 57.3, 3.9),
    ("Gemini-2.5-Pro", 55.0, 6.0),
    ("GPT-4o", 33.1, 2.3),
    ("Qwen2.5-7B-it", 16.4, 3.0),
    ("Llama-3.2-1B-it", 12.7, 1.9),
)


def balrog_rows(overall: Scores, results: RunResults) -> str:
    """An open-ended run's progression beside BALROG's published Crafter rows, with what keeps
    them from being strictly comparable (the game, and any balrog setting overridden)."""
    rows = [["Model", "Progression % ± SE", "episodes"]]
    rows.append(
        [
            f"{model_name_of(results)} (this run)",
            f"{overall.progression:.1f} ± {overall.progression_stderr:.1f}",
            str(overall.episodes),
        ]
    )
    rows += [
        [f"{name} (BALROG, published)", f"{p:.1f} ± {e:.1f}", "10"]
        for name, p, e in BALROG_PUBLISHED
    ]
    overrides = results.config.get("protocol_overrides") or []
    caveats = ["Craftax-Classic, not Crafter itself"]
    if results.config.get("protocol") != "balrog":
        caveats.append(f"played under --protocol {results.config.get('protocol')}")
    if overrides:
        caveats.append(f"balrog settings overridden: {', '.join(overrides)}")
    return "\n".join(
        [
            f"BALROG's Crafter leaderboard (LLM track) beside this run ({'; '.join(caveats)}):",
            *_render(rows),
        ]
    )
