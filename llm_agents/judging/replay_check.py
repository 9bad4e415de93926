"""Checking a run by replaying it: every figure of a card follows from the actions themselves.

Three checks, each naming the episode and the field that differ:

- **The episodes.** The set of episodes a run must hold is derived from its protocol, every
  setting it played (each compared with the protocol's value, a setting the record leaves out
  counting as its default, and any difference a recorded departure), the dataset (whose digest
  and split digests must be the run's) and the seed: never from the list `results.json` keeps.
  Each must be recorded once (every line of `episodes.jsonl` is read: none is dropped as a
  repeat), with its goal, wording, goal set, scenario class, instruction, seed and world key (a
  missing key is refused, never filled in); none other.
- **The outcomes.** Each episode is re-simulated from the world key the protocol gives and its
  recorded action ids through the environment and its goal's checker (`env.replay`); its steps,
  termination, success, achievements, return and game-over fields must be the recorded ones.
  The replayed outcomes, not the records, are what a card's figures are computed from
  (`ReplayCheck.replayed`).
- **The answers.** For a built-in agent whose actions are parsed answers (decided by the agent
  the run names, never by what its records say of model calls), each recorded raw answer is
  parsed again and must give the recorded action.

Some protocol settings leave no trace a replay can see (how an action was chosen; a step cap no
episode reached): `ReplayCheck.unshown` names them.

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
from llm_agents.backends.base import GenerateConfig
from llm_agents.evaluation.protocol import Protocol, normalised_setting
from llm_agents.evaluation.run_view import RunView, ScheduledEpisode
from llm_agents.run_data.records import NOT_STARTED, EpisodeRecord, StepRecord
from llm_agents.run_data.store import EPISODES_FILE

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
    replayed: list[EpisodeRecord] = field(default_factory=list)
    """The run's episodes as the protocol and the replay give them, in schedule order: goal,
    wording, goal set and world from the protocol's schedule; steps, termination, success,
    achievements, return and game-over fields from the replay; invalid actions from the step
    log; only what no replay can give (tokens, model calls, grounding) from the records."""
    unshown: list[str] = field(default_factory=list)
    """The protocol's settings whose value the records cannot show, each with why (see
    `unshown_settings`)."""


def expected_schedule(run: RunView) -> list[ScheduledEpisode]:
    """The episodes the run must hold: its protocol's schedule under the departures it
    recorded, over the dataset here (a `UserError` when its digest is not the run's, or when
    it played a protocol setting otherwise than its protocol without recording the departure)."""
    if run.named_protocol is not None:
        _check_departures(run, run.named_protocol)
    return run.schedule()


def played_value(run: RunView, setting: str) -> Any:
    """The value the run played `setting` (`NAME` or `generation.NAME`) with: as recorded, or,
    for a setting its record leaves out, the value it then had (the setting's default, or the
    value runs that predate it played)."""
    head, _, leaf = setting.rpartition(".")
    if head == "generation":
        return getattr(GenerateConfig.model_validate(run.config.get("generation") or {}), leaf)
    return getattr(run.settings, leaf)


def _check_departures(run: RunView, protocol: Protocol) -> None:
    """Every protocol setting the run played with another value than its protocol's, a setting
    its record leaves out included (as the value it then had), must be a recorded departure
    (else the schedule derived would not be the protocol's, nor its card's departures true)."""
    departures = set(run.config.get("protocol_overrides") or ())
    for choice in protocol.choices:
        if choice.setting in departures:
            continue
        played = played_value(run, choice.setting)
        if normalised_setting(choice.setting, played) != normalised_setting(
            choice.setting, choice.value
        ):
            raise UserError(
                f"the run in {run.path} played {choice.setting} = {_plain(played)!r}, not its "
                f"protocol's {choice.value!r}, and records no such departure: its results.json "
                "was changed"
            )


def _plain(value: Any) -> Any:
    return getattr(value, "value", value)


def _dataset_differences(run: RunView) -> list[str]:
    """The split digests `results.json` records (in the run's identity and its dataset entry,
    which the comparison with the paper reads) that are not those of the dataset the episodes
    were derived from."""
    here = run.dataset_here().split_sha256()
    differences = []
    recorded_dataset = run.results.dataset.get("split_sha256")
    for where, recorded in (
        ("identity.goals", run.results.identity.goals),
        ("dataset.split_sha256", recorded_dataset if isinstance(recorded_dataset, dict) else {}),
    ):
        for split, digest in sorted(recorded.items()):
            if here.get(split) != digest:
                differences.append(
                    f"results.json: {where}[{split}]: recorded {_shown(digest)}, the dataset "
                    f"the episodes were derived from {_shown(here.get(split))}"
                )
    return differences


def _episode_differences(
    run: RunView, schedule: list[ScheduledEpisode]
) -> tuple[list[str], list[tuple[ScheduledEpisode, EpisodeRecord]]]:
    """Episodes missing, extra, recorded twice or recorded as another one; and each expected
    episode with its record."""
    from env import episode_key

    differences: list[str] = []
    recorded: dict[str, list[EpisodeRecord]] = {}
    # Every line as written: a repeated id is a difference, never silently one record.
    for record in run.records:
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
        goal = spec.instruction.goal
        for name, want, have in (
            ("episode_index", spec.index, record.episode_index),
            ("goal_id", goal.id, record.goal_id),
            ("instruction_variant", spec.instruction.variant, record.instruction_variant),
            ("category", spec.category, record.category),
            ("scenario_class", goal.scenario_class, record.scenario_class),
            ("instruction", spec.instruction.text, record.instruction),
            ("seed", seed, record.seed),
            # A missing key is refused, not filled in: the world is part of what is checked.
            ("reset_key", key.tolist(), record.reset_key),
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
    differences = _dataset_differences(run) + differences
    # Decided by the agent the run names: a record saying no model was asked must not switch
    # the check off. An outside agent's parser is its own, and not here.
    parsed_answers = run.agent in PARSED_ANSWER_AGENTS and run.results.identity.agent is None
    answer_check = (
        _AnswerCheck(variant, action_id(config.fallback_action, variant))
        if parsed_answers
        else None
    )
    logs = _read_log(run, {record.episode_id: record for _, record in pairs}, answer_check)
    answers = 0
    playable = []
    replayed: dict[str, EpisodeRecord] = {}
    for spec, record in pairs:
        log = logs[record.episode_id]
        numbers, actions = log.in_order()
        problems = _step_differences(record, numbers, log.fallbacks)
        if answer_check is not None and not problems:
            answers += log.answers
            problems += [text for _, text in sorted(log.wrong_answers, key=lambda w: w[0])]
        differences += problems
        if record.termination == NOT_STARTED:
            replayed[spec.episode_id] = _as_scheduled(run, spec, record)
            continue
        if not problems or all(": step " in problem for problem in problems):
            playable.append((spec, record, actions))
    replayer = Replayer(shared_env(env_config), batch_size=_BATCH, render=False)
    # Episodes of similar length share a batch, so little of a batch is padding.
    playable.sort(key=lambda item: item[1].steps)
    goals = encode_goals([spec.instruction.goal for spec, _, _ in playable], variant)
    inputs = [
        ReplayInput(
            # The protocol's world, never the recorded key (compared above).
            reset_key=np.asarray(_key(run, spec), np.uint32),
            required=goals.required[row],
            forbidden=goals.forbidden[row],
            actions=actions,
            kind=int(goals.kind[row]),
            params=tuple(int(value) for value in goals.params[row]),
        )
        for row, (spec, record, actions) in enumerate(playable)
    ]
    bar = _bar(len(inputs), progress)
    for (spec, record, _), replay in zip(playable, replayer.replay(inputs), strict=True):
        differences += _outcome_differences(record, replay)
        replayed[spec.episode_id] = _as_replayed(run, spec, record, replay, logs)
        bar.update(1)
    bar.close()
    in_order = [replayed[spec.episode_id] for spec in schedule if spec.episode_id in replayed]
    return ReplayCheck(
        episodes=len(playable),
        answers=answers,
        differences=differences,
        seconds=time.perf_counter() - started,
        model_seconds=math.fsum(log.latency_s for log in logs.values()),
        replayed=in_order,
        unshown=unshown_settings(run, in_order),
    )


def _as_scheduled(run: RunView, spec: ScheduledEpisode, record: EpisodeRecord) -> EpisodeRecord:
    """`record` with what the protocol's schedule says of its episode in place of what it says."""
    goal = spec.instruction.goal
    return record.model_copy(
        update={
            "episode_id": spec.episode_id,
            "goal_id": goal.id,
            "instruction": spec.instruction.text,
            "instruction_variant": spec.instruction.variant,
            "category": spec.category,
            "scenario_class": goal.scenario_class,
            "seed": int(run.config.get("seed", 0)),
            "episode_index": spec.index,
            "reset_key": _key(run, spec),
        }
    )


def _as_replayed(
    run: RunView,
    spec: ScheduledEpisode,
    record: EpisodeRecord,
    replay: Any,
    logs: dict[str, _LoggedEpisode],
) -> EpisodeRecord:
    """The episode as the schedule and its replay give it (see `ReplayCheck.replayed`)."""
    scheduled = _as_scheduled(run, spec, record)
    return scheduled.model_copy(
        update={
            "success": replay.termination == "success",
            "steps": len(logs[record.episode_id].actions)
            if replay.ended_at is None
            else replay.ended_at,
            "termination": replay.termination,
            "episode_return": replay.episode_return,
            "achievements": list(replay.achievements),
            "invalid_actions": logs[record.episode_id].fallbacks,
            "goal_at_game_over": replay.goal_at_game_over,
            "goal_in_new_world": replay.goal_in_new_world,
        }
    )


#: Protocol settings a replay checks by the episode set it derives and the worlds it plays.
_SHOWN_BY_THE_EPISODES = frozenset(
    {"task", "variant", "categories", "episodes_per_instruction", "world_seeding"}
)


def unshown_settings(run: RunView, replayed: list[EpisodeRecord]) -> list[str]:
    """The protocol's settings whose value the run's records cannot show, each with why:
    how an action was chosen (sampling, history, answer length) leaves no trace a replay can
    see; a step cap no episode reached could have been higher; a success rule is seen only
    in an episode whose goal was met as the game ended."""
    protocol = run.named_protocol
    if protocol is None:
        return []
    cap = run.settings.max_steps
    unshown = []
    for choice in protocol.choices:
        setting = choice.setting
        played = _plain(played_value(run, setting))
        if setting in _SHOWN_BY_THE_EPISODES:
            continue
        if setting == "max_steps":
            if not any(e.termination == "timeout" and e.steps == cap for e in replayed):
                unshown.append(
                    f"max_steps = {played}: no episode reached the cap, so a higher one gives "
                    "the same records"
                )
        elif setting == "success_rule":
            if not any(e.goal_at_game_over or e.goal_in_new_world for e in replayed):
                unshown.append(
                    f"success_rule = {played}: no episode met its goal as the game ended, so "
                    "either rule gives the same records"
                )
        else:
            unshown.append(
                f"{setting} = {played!r}: how an action was chosen, which a replay does not see"
            )
    return unshown


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
    # Read by a re-score under the other success rule: a field the replay does not produce
    # would turn a failure into a success there.
    for name in ("goal_at_game_over", "goal_in_new_world"):
        recorded, replayed = getattr(record, name), getattr(replay, name)
        if recorded != replayed:
            differences.append(
                f"{where}: {name}: recorded {_shown(recorded)}, replay {_shown(replayed)}"
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
