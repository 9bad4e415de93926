"""Playing plans: each plan's skills carried out in order by the expert's controllers
(`agents.skill_runner`), strictly, in seeded worlds, many episodes in flight on one batched env.

Strictly: a skill that cannot start (its material, tool or station is missing), cannot go on,
or spends its step budget ends the episode as a failure at its step; prerequisites are never
solved for the plan. A skill cut short by an attack starts again. The episode succeeds when the
instruction's checker sees its goal met (the env ends it there); it fails when the game ends
first, or when every skill has played and the goal is not met.

An episode's world comes from (seed, goal, phrasing, world index) alone (`env.episode_key`), so
every candidate plan of a text is played in the same K worlds, whatever the batch.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict

from env.achievements import ACHIEVEMENTS
from env.goals import AnyGoal
from env.termination import Termination
from env.variant import Variant
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.expert.navigation import ExpertEpisode
from llm_agents.agents.skills.catalogue import AnySkill, GoTo
from llm_agents.agents.skills.runner import Finished, SkillRun
from textualizer.observation import Observation

#: Blocks no world starts with: `go to` one fails at once until the plan has placed it.
PLACED_ONLY = frozenset({"crafting_table", "furnace"})
#: Steps one skill may take before it counts as failed (the skills agent's default budget).
SKILL_STEPS = 60


@dataclass(frozen=True)
class PlanEpisode:
    """One plan played in one world."""

    key: str
    """Names the episode in the journal: text, candidate and world."""
    goal: AnyGoal
    text_index: int
    """The phrasing's index among the goal's texts (part of the world's key)."""
    world: int
    skills: tuple[tuple[int, AnySkill], ...]
    """(plan step number, skill) in playing order."""


class EpisodeOutcome(BaseModel):
    """How one plan episode ended."""

    model_config = ConfigDict(frozen=True)

    key: str
    success: bool
    steps: int
    """Environment steps played."""
    failed_step: int | None = None
    """The plan step whose skill failed; None on success or when the plan ran out."""
    failed_skill: str | None = None
    reason: str | None = None
    """Why it failed; None on success."""
    achieved: tuple[str, ...] = ()
    """The achievements unlocked when it ended (names of the 22 shared ids, in id order): how
    far a failed plan got towards its goal, for rewards that teach where no plan succeeds."""


@dataclass
class _Live:
    spec: PlanEpisode
    expert: ExpertEpisode = field(default_factory=lambda: ExpertEpisode((), ()))
    next_skill: int = 0
    run: SkillRun | None = None
    current: tuple[int, AnySkill] | None = None


class _Ended(Exception):
    def __init__(self, outcome: EpisodeOutcome):
        self.outcome = outcome


def _failed(live: _Live, steps: int, reason: str) -> _Ended:
    number, skill = live.current if live.current else (None, None)
    return _Ended(
        EpisodeOutcome(
            key=live.spec.key,
            success=False,
            steps=steps,
            failed_step=number,
            failed_skill=None if skill is None else skill.text,
            reason=reason,
        )
    )


def _action(live: _Live, obs: Observation, steps: int, skill_steps: int) -> str:
    """The next action of the episode's plan, or `_Ended` when the plan failed or ran out."""
    live.expert.world.update(obs)
    while True:
        if live.run is None:
            if live.next_skill >= len(live.spec.skills):
                live.current = None
                raise _failed(live, steps, "every step played; the goal is not met")
            live.current = live.spec.skills[live.next_skill]
            live.next_skill += 1
            skill = live.current[1]
            if (
                isinstance(skill, GoTo)
                and skill.block in PLACED_ONLY
                and not live.expert.world.cells([skill.block])
            ):
                raise _failed(live, steps, f"no {skill.block} placed yet (place one first)")
            live.run = SkillRun(skill, live.expert, obs, skill_steps)
            why = live.run.why_not()
            if why is not None:
                raise _failed(live, steps, why)
        result = live.run.advance(obs)
        if isinstance(result, str):
            return result
        if result.outcome == "interrupted" and live.current is not None:
            # An attack is the world's doing, not the plan's: the same skill starts again.
            live.run = SkillRun(live.current[1], live.expert, obs, skill_steps)
            continue
        if result.outcome != "succeeded":
            raise _failed(live, steps, _reason(result))
        live.run = None


def _reason(finished: Finished) -> str:
    return finished.reason or finished.outcome


def play_plan_episodes(
    episodes: Sequence[PlanEpisode],
    env: object,
    *,
    variant: Variant,
    seed: int,
    batch_size: int,
    on_done: Callable[[list[EpisodeOutcome]], None],
    skill_steps: int = SKILL_STEPS,
) -> None:
    """Play every episode, `batch_size` in flight, handing each round's finished ones to
    `on_done` (in the order they finished)."""
    from env import VectorEnv, episode_key
    from env.scenario_tasks import encode_goals
    from textualizer import observe_batch

    waiting = deque(ep for ep in episodes if not ep.skills)
    if waiting:
        on_done(
            [
                EpisodeOutcome(
                    key=ep.key, success=False, steps=0, reason="no step of the plan was read"
                )
                for ep in waiting
            ]
        )
    queue = deque(ep for ep in episodes if ep.skills)
    if not queue:
        return
    # The batch keeps its size whatever the number of episodes (idle slots are never stepped):
    # another shape would compile the env's functions again.
    size = batch_size
    noop = action_id("NOOP", variant)

    def rows(specs: Sequence[PlanEpisode]) -> tuple[np.ndarray, ...]:
        keys = np.stack([episode_key(seed, s.goal.id, s.text_index, s.world) for s in specs])
        tasks = encode_goals([s.goal for s in specs], variant)
        return keys, tasks.required, tasks.forbidden, tasks.kind, tasks.params

    first = [queue.popleft() for _ in range(min(size, len(queue)))]
    vector = VectorEnv(env, size)  # type: ignore[arg-type]
    host = vector.reset(*rows(first + [first[0]] * (size - len(first))))
    live: dict[int, _Live] = {slot: _Live(spec) for slot, spec in enumerate(first)}
    while live:
        slots = sorted(live)
        observations = observe_batch(host.game, variant, indices=slots)
        actions = np.full(size, noop, dtype=np.int32)
        active = np.zeros(size, dtype=bool)
        ended: list[tuple[int, EpisodeOutcome]] = []
        steps_now = host.steps.tolist()
        for slot, obs in zip(slots, observations, strict=True):
            try:
                actions[slot] = action_id(
                    _action(live[slot], obs, steps_now[slot], skill_steps), variant
                )
                active[slot] = True
            except _Ended as end:
                ended.append((slot, end.outcome))
        if active.any():
            host = vector.step(actions, active)
            termination, steps_after = host.termination.tolist(), host.steps.tolist()
            for slot in np.flatnonzero(active).tolist():
                code = termination[slot]
                if code == Termination.RUNNING:
                    continue
                if code == Termination.SUCCESS:
                    outcome = EpisodeOutcome(
                        key=live[slot].spec.key, success=True, steps=steps_after[slot]
                    )
                else:
                    label = Termination(code).label
                    outcome = _failed(
                        live[slot], steps_after[slot], f"the game ended ({label})"
                    ).outcome
                ended.append((slot, outcome))
        if not ended:
            continue
        unlocked = host.achievements
        on_done(
            [
                outcome.model_copy(
                    update={
                        "achieved": tuple(
                            ACHIEVEMENTS[i] for i in np.flatnonzero(unlocked[slot]).tolist()
                        )
                    }
                )
                for slot, outcome in ended
            ]
        )
        freed = [slot for slot, _ in ended]
        for slot in freed:
            del live[slot]
        refills = [queue.popleft() for _ in range(min(len(freed), len(queue)))]
        if refills:
            taken = sorted(freed)[: len(refills)]
            host = vector.refill(taken, *rows(refills))
            live.update({slot: _Live(spec) for slot, spec in zip(taken, refills, strict=True)})
