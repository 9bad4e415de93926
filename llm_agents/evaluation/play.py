"""The play loop: up to `batch_size` episodes in flight, each stepping as soon as its own answer
arrives, a finished one's slot refilled at once, every step and episode handed to a sink as a
record.

Each round takes every answer that has arrived, steps those episodes together (one masked env
step over the slots; the waiting ones are left untouched, so timing never changes a
trajectory), hands their records to the sink, refills finished slots and sends the next prompts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

import numpy as np

from env.trusted import trusted
from llm_agents.agents import Agent, build_agent
from llm_agents.agents.types import NO_PROMPT_HASH, Decision, EpisodeStart, StepPrompt
from llm_agents.backends.base import ImagePart, ModelAPI
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.dispatch import Dispatcher
from llm_agents.evaluation.schedule import ScheduledEpisode
from llm_agents.run_data.provenance import code_version
from llm_agents.run_data.readings import Grounding, reading_of
from llm_agents.run_data.records import (
    NOT_STARTED,
    SKILL_STAGE,
    EpisodeRecord,
    SkillRecord,
    StepRecord,
)

GameOver = Literal["death", "timeout"] | None


class EpisodeSink(Protocol):
    """What the play loop takes episodes from and hands records to: the run's `RunSink`, or a
    Ray worker's sink, which ships them to the driver's."""

    stopped: bool

    def take(self, count: int) -> list[ScheduledEpisode]: ...

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None: ...


def play_episodes(config: EvalConfig, env: Any, model: ModelAPI, sink: EpisodeSink) -> None:
    """Play the episodes `sink` hands out until it has none left or stops (see the module)."""
    agent: Agent = build_agent(config)
    first = sink.take(config.batch_size)
    if not first:
        return
    slots = _Slots(config, env, agent, first)
    dispatcher = Dispatcher(model, agent.choices, getattr(agent, "output_schema", None))
    try:
        dispatcher.submit(slots.prompts(list(range(slots.size))))
        while not sink.stopped and dispatcher.in_flight:
            decisions = [agent.decide(prompt, output) for prompt, output in dispatcher.wait()]
            slots.step(decisions)
            outcome = slots.settle(decisions)
            # A server answers each request on its own: the continuing episodes' prompts go out
            # before anything is written or a new world generated (tens of ms on a busy CPU). An
            # engine batches what it is handed at once, so it gets them with the refilled ones.
            to_prompt = sorted(outcome.continuing + slots.take_deferred())
            if model.concurrent_requests:
                dispatcher.submit(slots.prompts(to_prompt))
                to_prompt = []
            sink.record(decisions, outcome.steps, outcome.ended, outcome.aborted)
            free = slots.free()
            refilled = slots.refill(sink.take(len(free))) if free else []
            dispatcher.submit(slots.prompts(sorted(to_prompt + refilled)))
    finally:
        dispatcher.close()


@dataclass
class _Tally:
    """What an episode in a slot has collected so far."""

    spec: ScheduledEpisode
    episode_return: float = 0.0
    invalid: int = 0
    prompt_tokens: int = 0
    computed_prompt_tokens: int | None = 0
    """None once some step's backend did not say."""
    completion_tokens: int = 0
    achievements: list[str] = field(default_factory=list)
    grounding: Grounding | None = None
    model_calls: int = 0
    skills: dict[int, SkillRecord] = field(default_factory=dict)
    """`skills`: each decision as it last stood, by its index."""

    def add(self, decision: Decision, reward: float, new: list[str]) -> None:
        self.grounding = decision.grounding or self.grounding
        self.model_calls += decision.prompt_hash != NO_PROMPT_HASH
        for record in decision.skills:
            self.skills[record.index] = record
        self.episode_return += reward
        self.invalid += int(decision.fallback_used)
        self.prompt_tokens += decision.output.prompt_tokens
        computed = decision.output.computed_prompt_tokens
        if decision.prompt_hash != NO_PROMPT_HASH:
            self.computed_prompt_tokens = (
                None
                if computed is None or self.computed_prompt_tokens is None
                else self.computed_prompt_tokens + computed
            )
        self.completion_tokens += decision.output.completion_tokens
        self.achievements.extend(new)


@dataclass
class _Settled:
    """What became of the episodes whose answers a round took."""

    steps: list[StepRecord] = field(default_factory=list)
    ended: list[EpisodeRecord] = field(default_factory=list)
    aborted: list[str] = field(default_factory=list)
    continuing: list[int] = field(default_factory=list)
    """Slots whose episode goes on, in slot order."""


class _Slots:
    """The episodes in flight: which slot plays which, their worlds (one batched env) and the
    agent's episodes, kept in step."""

    def __init__(
        self, config: EvalConfig, env: Any, agent: Agent, first: Sequence[ScheduledEpisode]
    ):
        from env import VectorEnv

        self.config = config
        self.agent = agent
        self.size = len(first)
        self.vector = VectorEnv(env, self.size)
        self.host = self.vector.reset(*self._task_rows(first))
        self.live: dict[int, _Tally] = {}
        self.deferred: set[int] = set()
        #: Per slot, the frames its episode's model was last sent (`--observation image|both`):
        #: the current one last, after up to `frame_history` of the steps before.
        self.frames: dict[int, deque[ImagePart]] = {}
        self._start(list(range(self.size)), first)

    def _task_rows(
        self, specs: Sequence[ScheduledEpisode]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        from env import episode_key
        from env.scenario_tasks import encode_goals

        seed = self.config.seed
        keys = np.stack(
            [
                episode_key(seed, s.instruction.goal.id, s.instruction.variant, s.repeat)
                for s in specs
            ]
        )
        tasks = encode_goals([s.instruction.goal for s in specs], self.config.variant)
        return keys, tasks.required, tasks.forbidden, tasks.kind, tasks.params

    def _start(self, slots: list[int], specs: Sequence[ScheduledEpisode]) -> None:
        for slot, spec in zip(slots, specs, strict=True):
            self.live[slot] = _Tally(spec)
            self.frames[slot] = deque(maxlen=self.config.frame_history + 1)
            self.agent.start_episode(
                slot,
                EpisodeStart(
                    spec.instruction.text, spec.plan, spec.instruction.goal, spec.episode_id
                ),
            )

    def prompts(self, ready: list[int]) -> list[StepPrompt]:
        """The prompts of the slots in `ready`, from their current observations; a slot whose
        prompt the agent defers is kept aside (`take_deferred`) instead."""
        if not ready:
            return []
        from textualizer import observe_batch

        observations = observe_batch(self.host.game, self.config.variant, indices=ready)
        prompts = [self.agent.prepare(s, o) for s, o in zip(ready, observations, strict=True)]
        self.deferred.update(prompt.slot for prompt in prompts if prompt.deferred)
        sent = [prompt for prompt in prompts if not prompt.deferred]
        if self.config.observation == "text" or not sent:
            return sent
        return self._with_frames(sent)

    def _with_frames(self, prompts: list[StepPrompt]) -> list[StepPrompt]:
        """The prompts with their slots' frames on the last message: each slot's current frame
        (drawn now, for every listed slot at once) after those of its previous steps."""
        drawn = self.vector.frames([prompt.slot for prompt in prompts])
        framed = []
        for prompt, frame in zip(prompts, drawn, strict=True):
            frames = self.frames[prompt.slot]
            frames.append(ImagePart.from_frame(frame))
            *earlier, last = prompt.messages
            framed.append(
                replace(
                    prompt, messages=[*earlier, last.model_copy(update={"images": tuple(frames)})]
                )
            )
        return framed

    def take_deferred(self) -> list[int]:
        """The slots whose prompts were deferred (to prepare again now that a round's answers
        are decided), forgotten here."""
        deferred, self.deferred = sorted(self.deferred), set()
        return deferred

    def step(self, decisions: list[Decision]) -> None:
        """Step the decided slots' worlds together; the others stay as they are."""
        actions = np.full(self.size, self.agent.fallback_id, dtype=np.int32)
        active = np.zeros(self.size, dtype=bool)
        for decision in decisions:
            actions[decision.slot] = decision.action
            # An episode whose goal the agent could not read is not played at all.
            active[decision.slot] = not _not_started(decision)
        self.host = self.vector.step(actions, active)

    def settle(self, decisions: list[Decision]) -> _Settled:
        """Tally the stepped slots, record their steps, and close the episodes that ended."""
        host, settled = self.host, _Settled()
        # Each array read once for the round, as Python values: a numpy scalar per slot and
        # field cost more than the rest of a step's bookkeeping.
        rewards, done, steps = host.reward.tolist(), host.done.tolist(), host.steps.tolist()
        unlocked = _unlocked(host.new_achievements)
        for decision in decisions:
            slot = decision.slot
            tally = self.live[slot]
            started = not _not_started(decision)
            new = unlocked.get(slot, []) if started else []
            reward = rewards[slot] if started else 0.0
            tally.add(decision, reward, new)
            if self.config.record_steps and started:
                frame = self.frames[slot][-1] if self.frames[slot] else None
                settled.steps.append(
                    _step_record(tally, decision, steps[slot], done[slot], reward, new, frame)
                )
            if decision.output.finish_reason == "error":
                # The backend failed, not the agent: not scored; a rerun plays it again.
                settled.aborted.append(tally.spec.episode_id)
            elif not started:
                settled.ended.append(_episode_record(tally, 0, None, self.config.seed))
            elif done[slot]:
                settled.ended.append(self._episode_record(tally, slot))
            else:
                settled.continuing.append(slot)
                continue
            self.agent.end_episode(slot)
            del self.live[slot]
            del self.frames[slot]
        settled.continuing.sort()
        return settled

    def _episode_record(self, tally: _Tally, slot: int) -> EpisodeRecord:
        host = self.host
        ending: GameOver = "death" if host.game.player_health[slot] <= 0 else "timeout"
        return _episode_record(
            tally,
            int(host.steps[slot]),
            int(host.termination[slot]),
            self.config.seed,
            ending if host.goal_at_game_over[slot] else None,
            ending if host.goal_in_new_world[slot] else None,
        )

    def free(self) -> list[int]:
        """Slots without an episode, in order."""
        return [s for s in range(self.size) if s not in self.live]

    def refill(self, specs: Sequence[ScheduledEpisode]) -> list[int]:
        """Start `specs` in the first free slots (fresh worlds); the slots they took."""
        if not specs:
            return []
        slots = self.free()[: len(specs)]
        self.host = self.vector.refill(slots, *self._task_rows(specs))
        self._start(slots, specs)
        return slots


def _unlocked(new_achievements: np.ndarray) -> dict[int, list[str]]:
    """Slot -> the names of the achievements it unlocked on its last step, in id order (slots
    that unlocked none are left out)."""
    from env.achievements import ACHIEVEMENTS

    found: dict[int, list[str]] = {}
    slots, ids = np.nonzero(new_achievements)
    for slot, index in zip(slots.tolist(), ids.tolist(), strict=True):
        found.setdefault(slot, []).append(ACHIEVEMENTS[index])
    return found


def _not_started(decision: Decision) -> bool:
    return decision.grounding is not None and decision.grounding.reading is None


def _step_record(
    tally: _Tally,
    decision: Decision,
    steps: int,
    done: bool,
    reward: float,
    new: list[str],
    frame: ImagePart | None,
) -> StepRecord:
    """The record of a step that took the episode to `steps` steps (`done`: its last)."""
    # Unvalidated: every value is made here, of its field's type (the runner's tests read the
    # records back through validation).
    return trusted(
        StepRecord,
        episode_id=tally.spec.episode_id,
        step=steps - 1,
        observation=decision.observation_text,
        frame_png=frame.png_base64 if frame is not None else None,
        prompt_hash=decision.prompt_hash,
        raw_output=decision.output.text,
        reasoning=decision.output.reasoning,
        action_name=decision.name,
        action_id=decision.action,
        parse_stage=decision.parse.stage,
        fallback_used=decision.fallback_used,
        reward=reward,
        done=done,
        new_achievements=new,
        prompt_tokens=decision.output.prompt_tokens,
        computed_prompt_tokens=decision.output.computed_prompt_tokens,
        completion_tokens=decision.output.completion_tokens,
        latency_s=decision.output.latency_s,
        finish_reason=decision.output.finish_reason,
        error=decision.output.error,
        cached=decision.output.cached,
        followups=decision.output.followups,
        options_shown=list(decision.options_shown) if decision.options_shown else None,
        skill=decision.skills[-1].label
        if decision.skills and decision.parse.stage != SKILL_STAGE
        else None,
    )


def _episode_record(
    tally: _Tally,
    steps: int,
    termination: int | None,
    seed: int,
    goal_at_game_over: GameOver = None,
    goal_in_new_world: GameOver = None,
) -> EpisodeRecord:
    """The record of a finished episode; `termination` None: it could not start."""
    from env import Termination, episode_key

    spec, grounding = tally.spec, tally.grounding
    return EpisodeRecord(
        episode_id=spec.episode_id,
        goal_id=spec.instruction.goal.id,
        instruction=spec.instruction.text,
        instruction_variant=spec.instruction.variant,
        category=spec.category,
        scenario_class=spec.instruction.goal.scenario_class,
        seed=seed,
        episode_index=spec.index,
        success=termination == Termination.SUCCESS,
        steps=steps,
        termination=NOT_STARTED if termination is None else Termination(termination).label,
        episode_return=tally.episode_return,
        invalid_actions=tally.invalid,
        prompt_tokens=tally.prompt_tokens,
        computed_prompt_tokens=tally.computed_prompt_tokens,
        completion_tokens=tally.completion_tokens,
        achievements=tally.achievements,
        plan_given=spec.plan is not None,
        goal_at_game_over=goal_at_game_over,
        goal_in_new_world=goal_in_new_world,
        grounding=grounding,
        grounding_correct=None
        if grounding is None
        else grounding.matches(reading_of(spec.instruction.goal)),
        reset_key=episode_key(
            seed, spec.instruction.goal.id, spec.instruction.variant, spec.repeat
        ).tolist(),
        code=code_version(),
        model_calls=tally.model_calls,
        skills=[
            record
            if record.outcome != "running"
            else record.model_copy(update={"outcome": "unfinished"})
            for _, record in sorted(tally.skills.items())
        ]
        if tally.skills
        else None,
    )
