"""The evaluation runner: N episodes in lockstep, resumable, written as it goes.

Each loop iteration makes one batched env step, one batched textualization and one batched
model call for all live episodes; a finished episode's slot is refilled from the schedule so the
batch stays full.

The output directory holds `steps.jsonl` (a line per agent step), `episodes.jsonl` (a line per
finished episode) and `results.json` (resolved config, versions, dataset source, summary). A run
killed at any point and restarted on the same directory redoes only the episodes that had not
finished: episode worlds derive from their own keys, so with a deterministic backend the resumed
run ends with exactly the results of an uninterrupted one.
"""

from __future__ import annotations

import importlib.metadata
import json
import logging
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from env.dataset import Instruction, load_dataset
from env.errors import UserError
from llm_agents.agents import Agent, build_agent
from llm_agents.agents.zero_shot import Decision
from llm_agents.backends.base import ModelAPI
from llm_agents.config import EvalConfig
from llm_agents.metrics import Summary, summarize
from llm_agents.records import (
    EpisodeRecord,
    RunResults,
    StepRecord,
    append_records,
    read_episodes,
    read_results,
    write_results,
)

logger = logging.getLogger(__name__)

STEPS_FILE = "steps.jsonl"
EPISODES_FILE = "episodes.jsonl"
RESULTS_FILE = "results.json"


@dataclass(frozen=True)
class ScheduledEpisode:
    """One episode of the run's schedule."""

    index: int
    instruction: Instruction
    repeat: int
    plan: str | None

    @property
    def category(self) -> str:
        return self.instruction.goal.category

    @property
    def episode_id(self) -> str:
        return (
            f"{self.category}/{self.instruction.goal.id}/{self.instruction.variant}/{self.repeat}"
        )


@dataclass
class _Live:
    """Bookkeeping of the episode running in one slot."""

    spec: ScheduledEpisode
    episode_return: float = 0.0
    invalid: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    achievements: list[str] = field(default_factory=list)


@dataclass
class RunOutcome:
    """What `run_eval` returns."""

    results: RunResults
    output_dir: Path
    missing_plans: list[str]

    @property
    def summary(self) -> Summary | None:
        return self.results.summary


ProgressFactory = Callable[[int, int], Any]


def build_schedule(
    config: EvalConfig, instructions: Sequence[Instruction], plans: dict[str, str] | None
) -> list[ScheduledEpisode]:
    """Every (instruction, repeat) of the run in a fixed order, cut to `config.limit`.

    The order interleaves categories and puts original instructions before paraphrases, so a
    run cut short by `limit` still samples every category and goal.
    """
    rank_in_category: dict[tuple[str, str], int] = {}
    goals_seen: Counter[str] = Counter()
    keyed = []
    for instruction in instructions:
        category = instruction.goal.category
        goal_key = (category, instruction.goal.id)
        if goal_key not in rank_in_category:
            rank_in_category[goal_key] = goals_seen[category]
            goals_seen[category] += 1
        for repeat in range(config.episodes_per_instruction):
            order = (
                repeat,
                instruction.variant,
                rank_in_category[goal_key],
                config.splits.index(category),
            )
            keyed.append((order, instruction, repeat))
    keyed.sort(key=lambda item: item[0])
    if config.limit:
        keyed = keyed[: config.limit]
    return [
        ScheduledEpisode(
            index=index,
            instruction=instruction,
            repeat=repeat,
            plan=(plans or {}).get(instruction.text),
        )
        for index, (_, instruction, repeat) in enumerate(keyed)
    ]


def versions(model: ModelAPI) -> dict[str, str]:
    """Versions of everything that shaped the results."""
    found = {}
    for package in ("craftext-llm", "craftax", "jax", "jaxlib", "flax"):
        try:
            found[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            found[package] = "not installed"
    found.update({f"model.{key}": value for key, value in model.info().items()})
    return found


def run_eval(
    config: EvalConfig,
    model: ModelAPI,
    *,
    progress: ProgressFactory | None = None,
    env: Any = None,
) -> RunOutcome:
    """Run (or resume) the evaluation `config` describes with `model`.

    `env` may pass an existing `CrafTextEnv` of the same variant and step cap (tests share one).
    """
    from env import CrafTextEnv, EnvConfig

    out = Path(config.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    dataset = load_dataset(config.dataset)
    instructions = dataset.instructions(config.splits, include_paraphrases=config.paraphrases)
    if not instructions:
        raise UserError(f"the dataset has no instructions in categories {', '.join(config.splits)}")
    present = {i.goal.category for i in instructions}
    for category in config.splits:
        if category not in present:
            logger.warning(
                "the dataset (%s) has no %r goals; the 57-goal EASY train split of the official "
                "CrafText repository has them: pass a clone of it with --dataset",
                dataset.source.path,
                category,
            )
    plans = _load_plans(config.plans)
    missing = [i.text for i in instructions if plans is not None and i.text not in plans]
    if missing:
        logger.warning(
            "%d of %d instructions have no plan in %s; they run without one",
            len(missing),
            len(instructions),
            config.plans,
        )
    schedule = build_schedule(config, instructions, plans)

    results_path = out / RESULTS_FILE
    started_at = _check_resumable(results_path, config)
    finished = _finished_episodes(out)
    _drop_unfinished_steps(out / STEPS_FILE, {e.episode_id for e in finished})
    done_ids = {e.episode_id for e in finished}
    pending = [spec for spec in schedule if spec.episode_id not in done_ids]

    results = RunResults(
        config=config.model_dump(mode="json"),
        versions=versions(model),
        dataset=dataset.source.model_dump(mode="json")
        | {"missing_plans": len(missing), "instructions": len(instructions)},
        summary=summarize(finished) if finished else None,
        started_at=started_at,
    )
    write_results(results_path, results)

    if env is None:
        env = CrafTextEnv(EnvConfig(variant=config.variant, max_steps=config.max_steps))
    elif env.config.variant != config.variant or env.config.max_steps != config.max_steps:
        raise ValueError("the env passed to run_eval does not match the config")
    sink = _Sink(out, results, list(finished), list(reversed(pending)))
    sink.bar = progress(len(schedule), len(finished)) if progress else None
    try:
        if pending:
            _play_lanes(config, env, model, sink)
    except KeyboardInterrupt:
        _save(results_path, results, sink.episodes, complete=False)
        raise
    finally:
        if sink.bar is not None:
            sink.bar.close()
    results = _save(results_path, results, sink.episodes, complete=True)
    return RunOutcome(results=results, output_dir=out, missing_plans=missing)


class _Sink:
    """What the lanes share: the schedule queue, the output files and the progress bar.

    Every method takes the lock, so lanes running in threads never interleave records.
    """

    def __init__(
        self,
        out: Path,
        results: RunResults,
        episodes: list[EpisodeRecord],
        queue: list[ScheduledEpisode],
    ):
        self.out = out
        self.results = results
        self.episodes = episodes
        self.queue = queue
        self.bar: Any = None
        self.stop = threading.Event()
        self._lock = threading.Lock()
        self._started = time.perf_counter()
        self._agent_steps = 0
        self._tokens = 0

    def take(self, count: int) -> list[ScheduledEpisode]:
        with self._lock:
            return [self.queue.pop() for _ in range(min(count, len(self.queue)))]

    def record(
        self, decisions: list[Decision], steps: list[StepRecord], ended: list[EpisodeRecord]
    ) -> None:
        with self._lock:
            if steps:
                append_records(self.out / STEPS_FILE, steps)
            if ended:
                append_records(self.out / EPISODES_FILE, ended)
                self.episodes.extend(ended)
                _save(self.out / RESULTS_FILE, self.results, self.episodes, complete=False)
            self._agent_steps += len(decisions)
            self._tokens += sum(
                d.output.prompt_tokens + d.output.completion_tokens for d in decisions
            )
            if self.bar is not None:
                elapsed = max(time.perf_counter() - self._started, 1e-9)
                self.bar.update(len(ended))
                self.bar.set_postfix(
                    success=f"{sum(e.success for e in self.episodes)}/{len(self.episodes)}",
                    steps_s=f"{self._agent_steps / elapsed:.1f}",
                    tok_s=f"{self._tokens / elapsed:.0f}",
                    refresh=False,
                )


def _play_lanes(config: EvalConfig, env: Any, model: ModelAPI, sink: _Sink) -> None:
    """Split the batch into `config.lanes` lanes; with more than one, each lane's model call
    overlaps the other lanes' env steps and text work (threads: the waits release the GIL)."""
    lanes = min(config.lanes, len(sink.queue))
    lane_batch = min(-(-config.batch_size // lanes), -(-len(sink.queue) // lanes))
    if lanes == 1:
        _play(config, env, model, lane_batch, sink)
        return
    with ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="lane") as pool:
        futures = [pool.submit(_play, config, env, model, lane_batch, sink) for _ in range(lanes)]
        try:
            for future in futures:
                future.result()
        except BaseException:
            sink.stop.set()
            raise


def _play(config: EvalConfig, env: Any, model: ModelAPI, batch: int, sink: _Sink) -> None:
    from env import VectorEnv, episode_key, goal_masks
    from textualizer import observe_batch

    agent: Agent = build_agent(config)
    first = sink.take(batch)
    if not first:
        return
    # A lane that starts with fewer episodes than its batch pads the batch with copies of its
    # first one; the copies are never observed or recorded.
    padding = [first[0]] * (batch - len(first))
    vector = VectorEnv(env, batch)

    def task_rows(specs: Sequence[ScheduledEpisode]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        keys = np.stack(
            [
                episode_key(config.seed, s.instruction.goal.id, s.instruction.variant, s.repeat)
                for s in specs
            ]
        )
        required, forbidden = goal_masks([s.instruction.goal for s in specs])
        return keys, required, forbidden

    host = vector.reset(*task_rows(first + padding))
    live: dict[int, _Live] = {}
    for slot, spec in enumerate(first):
        live[slot] = _Live(spec)
        agent.start_episode(slot, spec.instruction.text, spec.plan, spec.instruction.goal)

    fallback = agent.fallback_id
    while live and not sink.stop.is_set():
        slots = sorted(live)
        observations = observe_batch(host.game, config.variant, indices=slots)
        decisions = agent.act(model, slots, observations)
        actions = np.full(batch, fallback, dtype=np.int32)
        for decision in decisions:
            actions[decision.slot] = decision.action
        host = vector.step(actions)

        step_records = []
        ended: list[EpisodeRecord] = []
        for decision in decisions:
            slot = decision.slot
            state = live[slot]
            new = _names(host.new_achievements[slot])
            reward = float(host.reward[slot])
            _account(state, decision, reward, new)
            if config.record_steps:
                step_records.append(_step_record(state, decision, host, slot, reward, new))
            if host.done[slot]:
                ended.append(
                    _episode_record(
                        state, int(host.steps[slot]), int(host.termination[slot]), config.seed
                    )
                )
                agent.end_episode(slot)
                del live[slot]
        sink.record(decisions, step_records, ended)

        if ended:
            free = [s for s in range(batch) if s not in live]
            specs = sink.take(len(free))
            if specs:
                refill_slots = free[: len(specs)]
                host = vector.refill(refill_slots, *task_rows(specs))
                for slot, spec in zip(refill_slots, specs, strict=True):
                    live[slot] = _Live(spec)
                    agent.start_episode(
                        slot, spec.instruction.text, spec.plan, spec.instruction.goal
                    )


def _names(mask: np.ndarray) -> list[str]:
    from env.achievements import ACHIEVEMENTS

    return [ACHIEVEMENTS[i] for i in np.flatnonzero(mask)]


def _account(state: _Live, decision: Decision, reward: float, new: list[str]) -> None:
    state.episode_return += reward
    state.invalid += int(decision.fallback_used)
    state.prompt_tokens += decision.output.prompt_tokens
    state.completion_tokens += decision.output.completion_tokens
    state.achievements.extend(new)


def _step_record(
    state: _Live, decision: Decision, host: Any, slot: int, reward: float, new: list[str]
) -> StepRecord:
    return StepRecord(
        episode_id=state.spec.episode_id,
        step=int(host.steps[slot]) - 1,
        observation=decision.observation_text,
        prompt_hash=decision.prompt_hash,
        raw_output=decision.output.text,
        reasoning=decision.output.reasoning,
        action_name=decision.name,
        action_id=decision.action,
        parse_stage=decision.parse.stage,
        fallback_used=decision.fallback_used,
        reward=reward,
        done=bool(host.done[slot]),
        new_achievements=new,
        prompt_tokens=decision.output.prompt_tokens,
        completion_tokens=decision.output.completion_tokens,
        latency_s=decision.output.latency_s,
    )


def _episode_record(state: _Live, steps: int, termination: int, seed: int) -> EpisodeRecord:
    from env import Termination

    spec = state.spec
    return EpisodeRecord(
        episode_id=spec.episode_id,
        goal_id=spec.instruction.goal.id,
        instruction=spec.instruction.text,
        instruction_variant=spec.instruction.variant,
        category=spec.category,
        seed=seed,
        episode_index=spec.index,
        success=termination == Termination.SUCCESS,
        steps=steps,
        termination=Termination(termination).label,
        episode_return=state.episode_return,
        invalid_actions=state.invalid,
        prompt_tokens=state.prompt_tokens,
        completion_tokens=state.completion_tokens,
        achievements=state.achievements,
        plan_given=spec.plan is not None,
    )


def _save(
    path: Path, results: RunResults, episodes: list[EpisodeRecord], *, complete: bool
) -> RunResults:
    results.summary = summarize(episodes) if episodes else None
    results.complete = complete
    results.finished_at = datetime.now(UTC) if complete else None
    write_results(path, results)
    return results


def _load_plans(path: str | None) -> dict[str, str] | None:
    if path is None:
        return None
    from llm_agents.planner import load_plans

    return load_plans(path)


def _check_resumable(results_path: Path, config: EvalConfig) -> datetime:
    """The original start time of a run being resumed (now for a new run).

    Refuses to mix episodes of different settings in one directory.
    """
    if not results_path.exists():
        return datetime.now(UTC)
    previous = read_results(results_path)
    try:
        saved = EvalConfig.model_validate(previous.config)
    except ValueError as err:
        raise UserError(f"{results_path} holds an unreadable config: {err}") from err
    ours, theirs = config.run_identity(), saved.run_identity()
    differing = sorted(
        key for key in ours.keys() | theirs.keys() if ours.get(key) != theirs.get(key)
    )
    if differing:
        raise UserError(
            f"{results_path.parent} holds a run with other settings ({', '.join(differing)} differ); "
            "use another --output-dir, or delete that directory to start over"
        )
    return previous.started_at


def _finished_episodes(out: Path) -> list[EpisodeRecord]:
    path = out / EPISODES_FILE
    if not path.exists():
        return []
    episodes = read_episodes(path)
    # Rewrite without a torn last line or duplicates so later appends stay well-formed.
    _rewrite_lines(path, [e.model_dump_json() for e in episodes])
    return episodes


def _drop_unfinished_steps(path: Path, finished_ids: set[str]) -> None:
    """Forget the steps of episodes that did not finish: they are replayed from the start."""
    if not path.exists():
        return
    kept = []
    with path.open(encoding="utf-8") as handle:
        for line in handle:
            try:
                episode_id = json.loads(line)["episode_id"]
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
            if episode_id in finished_ids:
                kept.append(line.rstrip("\n"))
    _rewrite_lines(path, kept)


def _rewrite_lines(path: Path, lines: list[str]) -> None:
    partial = path.with_name(path.name + ".tmp")
    with partial.open("w", encoding="utf-8") as handle:
        handle.writelines(line + "\n" for line in lines)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(partial, path)
