"""Asking the model again: whether a run's recorded answers are the ones its model gives.

Replaying a run (`replay_check`) proves its figures follow from its actions, not that the
actions came from the model it names. For a run played greedily, `reask` picks K of its answered
steps (a seeded choice), rebuilds each one's prompt by playing its episode again through the
run's own agent and play loop, fed the recorded answers (the rebuilt prompt's hash must be the
recorded `prompt_hash`), asks the run's model that prompt, and counts the answers that are the
recorded one. A figure, not a verdict: float rounding on other hardware can flip a token.
"""

from __future__ import annotations

import random
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from env.errors import UserError
from llm_agents.agents.types import NO_PROMPT_HASH, Decision, messages_hash
from llm_agents.backends.base import ChoiceSet, Conversation, GenerateConfig, ModelAPI, ModelOutput
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.schedule import ScheduledEpisode
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.run_view import RunView

__all__ = ["ReaskResult", "check_reask", "reask"]


@dataclass(frozen=True)
class ReaskResult:
    """What asking the model again found."""

    asked: int
    """Steps whose rebuilt prompt the model was asked again."""
    same: int
    """Of those, the answers identical to the recorded one."""
    differing: list[str]
    """`episode ID step N: recorded 'X', now 'Y'`, one per answer that differs."""
    not_rebuilt: list[str]
    """Chosen steps whose prompt could not be rebuilt, and why (a changed template, a record
    edited): they were not asked."""
    seconds: float


def reask(
    run: RunView,
    count: int,
    *,
    seed: int = 0,
    model: ModelAPI | None = None,
    progress: bool = False,
) -> ReaskResult:
    """Ask the run's model again for `count` of its answered steps, drawn with `seed` (see
    the module). `model`: the backend to ask (default: the model the run names, opened here;
    `UserError` when it is not at hand). Refuses a run that was not greedy or asked no model."""
    config = check_reask(run, count)
    chosen = _chosen_steps(run, count, seed)
    schedule = {spec.episode_id: spec for spec in _schedule(run, config)}
    started = time.perf_counter()
    asker = model if model is not None else _open(run, config)
    try:
        outcomes = _ask(run, config, asker, schedule, chosen, progress)
    finally:
        if model is None:
            asker.close()
    asked = [o for o in outcomes if o.now is not None]
    return ReaskResult(
        asked=len(asked),
        same=sum(o.now == o.step.raw_output for o in asked),
        differing=[
            f"episode {o.step.episode_id} step {o.step.step}: recorded {o.step.raw_output!r}, "
            f"now {o.now!r}"
            for o in asked
            if o.now != o.step.raw_output
        ],
        not_rebuilt=[
            f"episode {o.step.episode_id} step {o.step.step}: {o.why}" for o in outcomes if o.why
        ],
        seconds=time.perf_counter() - started,
    )


def check_reask(run: RunView, count: int) -> EvalConfig:
    """The run's config, for asking its model again; `UserError` where that cannot be done (no
    model asked, a sampled run, K below 1)."""
    if count < 1:
        raise UserError(
            f"--reask asks the model again for K steps: K must be at least 1, not {count}"
        )
    config = _recorded_config(run)
    if not run.asked_a_model:
        raise UserError(f"--reask asks the run's model again, and the run in {run.path} asked none")
    if config.generation.temperature != 0:
        raise UserError(
            f"--reask needs a greedy run, and the run in {run.path} sampled at temperature "
            f"{config.generation.temperature:g}: its answers are draws, another draw may differ"
        )
    return config


def _recorded_config(run: RunView) -> EvalConfig:
    recorded = EvalConfig.recorded(run.config)
    generation = GenerateConfig.model_validate(run.config.get("generation") or {})
    # One episode at a time: the play loop's trajectories do not depend on the batch.
    return recorded.model_copy(update={"generation": generation, "batch_size": 1})


def _chosen_steps(run: RunView, count: int, seed: int) -> list[StepRecord]:
    answered = [
        step
        for own in run.answered_steps().values()
        for step in own
        if step.prompt_hash != NO_PROMPT_HASH and step.error is None
    ]
    if not answered:
        raise UserError(f"the run in {run.path} records no answered step to ask again")
    picked = random.Random(seed).sample(answered, min(count, len(answered)))
    return sorted(picked, key=lambda step: (step.episode_id, step.step))


def _schedule(run: RunView, config: EvalConfig) -> list[ScheduledEpisode]:
    from llm_agents.evaluation.replay_check import expected_schedule

    schedule = expected_schedule(run)
    if config.plans is None:
        return schedule
    from llm_agents.run_data.plans import load_plans

    try:
        plans = load_plans(config.plans)
    except (OSError, UserError) as err:
        raise UserError(
            f"the run in {run.path} played with the plans in {config.plans}, which cannot be "
            f"read here ({err}): its prompts cannot be rebuilt"
        ) from None
    return [replace(spec, plan=plans.get(spec.instruction.text)) for spec in schedule]


def _open(run: RunView, config: EvalConfig) -> ModelAPI:
    from llm_agents.evaluation.runner import open_model

    spec = run.model
    if spec is None or "***" in spec:
        raise UserError(
            f"the model of the run in {run.path} is not at hand here ({spec or 'none recorded'}): "
            "--reask asks it again"
        )
    commit = getattr(run.results.identity, "model_revision", None)
    try:
        return open_model(config, commit)
    except UserError as err:
        raise UserError(f"the model of the run in {run.path} is not at hand here: {err}") from None


@dataclass
class _Outcome:
    step: StepRecord
    now: str | None = None
    """The model's answer now; None when it was not asked."""
    why: str | None = None
    """Why the step's prompt could not be rebuilt."""


def _ask(
    run: RunView,
    config: EvalConfig,
    model: ModelAPI,
    schedule: dict[str, ScheduledEpisode],
    chosen: list[StepRecord],
    progress: bool,
) -> list[_Outcome]:
    from tqdm import tqdm

    from env import shared_env
    from llm_agents.evaluation.play import play_episodes

    env = shared_env(config.env_config())
    # A prompt some other episode asked (a text a `guided` run read once) answers from there.
    by_hash = {
        step.prompt_hash: step
        for own in run.answered_steps().values()
        for step in own
        if step.prompt_hash != NO_PROMPT_HASH
    }
    wanted: dict[str, list[StepRecord]] = {}
    for step in chosen:
        wanted.setdefault(step.episode_id, []).append(step)
    outcomes: list[_Outcome] = []
    with tqdm(total=len(chosen), desc="re-asking", unit="answer", disable=not progress) as bar:
        for episode_id, steps in wanted.items():
            episode = [_Outcome(step) for step in steps]
            spec = schedule.get(episode_id)
            if spec is None:
                for outcome in episode:
                    outcome.why = "the episode is not in the run's schedule"
            else:
                sink = _OneEpisode(spec, last_step=steps[-1].step)
                answers = _RecordedAnswers(
                    model, run.steps()[episode_id], by_hash, {o.step.step: o for o in episode}, sink
                )
                play_episodes(config, env, answers, sink)
                for outcome in episode:
                    if outcome.now is None and outcome.why is None:
                        outcome.why = sink.ended_early or "the replayed episode never reached it"
            outcomes.extend(episode)
            bar.update(len(steps))
    return outcomes


class _OneEpisode:
    """The play loop's sink for one episode, stopped once its last wanted step is played."""

    def __init__(self, spec: ScheduledEpisode, last_step: int):
        self._pending = [spec]
        self.last_step = last_step
        self.played = 0
        """Steps played so far: the index of the step whose prompt is asked next."""
        self.stopped = False
        self.ended_early: str | None = None

    def take(self, count: int) -> list[ScheduledEpisode]:
        taken, self._pending = self._pending[:count], self._pending[count:]
        return taken

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None:
        self.played += len(steps)
        if self.played > self.last_step:
            self.stopped = True
        elif ended or aborted:
            self.ended_early = "the replayed episode ended before it"
            self.stopped = True

    def stop(self, why: str) -> None:
        self.ended_early, self.stopped = why, True


class _RecordedAnswers(ModelAPI):
    """A backend answering a replayed episode with its recorded answers; at the chosen steps it
    also asks the run's model the same conversation and keeps what it says."""

    backend_name = "recorded"

    def __init__(
        self,
        model: ModelAPI,
        recorded: list[StepRecord],
        by_hash: dict[str, StepRecord],
        chosen: dict[int, _Outcome],
        sink: _OneEpisode,
    ):
        super().__init__(model.model_name, model.config)
        self.model, self.sink, self.chosen = model, sink, chosen
        self.recorded = {step.step: step for step in recorded}
        self.by_hash = by_hash

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        return [self._answer(conversation, choices) for conversation in conversations]

    def check_choice_rule(self, rule: Any) -> None:
        self.model.check_choice_rule(rule)

    def _answer(self, conversation: Conversation, choices: ChoiceSet | None) -> ModelOutput:
        index = self.sink.played
        rebuilt = messages_hash(conversation)
        own = self.recorded.get(index)
        if own is not None and own.prompt_hash != NO_PROMPT_HASH:
            source = own if own.prompt_hash == rebuilt else None
        else:
            source = self.by_hash.get(rebuilt)
        if source is None:
            why = (
                "its prompt, rebuilt, is not the recorded one (another template, or a record "
                "edited)"
            )
            for outcome in self.chosen.values():
                if outcome.step.step >= index and outcome.now is None:
                    outcome.why = why
            self.sink.stop(why)
            return ModelOutput(text="", finish_reason="error", error=why)
        if index in self.chosen:
            self.chosen[index].now = self.model.generate([conversation], choices=choices)[0].text
        return ModelOutput(
            text=source.raw_output,
            reasoning=source.reasoning,
            prompt_tokens=source.prompt_tokens,
            completion_tokens=source.completion_tokens,
            finish_reason=source.finish_reason,
        )
