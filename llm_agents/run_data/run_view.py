"""One reading of an evaluation run directory: its results, its scheduled finished episodes, its
step log, and what it was played under (protocol, difficulty, success rule, agent, model), read
once and typed, for every command that reads a run (report, card, its verification, the viewer,
the leaderboard).

What the run was played under is read from `results.json` as the run recorded it; runs recorded
before a setting existed played its old value (`recorded_difficulty`, `recorded_rule`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from env.errors import UserError
from env.goals import DIFFICULTY_CATEGORIES, Difficulty
from env.rules import SUCCESS_RULES, SuccessRule
from llm_agents.run_data.records import SKILL_STAGE, EpisodeRecord, StepRecord
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunResults,
    read_episodes,
    read_results,
    read_steps,
    results_kind,
)

__all__ = ["RunView", "read_run", "recorded_difficulty", "recorded_rule"]

# Runs recorded before the difficulty was a setting played EASY.
_RECORDED_DIFFICULTY_BEFORE_SETTING: Difficulty = "easy"
# Runs recorded before the success rule was a setting scored the game-over step as a success.
_RECORDED_RULE_BEFORE_SETTING: SuccessRule = "game_over_counts"
# Runs recorded before the agent was a setting played zero-shot.
_RECORDED_AGENT_BEFORE_SETTING = "zero-shot"


def recorded_difficulty(config: Mapping[str, Any]) -> Difficulty:
    """The difficulty a run whose results record `config` played."""
    difficulty = config.get("difficulty", _RECORDED_DIFFICULTY_BEFORE_SETTING)
    return (
        difficulty if difficulty in DIFFICULTY_CATEGORIES else _RECORDED_DIFFICULTY_BEFORE_SETTING
    )


def recorded_rule(config: Mapping[str, Any]) -> SuccessRule:
    """The success rule a run whose results record `config` was scored under when played."""
    rule = config.get("success_rule")
    return rule if rule in SUCCESS_RULES else _RECORDED_RULE_BEFORE_SETTING


@dataclass
class RunView:
    """An evaluation run directory, read once."""

    path: Path
    results: RunResults
    episodes: list[EpisodeRecord]
    """The finished episodes of the run's schedule as `results.json` lists it, in schedule
    order (`episode_index`)."""
    difficulty: Difficulty
    rule: SuccessRule
    """The success rule the run was played (and scored) under."""
    protocol: str | None
    """The named protocol the run followed; None for runs that predate protocols."""
    agent: str
    _steps: dict[str, list[StepRecord]] | None = field(default=None, repr=False)

    @property
    def config(self) -> dict[str, Any]:
        return self.results.config

    @property
    def has_steps(self) -> bool:
        """Whether the run kept its step log (`--no-record-steps` keeps none)."""
        return (self.path / STEPS_FILE).is_file()

    @property
    def model(self) -> str | None:
        """The model spec that answered, as the run recorded it; None for an agent that asks
        no model (no episode of the run made a model call, and the run pinned no model)."""
        if not self.asked_a_model:
            return None
        spec = self.config.get("model")
        return spec if isinstance(spec, str) and spec else None

    @property
    def asked_a_model(self) -> bool:
        """Whether the agent asked a model, as the records say: a model call or token in an
        episode, or a model commit pinned in the run's identity. Read from the run, never by
        importing the agent (whose package a reader may not have)."""
        if getattr(self.results.identity, "model_revision", None):
            return True
        return any(
            (e.model_calls or 0) > 0 or e.prompt_tokens > 0 or e.completion_tokens > 0
            for e in self.episodes
        )

    def steps(self) -> dict[str, list[StepRecord]]:
        """Episode id -> its steps in order, for the scheduled finished episodes; read from the
        step log on first use, then kept (empty without a step log)."""
        if self._steps is None:
            steps: dict[str, list[StepRecord]] = {e.episode_id: [] for e in self.episodes}
            if self.has_steps:
                for step in read_steps(self.path / STEPS_FILE, set(steps)):
                    steps[step.episode_id].append(step)
            for own in steps.values():
                own.sort(key=lambda step: step.step)
            self._steps = steps
        return self._steps

    def answered_steps(self) -> dict[str, list[StepRecord]]:
        """The steps whose action was read from a model's answer (not chosen by a running
        skill); empty for an agent that asks no model."""
        if not self.asked_a_model:
            return {}
        return {
            episode: [s for s in own if s.parse_stage != SKILL_STAGE]
            for episode, own in self.steps().items()
        }


def read_run(run_dir: str | Path, *, require_episodes: bool = True) -> RunView:
    """The evaluation run in `run_dir`; a `UserError` for a directory that is not one (or,
    with `require_episodes`, one in which no episode has finished)."""
    path = Path(run_dir)
    if not path.is_dir():
        raise UserError(f"run directory {path} does not exist")
    results_path = path / RESULTS_FILE
    if not results_path.is_file():
        raise UserError(f"{path} has no {RESULTS_FILE}: it is not a run directory")
    if results_kind(results_path) != "eval":
        raise UserError(f"{path} is a grounding run, not an evaluation run")
    results = read_results(results_path)
    wanted = set(results.schedule)
    episodes_path = path / EPISODES_FILE
    episodes = (
        [e for e in read_episodes(episodes_path) if e.episode_id in wanted]
        if episodes_path.is_file()
        else []
    )
    if require_episodes and not episodes:
        raise UserError(f"no episode of the run in {path} has finished yet")
    episodes.sort(key=lambda e: e.episode_index)
    protocol = results.config.get("protocol")
    return RunView(
        path=path,
        results=results,
        episodes=episodes,
        difficulty=recorded_difficulty(results.config),
        rule=recorded_rule(results.config),
        protocol=protocol if isinstance(protocol, str) else None,
        agent=str(results.config.get("agent", _RECORDED_AGENT_BEFORE_SETTING)),
    )
