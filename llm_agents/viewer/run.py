"""Reading a run directory for the viewer: results, episodes, their steps and their goals."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from env.dataset import load_dataset
from env.errors import UserError
from env.goals import AnyGoal, Difficulty, run_category
from env.open_ended import open_ended_dataset
from llm_agents.evaluation.run_view import RunView, read_run
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.store import EPISODES_FILE, RESULTS_FILE, RunResults


@dataclass
class EpisodeView:
    """One finished episode with its steps and what its replay needs."""

    record: EpisodeRecord
    steps: list[StepRecord]
    errors: list[str]
    """Backend error text of each step whose record carries one (empty when none do)."""
    goal: AnyGoal | None
    """The episode's goal in the run's dataset; None when the dataset no longer has it."""
    unreplayable: str | None = None
    """Why the episode cannot be replayed; None when it can."""

    @property
    def page(self) -> str:
        """File name of the episode's page, relative to the report's episodes/ folder."""
        return f"episode-{self.record.episode_index:05d}.html"

    @property
    def sheet(self) -> str:
        """File name of the episode's frame sheet, beside its page."""
        return f"episode-{self.record.episode_index:05d}.png"

    def reset_key(self) -> np.ndarray:
        """The episode's key (its world's reset key): recorded, or derived as the runner did."""
        if self.record.reset_key is not None:
            return np.asarray(self.record.reset_key, dtype=np.uint32)
        from env import episode_key

        # Records written before reset_key existed: the repeat is the id's last field
        # (`ScheduledEpisode.episode_id`).
        repeat = int(self.record.episode_id.rsplit("/", 1)[-1])
        return episode_key(
            self.record.seed, self.record.goal_id, self.record.instruction_variant, repeat
        )


@dataclass
class LoadedRun:
    """A run directory as the viewer sees it: the run read once (`RunView`) and each finished
    episode with its steps and goal."""

    run: RunView
    episodes: list[EpisodeView]
    parse_stages: dict[str, int] = field(default_factory=dict)
    latencies: list[float] = field(default_factory=list)

    @property
    def path(self) -> Path:
        return self.run.path

    @property
    def results(self) -> RunResults:
        return self.run.results

    @property
    def config(self) -> dict[str, Any]:
        return self.run.config

    @property
    def has_steps(self) -> bool:
        return self.run.has_steps

    def find(self, episode: str) -> EpisodeView:
        """An episode by its id or by its schedule index."""
        for view in self.episodes:
            if view.record.episode_id == episode or str(view.record.episode_index) == episode:
                return view
        raise UserError(
            f"{self.path} has no finished episode {episode!r} (give an episode id such as "
            f"{self.episodes[0].record.episode_id!r}, or its index)"
        )


def load_run(run_dir: str | Path) -> LoadedRun:
    """Read `run_dir`'s results, finished episodes and (when recorded) their steps."""
    path = Path(run_dir)
    if path.is_dir() and not (path / EPISODES_FILE).is_file() and (path / RESULTS_FILE).is_file():
        raise UserError(f"{path} has no {EPISODES_FILE}: no episode finished")
    run = read_run(path)
    steps = run.steps()
    stages: dict[str, int] = {}
    latencies: list[float] = []
    for own in steps.values():
        for step in own:
            stages[step.parse_stage] = stages.get(step.parse_stage, 0) + 1
            latencies.append(step.latency_s)
    try:
        goals = goals_of_run(run)
        no_dataset = None
    except UserError as exc:
        # The pages are still worth having; only the replays need the goals.
        goals, no_dataset = {}, f"the run's dataset cannot be loaded ({exc})"
    episodes = []
    for record in run.episodes:
        own = steps.get(record.episode_id, [])
        view = EpisodeView(
            record=record,
            steps=own,
            errors=[step.error for step in own if step.error],
            goal=goals.get((record.category, record.goal_id)),
        )
        view.unreplayable = no_dataset or _why_unreplayable(view, has_steps=run.has_steps)
        episodes.append(view)
    return LoadedRun(
        run=run,
        episodes=episodes,
        parse_stages=dict(sorted(stages.items(), key=lambda item: -item[1])),
        latencies=latencies,
    )


def goals_of_run(run: RunView) -> dict[tuple[str, str], AnyGoal]:
    """(category, goal id) -> goal, of the run's difficulty in the dataset it names."""
    return _goals(run.config.get("dataset"), run.difficulty, run.config.get("task"))


def _goals(
    dataset: Any, difficulty: Difficulty, task: Any = None
) -> dict[tuple[str, str], AnyGoal]:
    # The open-ended task's one goal is ours, in no dataset.
    if task == "open_ended":
        data = open_ended_dataset()
    else:
        data = load_dataset(dataset if isinstance(dataset, str) else None)
    return {
        (run_category(goal), goal.id): goal for goal in data.goals if goal.difficulty == difficulty
    }


def _why_unreplayable(view: EpisodeView, *, has_steps: bool) -> str | None:
    if not has_steps:
        return "the run kept no step log (--no-record-steps): nothing to replay"
    if view.goal is None:
        return f"goal {view.record.goal_id!r} is not in the run's dataset any more"
    indices = [step.step for step in view.steps]
    if indices != list(range(view.record.steps)):
        return (
            f"the step log holds {len(indices)} of the episode's {view.record.steps} steps "
            "(or not in order)"
        )
    return None
