"""A recorded run's figures for a report: its episodes re-scored under either success rule (from
the records alone), its summary and action counts, and its achievement scores. Reading the run
itself is `llm_agents.evaluation.run_view`'s."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from env.goals import Difficulty
from env.rules import SuccessRule
from llm_agents.evaluation.run_view import RunView, recorded_difficulty, recorded_rule
from llm_agents.run_data.metrics import Summary, action_counts, summarize
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import RunScores, achievement_list_of, score_run
from llm_agents.run_data.store import RunResults


def difficulty_of_run(results: RunResults) -> Difficulty:
    """The difficulty a run played."""
    return recorded_difficulty(results.config)


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
        and rule == recorded_rule(results.config)
        and results.finished == len(episodes)
        and stored.overall.clusters is not None
        and (stored.actions is not None or actions is None)
    ):
        return stored
    return summarize(rescore(episodes, rule), actions)


def run_actions(run: RunView) -> dict[str, dict[str, int]] | None:
    """Episode id -> action -> steps of the run's finished episodes: from `results.json` when it
    holds every one, else from the step log; None without one."""
    results, episodes = run.results, run.episodes
    if all(e.episode_id in results.actions for e in episodes):
        return {e.episode_id: results.actions[e.episode_id].counts for e in episodes}
    if not run.has_steps:
        return None
    counts = action_counts(run.step_stream({e.episode_id for e in episodes}))
    return {episode_id: dict(actions) for episode_id, actions in counts.items()}


#: The built-in agents that never ask a model, as a report names their rows.
MODEL_FREE_AGENTS = {"expert": "expert (scripted, no model)", "noop": "noop (NOOP only, no model)"}


def model_name_of(results: RunResults) -> str:
    agent = results.config.get("agent")
    if agent in MODEL_FREE_AGENTS:
        return MODEL_FREE_AGENTS[agent]
    model = results.config.get("model")
    return model if isinstance(model, str) and model else "this model"


def run_scores(results: RunResults, episodes: Sequence[EpisodeRecord]) -> RunScores:
    """The field's achievement scores of a run's finished episodes, from their records (no
    replay), over its variant's achievement list; the success rule does not touch them."""
    return score_run(episodes, achievement_list_of(results.config.get("variant")))
