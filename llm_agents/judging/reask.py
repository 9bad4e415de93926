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
from dataclasses import dataclass, replace

from env.errors import UserError
from llm_agents.agents.types import NO_PROMPT_HASH
from llm_agents.backends.base import GenerateConfig, ModelAPI
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.replay import AskedAgain, open_run_model, replay_answers
from llm_agents.evaluation.run_view import RunView, ScheduledEpisode
from llm_agents.run_data.records import StepRecord

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
    from llm_agents.judging.replay_check import expected_schedule

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
    spec = run.model
    if spec is None or "***" in spec:
        raise UserError(
            f"the model of the run in {run.path} is not at hand here ({spec or 'none recorded'}): "
            "--reask asks it again"
        )
    commit = getattr(run.results.identity, "model_revision", None)
    try:
        return open_run_model(config, commit)
    except UserError as err:
        raise UserError(f"the model of the run in {run.path} is not at hand here: {err}") from None


def _ask(
    run: RunView,
    config: EvalConfig,
    model: ModelAPI,
    schedule: dict[str, ScheduledEpisode],
    chosen: list[StepRecord],
    progress: bool,
) -> list[AskedAgain]:
    from tqdm import tqdm

    from env import shared_env

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
    outcomes: list[AskedAgain] = []
    with tqdm(total=len(chosen), desc="re-asking", unit="answer", disable=not progress) as bar:
        for episode_id, steps in wanted.items():
            episode = [AskedAgain(step) for step in steps]
            spec = schedule.get(episode_id)
            if spec is None:
                for outcome in episode:
                    outcome.why = "the episode is not in the run's schedule"
            else:
                replay_answers(config, env, model, spec, run.steps()[episode_id], by_hash, episode)
            outcomes.extend(episode)
            bar.update(len(steps))
    return outcomes
