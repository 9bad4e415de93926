"""Checking a run by replaying it: every figure of a card follows from the actions themselves.

Three checks, each naming the episode and the field that differ:

- **The episodes.** The set of episodes a run must hold is derived from its protocol, the
  departures it recorded from it (`protocol_overrides`, `--limit`, the paraphrases), the
  dataset (whose digest must be the run's) and the seed: never from the list `results.json`
  keeps. Each must be recorded once, with its goal, instruction, seed and world key; none other.
- **The outcomes.** Each episode is re-simulated from its world key and its recorded action ids
  through the environment and its goal's checker (`env.replay`); its steps, termination,
  success, achievements and return must be the recorded ones.
- **The answers.** For an agent whose actions are parsed answers, each recorded raw answer is
  parsed again and must give the recorded action.

None of them can tell where the actions came from: a run fabricated whole, with actions taken
from elsewhere, replays fine (`llm_agents.judging.reask` asks the model again for that).
"""

from __future__ import annotations

import logging
import math
import time
from array import array
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from env.errors import UserError
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.answers.lettered import LetteredOptions
from llm_agents.agents.answers.parser import parse_action
from llm_agents.agents.registry import PARSED_ANSWER_AGENTS
from llm_agents.evaluation.protocol import normalised_setting, protocol_for
from llm_agents.evaluation.run_view import RunView, ScheduledEpisode
from llm_agents.run_data.records import NOT_STARTED, EpisodeRecord, StepRecord
from llm_agents.run_data.store import EPISODES_FILE, read_episodes

__all__ = ["ReplayCheck", "RunDoesNotReplay", "check_run", "expected_schedule"]

logger = logging.getLogger(__name__)

#: Episodes replayed per batch: large batches keep the cores busy on long episodes.
_BATCH = 32
#: Returns equal to this are the same (float32 sums of the environment's rewards).
_RETURN_TOLERANCE = 1e-4


class RunDoesNotReplay(Exception):
    """A run whose records its replay does not give."""

    def __init__(self, run_dir: Any, differences: list[str]):
        self.differences = differences
        shown = "; ".join(differences[:3])
        more = f" (and {len(differences) - 3} more)" if len(differences) > 3 else ""
        super().__init__(
            f"the records in {run_dir} do not replay: {len(differences)} differences: {shown}{more}"
        )


@dataclass(frozen=True)
class ReplayCheck:
    """What checking a run by replay found."""

    episodes: int
    """Episodes replayed."""
    answers: int
    """Recorded answers parsed again (0 for an agent whose actions are not parsed answers)."""
    differences: list[str]
    """Each as `episode ID: FIELD: recorded X, replay Y`; empty when the run replays."""
    seconds: float
    model_seconds: float = 0.0
    """The logged steps' summed model latency (read in the same pass as their actions)."""


def expected_schedule(run: RunView) -> list[ScheduledEpisode]:
    """The episodes the run must hold: its protocol's schedule under the departures it
    recorded, over the dataset here (a `UserError` when its digest is not the run's)."""
    if run.named_protocol is not None:
        _check_departures(run)
    return run.schedule()


def _check_departures(run: RunView) -> None:
    """Every protocol setting the run played with another value than its protocol's must be
    a recorded departure (else the schedule derived would not be the protocol's)."""

    protocol = protocol_for(str(run.protocol), run.difficulty)
    departures = set(run.config.get("protocol_overrides") or ())
    for choice in protocol.choices:
        if choice.setting in departures:
            continue
        head, _, leaf = choice.setting.rpartition(".")
        table = run.config.get(head, {}) if head else run.config
        if leaf not in table:
            continue
        if normalised_setting(choice.setting, table[leaf]) != normalised_setting(
            choice.setting, choice.value
        ):
            raise UserError(
                f"the run in {run.path} played {choice.setting} = {table[leaf]!r}, not its "
                f"protocol's {choice.value!r}, and records no such departure: its results.json "
                "was changed"
            )


def _episode_differences(
    run: RunView, schedule: list[ScheduledEpisode]
) -> tuple[list[str], list[tuple[ScheduledEpisode, EpisodeRecord]]]:
    """Episodes missing, extra, recorded twice or recorded as another one; and each expected
    episode with its record."""
    from env import episode_key

    differences: list[str] = []
    recorded: dict[str, list[EpisodeRecord]] = {}
    for record in read_episodes(run.path / EPISODES_FILE):
        recorded.setdefault(record.episode_id, []).append(record)
    expected = {spec.episode_id: spec for spec in schedule}
    for extra in sorted(recorded.keys() - expected.keys()):
        differences.append(f"episode {extra}: not an episode of the run's protocol (extra)")
    for listed in sorted(set(run.results.schedule) - expected.keys()):
        if listed not in recorded:
            differences.append(
                f"episode {listed}: listed by results.json, not an episode of the protocol"
            )
    seed = int(run.config.get("seed", 0))
    pairs = []
    for spec in schedule:
        records = recorded.get(spec.episode_id, [])
        if not records:
            differences.append(f"episode {spec.episode_id}: missing from {EPISODES_FILE}")
            continue
        if len(records) > 1:
            differences.append(f"episode {spec.episode_id}: recorded {len(records)} times")
        record = records[-1]
        key = episode_key(seed, spec.instruction.goal.id, spec.instruction.variant, spec.repeat)
        for name, want, have in (
            ("episode_index", spec.index, record.episode_index),
            ("instruction", spec.instruction.text, record.instruction),
            ("seed", seed, record.seed),
            ("reset_key", key.tolist(), record.reset_key or key.tolist()),
        ):
            if want != have:
                differences.append(
                    f"episode {spec.episode_id}: {name}: recorded {_shown(have)}, "
                    f"protocol {_shown(want)}"
                )
        pairs.append((spec, record))
    return differences, pairs


@dataclass
class _LoggedEpisode:
    """One episode's step log as the check keeps it: step numbers and action ids in compact
    arrays (a Medium run logs tens of millions of steps), the fallbacks counted, and each
    answer parsed again as its step is read."""

    numbers: array[int] = field(default_factory=lambda: array("i"))
    actions: array[int] = field(default_factory=lambda: array("i"))
    fallbacks: int = 0
    latency_s: float = 0.0
    answers: int = 0
    wrong_answers: list[tuple[int, str]] = field(default_factory=list)

    def in_order(self) -> tuple[list[int], array[int]]:
        """Step numbers and actions sorted by step number (the log's order is the play's)."""
        numbers = list(self.numbers)
        if numbers == sorted(numbers):
            return numbers, self.actions
        order = sorted(range(len(numbers)), key=numbers.__getitem__)
        return [numbers[i] for i in order], array("i", (self.actions[i] for i in order))


class _AnswerCheck:
    """Parses each recorded raw answer again against its recorded action."""

    def __init__(self, variant: Any, fallback: int):
        self.variant = variant
        self.fallback = fallback

    def __call__(self, record: EpisodeRecord, step: StepRecord, logged: _LoggedEpisode) -> None:
        if step.finish_reason == "error" or step.skill is not None:
            return
        answer = step.raw_output
        if step.options_shown is not None:
            answer = LetteredOptions(order=step.options_shown).option_of(answer) or ""
        result = parse_action(answer, self.variant, prompt=[step.observation, record.instruction])
        action = self.fallback if result.action is None else result.action
        logged.answers += 1
        if action != step.action_id or (result.action is None) != step.fallback_used:
            name = self.variant.action_names[action]
            logged.wrong_answers.append(
                (
                    step.step,
                    f"episode {record.episode_id}: step {step.step} action: recorded "
                    f"{step.action_name}, the answer {_shown(step.raw_output)} gives {name}",
                )
            )


def _read_log(
    run: RunView, records: dict[str, EpisodeRecord], answers: _AnswerCheck | None
) -> dict[str, _LoggedEpisode]:
    """The step log of `records`' episodes, read line by line into compact arrays (never the
    whole log's records in memory at once)."""
    logged = {episode_id: _LoggedEpisode() for episode_id in records}
    for step in run.step_stream(logged.keys()):
        own = logged[step.episode_id]
        own.numbers.append(step.step)
        own.actions.append(step.action_id)
        own.fallbacks += step.fallback_used
        own.latency_s += step.latency_s
        if answers is not None:
            answers(records[step.episode_id], step, own)
    return logged


def _step_differences(record: EpisodeRecord, numbers: list[int], fallbacks: int) -> list[str]:
    where = f"episode {record.episode_id}"
    if numbers != list(range(record.steps)):
        return [
            f"{where}: steps: recorded {record.steps}, the step log holds {len(numbers)} "
            "(or out of order)"
        ]
    if fallbacks != record.invalid_actions:
        return [f"{where}: invalid_actions: recorded {record.invalid_actions}, steps {fallbacks}"]
    return []


def check_run(run: RunView, *, progress: bool = False) -> ReplayCheck:
    """Check `run` by replay (see the module); a `UserError` when it cannot be checked at all
    (no protocol, no step log, another dataset)."""
    from env import EnvConfig, shared_env
    from env.replay import Replayer, ReplayInput
    from env.scenario_tasks import encode_goals

    started = time.perf_counter()
    if not run.has_steps:
        raise UserError(
            f"the run in {run.path} kept no step log (--no-record-steps): its episodes cannot "
            "be replayed"
        )
    schedule = expected_schedule(run)
    differences, pairs = _episode_differences(run, schedule)
    config = run.settings
    env_config = EnvConfig.model_validate_json(config.env_config().model_dump_json())
    variant = env_config.variant
    parsed_answers = (
        run.agent in PARSED_ANSWER_AGENTS
        and run.results.identity.agent is None
        and run.asked_a_model
    )
    answer_check = (
        _AnswerCheck(variant, action_id(config.fallback_action, variant))
        if parsed_answers
        else None
    )
    logs = _read_log(run, {record.episode_id: record for _, record in pairs}, answer_check)
    answers = 0
    playable = []
    for spec, record in pairs:
        log = logs[record.episode_id]
        numbers, actions = log.in_order()
        problems = _step_differences(record, numbers, log.fallbacks)
        if answer_check is not None and not problems:
            answers += log.answers
            problems += [text for _, text in sorted(log.wrong_answers, key=lambda w: w[0])]
        differences += problems
        if record.termination == NOT_STARTED:
            continue
        if not problems or all(": step " in problem for problem in problems):
            playable.append((spec, record, actions))
    replayer = Replayer(shared_env(env_config), batch_size=_BATCH, render=False)
    # Episodes of similar length share a batch, so little of a batch is padding.
    playable.sort(key=lambda item: item[1].steps)
    goals = encode_goals([spec.instruction.goal for spec, _, _ in playable], variant)
    inputs = [
        ReplayInput(
            reset_key=np.asarray(record.reset_key or _key(run, spec), np.uint32),
            required=goals.required[row],
            forbidden=goals.forbidden[row],
            actions=actions,
            kind=int(goals.kind[row]),
            params=tuple(int(value) for value in goals.params[row]),
        )
        for row, (spec, record, actions) in enumerate(playable)
    ]
    bar = _bar(len(inputs), progress)
    for (_, record, _), replay in zip(playable, replayer.replay(inputs), strict=True):
        differences += _outcome_differences(record, replay)
        bar.update(1)
    bar.close()
    return ReplayCheck(
        episodes=len(playable),
        answers=answers,
        differences=differences,
        seconds=time.perf_counter() - started,
        model_seconds=math.fsum(log.latency_s for log in logs.values()),
    )


def _key(run: RunView, spec: ScheduledEpisode) -> list[int]:
    from env import episode_key

    seed = int(run.config.get("seed", 0))
    return episode_key(
        seed, spec.instruction.goal.id, spec.instruction.variant, spec.repeat
    ).tolist()


def _outcome_differences(record: EpisodeRecord, replay: Any) -> list[str]:
    where = f"episode {record.episode_id}"
    differences = []
    if replay.ended_at != record.steps:
        ended = "never ends" if replay.ended_at is None else f"ends after {replay.ended_at}"
        differences.append(f"{where}: steps: recorded {record.steps}, the replay {ended}")
    if replay.termination != record.termination:
        differences.append(
            f"{where}: termination: recorded {record.termination}, replay {replay.termination}"
        )
    if (replay.termination == "success") != record.success:
        differences.append(
            f"{where}: success: recorded {record.success}, replay {replay.termination == 'success'}"
        )
    if replay.achievements != record.achievements:
        differences.append(
            f"{where}: achievements: recorded {record.achievements or 'none'}, replay "
            f"{replay.achievements or 'none'}"
        )
    if not math.isclose(
        replay.episode_return, record.episode_return, rel_tol=0, abs_tol=_RETURN_TOLERANCE
    ):
        differences.append(
            f"{where}: episode_return: recorded {record.episode_return:.4f}, replay "
            f"{replay.episode_return:.4f}"
        )
    return differences


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _NoBar:
    def update(self, count: int) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, progress: bool) -> Any:
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    # Hidden where stderr is no terminal (a log, a test).
    return tqdm(total=total, unit="episode", desc="replaying", leave=False, disable=None)
