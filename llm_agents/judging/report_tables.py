"""The report's text: a run's success table in the paper's layout beside the published rows (for
an EASY run its zero-shot table, `one`, `combo`, `New objects`, with `paraphrased` and overall
when the run has them; for Medium and Hard its Table 2 and a table per scenario class), the
goal-status tables, the achievement-score tables and the run's status lines."""

from __future__ import annotations

import statistics
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

from env.dataset import PAPER_CATEGORIES
from env.goals import DEFAULT_DIFFICULTY, DIFFICULTY_CATEGORIES, Difficulty
from env.rules import SuccessRule
from llm_agents.judging.goal_flags import EXPERT_PLAYED, GoalStatus
from llm_agents.judging.published import (
    BALROG_PUBLISHED,
    PUBLISHED_KIND,
    SCENARIO_ROWS,
    PublishedResult,
    published_for,
)
from llm_agents.judging.rescoring import model_name_of
from llm_agents.run_data.metrics import (
    DOMINANT_SHARE,
    SuccessRate,
    Summary,
    action_histogram,
    summarize,
)
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import RunScores, Scores
from llm_agents.run_data.store import RunResults

NOT_IN_DATASET = "not in this dataset"


CATEGORY_LABELS = {
    "one": "one",
    "combo": "combo",
    "new_objects": "New objects",
    "paraphrased": "Paraphrased",
    "train": "Train",
    "overall": "overall",
}


def chart_categories(summary: Summary, difficulty: Difficulty = DEFAULT_DIFFICULTY) -> list[str]:
    if difficulty != "easy":
        return list(DIFFICULTY_CATEGORIES[difficulty])
    extra = ["paraphrased"] if "paraphrased" in summary.by_category else []
    return [*PAPER_CATEGORIES, *extra]


def table_columns(summary: Summary, difficulty: Difficulty = DEFAULT_DIFFICULTY) -> list[str]:
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


def render_rows(rows: list[list[str]]) -> list[str]:
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
    difficulty: Difficulty = DEFAULT_DIFFICULTY,
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
            *render_rows([header, ours]),
            "",
            f"Published numbers ({PUBLISHED_KIND[difficulty]}), NOT comparable with this run:",
            *(f"  - {difference}" for difference in differences),
            *render_rows([header, *published]),
        ]
    else:
        table = render_rows([header, ours, *published])
    if difficulty != "easy":
        table += [
            "",
            f"By scenario class ({difficulty}):",
            *render_rows(scenario_rows(summary, difficulty)),
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
            [
                f"Prompt tokens computed: {summary.computed_prompt_share:.0%} "
                "(the rest reused from the backend's prefix cache)."
            ]
            if summary.computed_prompt_share is not None
            else []
        ),
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

    lines = [
        f"Understanding: goal read exactly right in {our_cell(read.grounded)} "
        f"{'texts' if read.grounded.clusters is not None else 'episodes'} "
        f"(could not start: {read.not_started} episodes). Success when read right: "
        f"{rate(read.success_when_right)}; read wrong: {rate(read.success_when_wrong)}.",
    ]
    if read.by_category:
        lines += [
            "Reading accuracy (texts read exactly right) beside success:",
            *render_rows(
                [
                    ["Goal set", "Read right", "Success"],
                    *(
                        [CATEGORY_LABELS.get(key, key), our_cell(value), rate(successes.get(key))]
                        for key, value, successes in (
                            *((c, v, summary.by_category) for c, v in read.by_category.items()),
                            *((s, v, read.scenario_success) for s, v in read.by_scenario.items()),
                        )
                    ),
                ]
            ),
        ]
    return lines


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
        lines += ["", *([title] if title else []), *render_rows(rows)]
    lines += ["", f"Left out ({len(tables.left_out)}):", *(f"  {line}" for line in tables.left_out)]
    return "\n".join(lines)


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


#: Runs with at most this many episodes list each episode's scores in the text report (more
#: would drown the table; results.json and `view` hold every episode's).
EPISODE_ROWS_MAX = 20


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
        *render_rows(rows),
        "",
        f"Unlocked in % of episodes (never unlocked, not listed: {never} of "
        f"{len(overall.unlock_percent)}):",
        *(render_rows(unlock_rows) if unlocked else ["  none"]),
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
        lines += ["", "Per episode:", *render_rows(episode_rows)]
    else:
        lines.append("Per episode: results.json `scores.by_episode` and `view`.")
    return "\n".join(lines)


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
            *render_rows(rows),
        ]
    )
