"""Playing a recorded episode again, fed its recorded answers, through the run's own agent and
play loop: the prompts it rebuilds are the ones the run sent (their hashes say so), and at the
chosen steps the run's model is asked the same conversation again (`llm_agents.judging.reask`).

The one way the judging room reaches the play loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from llm_agents.agents.types import NO_PROMPT_HASH, Decision, messages_hash
from llm_agents.backends.base import ChoiceSet, Conversation, ModelAPI, ModelOutput
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.schedule import ScheduledEpisode
from llm_agents.run_data.records import EpisodeRecord, StepRecord

__all__ = ["AskedAgain", "open_run_model", "replay_answers"]


@dataclass
class AskedAgain:
    """One chosen step: what the model answers now, or why its prompt was not rebuilt."""

    step: StepRecord
    now: str | None = None
    """The model's answer now; None when it was not asked."""
    why: str | None = None
    """Why the step's prompt could not be rebuilt."""


def open_run_model(config: EvalConfig, commit: str | None) -> ModelAPI:
    """The model a recorded run names, opened as its runner opens it (at `commit` for a hub id)."""
    from llm_agents.evaluation.runner import open_model

    return open_model(config, commit)


def replay_answers(
    config: EvalConfig,
    env: Any,
    model: ModelAPI,
    spec: ScheduledEpisode,
    recorded: list[StepRecord],
    by_hash: dict[str, StepRecord],
    chosen: list[AskedAgain],
) -> None:
    """Play the episode `spec` again, answered with its `recorded` steps (or, for a prompt it did
    not send itself, the step of `by_hash` that did), asking `model` at each `chosen` step and
    filling in what it says or why the prompt was not rebuilt."""
    from llm_agents.evaluation.play import play_episodes

    sink = _OneEpisode(spec, last_step=chosen[-1].step.step)
    answers = _RecordedAnswers(model, recorded, by_hash, {o.step.step: o for o in chosen}, sink)
    play_episodes(config, env, answers, sink)
    for outcome in chosen:
        if outcome.now is None and outcome.why is None:
            outcome.why = sink.ended_early or "the replayed episode never reached it"


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
        chosen: dict[int, AskedAgain],
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
