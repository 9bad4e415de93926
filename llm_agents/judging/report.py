"""`craftext-llm report`: a run's report rebuilt from its directory (table, chart, scores, goal
status), beside the published CrafText numbers.

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

from pathlib import Path

from env.errors import UserError
from env.rules import SUCCESS_RULES, SuccessRule
from llm_agents.evaluation.run_view import read_run
from llm_agents.judging.goal_flags import DEFAULT_WORLDS, run_goal_status
from llm_agents.judging.published import paper_differences
from llm_agents.judging.report_chart import CHART_FILE, plot_success
from llm_agents.judging.report_tables import (
    balrog_rows,
    episode_actions_line,
    format_scores,
    format_table,
    goal_status_tables,
    goal_status_text,
    run_status,
    success_rule_note,
)
from llm_agents.judging.rescoring import (
    model_name_of,
    rescore,
    run_actions,
    run_scores,
    run_summary,
)
from llm_agents.run_data.provenance import code_note
from llm_agents.run_data.store import RunResults


def _absent_categories(results: RunResults) -> set[str]:
    goals = results.dataset.get("goals")
    if not isinstance(goals, dict):
        return set()
    return {category for category, count in goals.items() if count == 0}


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
    if success_rule is not None and success_rule not in SUCCESS_RULES:
        raise UserError(f"unknown success rule {success_rule!r}; known: {', '.join(SUCCESS_RULES)}")
    run = read_run(run_dir)
    run_dir, results, episodes = run.path, run.results, run.episodes
    played = run.rule
    rule = success_rule or played
    notes = [success_rule_note(episodes, rule, played)]
    if results.identity.agent is not None:
        notes.append(f"Agent: {results.identity.agent.described()}, from outside craftext-llm.")
    mixed = code_note(episode.code for episode in episodes)
    if mixed:
        notes.append(mixed)
    actions = run_actions(run)
    summary = run_summary(results, episodes, rule, actions)
    notes += episode_actions_line(actions)
    model_name = model_name_of(results)
    differences = paper_differences(results, rule)
    difficulty = run.difficulty
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
        agent=run.agent,
        difficulty=difficulty,
    )
    return f"{table}\n{run_status(results)}\n\n{scores}\n\n{goal_status_text(flagged)}"
