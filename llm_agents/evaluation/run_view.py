"""One reading of an evaluation run directory: its results, its episode records (every line, and
the scheduled finished episodes by id), its step log as a stream, and what it was played under
(the recorded settings typed, protocol, difficulty, success rule, agent, model, and the schedule
they derive), read once, for every command that reads a run (report, card, its verification,
re-asking, the viewer, the leaderboard, exports). The judging room reads a run only through it.

What the run was played under is read from `results.json` as the run recorded it; runs recorded
before a setting existed played its old value (`recorded_difficulty`, `recorded_rule`).
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from env.dataset import Dataset
from env.errors import UserError
from env.goals import DIFFICULTY_CATEGORIES, Difficulty
from env.rules import SUCCESS_RULES, SuccessRule
from llm_agents.agents.registry import PARSED_ANSWER_AGENTS
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.protocol import PROTOCOL_NAMES, Protocol, protocol_for
from llm_agents.evaluation.schedule import ScheduledEpisode, build_schedule
from llm_agents.run_data.records import SKILL_STAGE, EpisodeRecord, StepRecord
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunResults,
    read_records,
    read_results,
    read_steps,
    results_kind,
)

__all__ = [
    "RunView",
    "ScheduledEpisode",
    "read_run",
    "recorded_difficulty",
    "recorded_rule",
]

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
    order (`episode_index`); where an id is recorded twice, its later line."""
    difficulty: Difficulty
    rule: SuccessRule
    """The success rule the run was played (and scored) under."""
    protocol: str | None
    """The named protocol the run followed; None for runs that predate protocols."""
    agent: str
    records: list[EpisodeRecord] = field(default_factory=list, repr=False)
    """Every line of `episodes.jsonl` in file order: an id recorded twice, or not listed by
    `results.json`, is here as it was written (what a check of the run must see)."""
    _steps: dict[str, list[StepRecord]] | None = field(default=None, repr=False)
    _dataset: Dataset | None = field(default=None, repr=False)

    @cached_property
    def by_id(self) -> dict[str, EpisodeRecord]:
        """`episodes` by episode id."""
        return {e.episode_id: e for e in self.episodes}

    @cached_property
    def settings(self) -> EvalConfig:
        """The settings the run recorded, typed (`EvalConfig.recorded`: a setting it predates
        counts as the value it played)."""
        return EvalConfig.recorded(self.config)

    @property
    def named_protocol(self) -> Protocol | None:
        """The protocol the run followed, at its difficulty; None for a run that predates them."""
        if self.protocol not in PROTOCOL_NAMES:
            return None
        return protocol_for(str(self.protocol), self.difficulty)

    def schedule(self) -> list[ScheduledEpisode]:
        """The episodes the run must hold: its protocol's schedule under the settings it
        recorded, over the dataset here, never the list `results.json` keeps (a `UserError`
        for a run under no named protocol, or when the dataset here is not the run's)."""
        if self.named_protocol is None:
            raise UserError(
                f"the run in {self.path} records no protocol (it predates them): only a run "
                f"under a named protocol ({', '.join(PROTOCOL_NAMES)}) can be checked by replay"
            )
        config = self.settings
        instructions = self.dataset_here().instructions(
            config.categories, include_paraphrases=config.paraphrases, difficulty=config.difficulty
        )
        return build_schedule(config, instructions, None)

    def dataset_here(self) -> Dataset:
        """The dataset the run names, loaded here once (a `UserError` when its digest is not
        the one the run recorded: the run's episodes cannot be derived from it)."""
        if self._dataset is None:
            from env.dataset import load_dataset
            from env.open_ended import open_ended_dataset

            config = self.settings
            if config.task == "open_ended":
                self._dataset = open_ended_dataset()
            else:
                dataset = load_dataset(config.dataset)
                recorded = self.results.identity.dataset
                if recorded is not None and dataset.source.sha256 != recorded:
                    raise UserError(
                        f"the dataset here ({dataset.source.path}, digest "
                        f"{(dataset.source.sha256 or 'none')[:12]}) is not the one the run in "
                        f"{self.path} played (digest {recorded[:12]}): its episodes cannot be "
                        "derived"
                    )
                self._dataset = dataset
        return self._dataset

    def step_stream(self, episodes: Collection[str] | None = None) -> Iterator[StepRecord]:
        """The step log's records in file order, only `episodes`' when given, read a line at a
        time (a Medium run logs tens of millions of steps); nothing without a step log."""
        if self.has_steps:
            yield from read_steps(self.path / STEPS_FILE, episodes)

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
        """Whether the agent asked a model: always for a built-in agent whose actions are parsed
        answers (whatever its records count); else as the records say, a model call or token in
        an episode, or a model commit pinned in the run's identity. Read from the run, never by
        importing the agent (whose package a reader may not have)."""
        if self.agent in PARSED_ANSWER_AGENTS and self.results.identity.agent is None:
            return True
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
            for step in self.step_stream(set(steps)):
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
    records = (
        read_records(episodes_path, EpisodeRecord, repair=False) if episodes_path.is_file() else []
    )
    # The later line of an id recorded twice, as a resumed run's reader keeps it.
    latest = {e.episode_id: e for e in records}
    episodes = [e for e in latest.values() if e.episode_id in wanted]
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
        records=records,
    )
