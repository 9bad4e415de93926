"""The evaluation runner: up to N episodes in flight, resumable, written as it goes.

A run has two phases. `prepare_run` does every cheap check (settings, dataset, plans, templates,
fallback action, output directory, the identity of a run already in that directory) and writes
nothing; only then is the model loaded and probed, and `execute_run` plays. Scheduling is
continuous: each episode takes its next step as soon as its own answer arrives, never waiting
for slower ones, and a finished episode's slot is refilled from the schedule at once. Model
requests go through one `Dispatcher` (many concurrent requests to a server, whatever is ready
in one batch to an in-process engine); the env work of the episodes whose answers arrived
together is one masked, batched env step. Results never depend on timing: an episode's world
and randomness derive from its own key and step index.

A model answer that failed (after the backend's retries) is data, not an answer: the step is
recorded with its error, its episode is cut short and not counted, and a rerun plays it again.
Too many failures in a row stop the run (status `failed`), keeping everything that finished. A
run killed at any point and restarted on the same directory redoes only the episodes that had
not finished: episode worlds derive from their own keys, so with a deterministic backend the
resumed run ends with exactly the results of an uninterrupted one.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import logging
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from env.dataset import Instruction, load_dataset
from env.errors import UserError
from llm_agents.agents import Agent, build_agent
from llm_agents.agents.types import Decision
from llm_agents.backends.base import ModelAPI
from llm_agents.backends.endpoints import EndpointStats
from llm_agents.evaluation.config import EvalConfig, ModelSettings
from llm_agents.evaluation.dispatch import Dispatcher
from llm_agents.run_data.metrics import Summary, summarize
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunIdentity,
    RunResults,
    append_records,
    check_output_dir,
    episode_ids_of_steps,
    file_sha256,
    make_output_dir,
    read_episodes,
    read_results,
    rewrite_lines,
    write_results,
)

logger = logging.getLogger(__name__)


class BackendFailure(Exception):
    """The backend failed too often in a row; the run stopped with status `failed`."""


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


@dataclass
class PreparedRun:
    """A run checked and ready to play: nothing has been written yet."""

    config: EvalConfig
    output_dir: Path
    dataset_source: dict[str, Any]
    instructions: int
    schedule: list[ScheduledEpisode]
    missing_plans: list[str]
    identity: RunIdentity
    previous: RunResults | None


ProgressFactory = Callable[[int, int], Any]
GameOver = Literal["death", "timeout"] | None


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


def _template_hashes(templates_dir: str | None) -> dict[str, str]:
    """Every template a run may render (packaged names, resolved through the override dir)."""
    from prompts import PACKAGE_TEMPLATES_DIR, template_source

    return {
        path.name: hashlib.sha256(
            template_source(path.stem, templates_dir).encode("utf-8")
        ).hexdigest()
        for path in sorted(PACKAGE_TEMPLATES_DIR.glob("*.j2"))
    }


def prepare_run(config: EvalConfig) -> PreparedRun:
    """Check everything that can be checked without the model; write nothing.

    Raises `UserError` for any mistake: an unusable output directory, a dataset without the
    requested categories, an unreadable plans file, a template that does not render, a
    fallback action the variant lacks, or a directory holding a different run.
    """
    out = Path(config.output_dir)
    check_output_dir(out)
    dataset = load_dataset(config.dataset)
    instructions = dataset.instructions(config.splits, include_paraphrases=config.paraphrases)
    if not instructions:
        raise UserError(f"the dataset has no instructions in categories {', '.join(config.splits)}")
    present = {i.goal.category for i in instructions}
    for category in config.splits:
        if category not in present:
            logger.warning(
                "the dataset (%s) has no %r goals; the official CrafText data has them: run "
                "`craftext-llm data fetch` when online, or pass a clone of the official "
                "repository with --dataset",
                dataset.source.path,
                category,
            )
    plans = _load_plans(config.plans)
    missing = [i.text for i in instructions if plans is not None and i.text not in plans]
    schedule = build_schedule(config, instructions, plans)
    # Renders the system prompt and checks the fallback action; a step's messages are built
    # too, so a broken template fails here rather than on the first model call.
    agent: Agent = build_agent(config)
    first = schedule[0]
    agent.check_templates(first.instruction.text, first.plan, first.instruction.goal)
    identity = RunIdentity(
        settings=config.result_settings(),
        templates=_template_hashes(config.templates_dir),
        plans=file_sha256(Path(config.plans), "plans file") if config.plans else None,
        dataset=dataset.source.sha256,
    )
    return PreparedRun(
        config=config,
        output_dir=out,
        dataset_source=dataset.source.model_dump(mode="json")
        | {"goals": dataset.category_goals(), "split_sha256": dataset.split_sha256()},
        instructions=len(instructions),
        schedule=schedule,
        missing_plans=missing,
        identity=identity,
        previous=_previous_run(out, identity),
    )


def _previous_run(out: Path, identity: RunIdentity) -> RunResults | None:
    """The run already in `out`, refused when it is not this run."""
    results_path = out / RESULTS_FILE
    if not results_path.exists():
        leftovers = [name for name in (EPISODES_FILE, STEPS_FILE) if (out / name).exists()]
        if leftovers:
            raise UserError(
                f"{out} holds {' and '.join(leftovers)} but no {RESULTS_FILE}, so it cannot be "
                "told whether they belong to this run; use another --output-dir or remove them"
            )
        return None
    previous = read_results(results_path)
    changed = identity.differences(previous.identity)
    if changed:
        raise UserError(
            f"{out} holds a run with other settings: {'; '.join(changed)}; "
            "use another --output-dir, or delete that directory to start over"
        )
    return previous


def run_eval(
    config: EvalConfig,
    model: ModelAPI,
    *,
    progress: ProgressFactory | None = None,
    env: Any = None,
) -> RunOutcome:
    """Prepare, probe the model, and run (or resume) the evaluation `config` describes.

    `model` must be the one `config` names, opened as `open_model(config)` opens it (the same
    backend, model, generation settings and response cache): the results record the config.
    """
    prepared = prepare_run(config)
    return execute_run(prepared, model, progress=progress, env=env, probe=config.probe)


def open_model(settings: ModelSettings) -> ModelAPI:
    """Load the model the settings name and check it answers (unless `probe` is off)."""
    from llm_agents.backends import get_model

    model = get_model(settings.model, settings.generation, **settings.backend_options)
    choice = getattr(settings, "choice", None)
    if choice is not None:
        model.check_choice_rule(choice)
    if settings.cache:
        from llm_agents.backends.cache import CachedModel

        model = CachedModel(model, settings.cache)
    if settings.probe:
        try:
            model.probe()
        except BaseException:
            model.close()
            raise
    return model


def check_model(config: EvalConfig, model: ModelAPI) -> None:
    """Refuse a model other than the one `config` names, since the results record the config:
    another backend, model or generation settings, or a response cache other than
    `config.cache` (`open_model(config)` opens the right one). An agent that needs no model
    plays with any, and records none."""
    from llm_agents.agents import agent_class
    from llm_agents.backends import parse_model_spec
    from llm_agents.backends.cache import CachedModel

    if not agent_class(config.agent).needs_model:
        return
    spec = parse_model_spec(config.model)
    problems = []
    if (model.backend_name, model.model_name) != (spec.backend, spec.name):
        problems.append(
            f"it is {model.backend_name}:{model.model_name}, the config names {config.model}"
        )
    if model.config != config.generation:
        problems.append("its generation settings are not the config's")
    cache = model.path if isinstance(model, CachedModel) else None
    wanted = Path(config.cache).expanduser() if config.cache else None
    if cache != wanted:
        problems.append(f"its response cache is {cache}, the config's is {wanted}")
    if problems:
        raise ValueError(
            f"the model passed to run_eval is not the config's: {'; '.join(problems)} "
            "(open it with open_model(config))"
        )


def execute_run(
    prepared: PreparedRun,
    model: ModelAPI,
    *,
    progress: ProgressFactory | None = None,
    env: Any = None,
    probe: bool = False,
) -> RunOutcome:
    """Play the prepared run with `model` (probed first with `probe`), writing as it goes.

    `model` must be the one the config names (see `check_model`). `env` may pass an existing
    `CrafTextEnv` of the same variant and step cap (tests share one). Raises `BackendFailure`
    (after saving) when the backend failed too often in a row.
    """
    from env import CrafTextEnv

    config = prepared.config
    check_model(config, model)
    if probe:
        model.probe()
    env_config = config.env_config()
    if env is None:
        env = CrafTextEnv(env_config)
    elif env.config != env_config:
        raise ValueError("the env passed to run_eval does not match the config")
    return run_schedule(
        prepared,
        versions(model),
        lambda sink: _play(config, env, model, sink),
        progress=progress,
        endpoint_stats=model.endpoint_stats,
    )


def run_schedule(
    prepared: PreparedRun,
    model_versions: dict[str, str],
    play: Callable[[_Sink], None],
    *,
    progress: ProgressFactory | None = None,
    endpoint_stats: Callable[[], list[EndpointStats]] = list,
) -> RunOutcome:
    """Open the run directory (keeping the episodes that finished there), have `play` run the
    pending ones through the sink, and save the results: the part of a run that is the same
    wherever the episodes are played (in this process, or on Ray workers).

    Raises `BackendFailure` (after saving) when the backend failed too often in a row.
    """
    config, out = prepared.config, prepared.output_dir
    make_output_dir(out)
    scheduled_ids = {spec.episode_id for spec in prepared.schedule}
    finished = _finished_episodes(out)
    _drop_unfinished_steps(out / STEPS_FILE, {e.episode_id for e in finished})
    done_ids = {e.episode_id for e in finished}
    pending = [spec for spec in prepared.schedule if spec.episode_id not in done_ids]

    results = RunResults(
        config=config.model_dump(mode="json"),
        identity=prepared.identity,
        versions=model_versions,
        dataset=prepared.dataset_source
        | {"missing_plans": len(prepared.missing_plans), "instructions": prepared.instructions},
        schedule=[spec.episode_id for spec in prepared.schedule],
        started_at=prepared.previous.started_at if prepared.previous else datetime.now(UTC),
    )
    sink = _Sink(
        out, results, scheduled_ids, finished, list(reversed(pending)), config, endpoint_stats
    )
    sink.save()
    sink.bar = progress(len(prepared.schedule), sink.counted) if progress else None
    try:
        if pending:
            with _latched_interrupts() as sink.interrupted:
                play(sink)
    except KeyboardInterrupt:
        # The interrupt may land between an episode's line and its count in memory: the
        # summary is rebuilt from the file, so the two always agree.
        sink.episodes = _finished_episodes(out)
        sink.save()
        raise
    finally:
        if sink.bar is not None:
            sink.bar.close()
    if sink.failure is not None:
        sink.save(failure=sink.failure)
        raise BackendFailure(
            f"stopped after {config.max_consecutive_failures} failed model answers in a row "
            f"(last: {sink.failure}); finished episodes are kept in {out}: fix the cause and "
            "rerun the same command to resume"
        )
    sink.save()
    return RunOutcome(results=sink.results, output_dir=out, missing_plans=prepared.missing_plans)


@contextlib.contextmanager
def _latched_interrupts() -> Iterator[threading.Event]:
    """Ctrl-C also sets the event this yields, and the sink raises `KeyboardInterrupt` again on
    its next record.

    The interrupt raised by Python's handler can be lost when it lands in code that swallows
    exceptions (about 1 loaded run in 15 played on to the end); the latch makes it stick. Only
    the main thread can set handlers, and a handler someone else installed is left alone.
    """
    latch = threading.Event()
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield latch
        return

    def interrupt(signum: int, frame: Any) -> None:
        latch.set()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    try:
        yield latch
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


class _Sink:
    """Where finished work goes: the schedule queue, the output files, failure accounting and
    the progress bar."""

    def __init__(
        self,
        out: Path,
        results: RunResults,
        scheduled_ids: set[str],
        finished: list[EpisodeRecord],
        queue: list[ScheduledEpisode],
        config: EvalConfig,
        endpoint_stats: Callable[[], list[EndpointStats]] = list,
    ):
        self.out = out
        self.endpoint_stats = endpoint_stats
        self.results = results
        self.scheduled_ids = scheduled_ids
        self.episodes = finished
        self.queue = queue
        self.max_failures = config.max_consecutive_failures
        self.bar: Any = None
        self.stopped = False
        self.interrupted = threading.Event()
        self.failure: str | None = None
        self._failures_in_a_row = 0
        self._started = time.perf_counter()
        self._agent_steps = 0
        self._tokens = 0

    @property
    def counted(self) -> int:
        return sum(e.episode_id in self.scheduled_ids for e in self.episodes)

    def take(self, count: int) -> list[ScheduledEpisode]:
        if self.stopped:
            return []
        return [self.queue.pop() for _ in range(min(count, len(self.queue)))]

    def put_back(self, specs: Sequence[ScheduledEpisode]) -> None:
        """Episodes taken but lost unplayed (a Ray worker died): they are taken again first."""
        self.queue.extend(sorted(specs, key=lambda spec: spec.index, reverse=True))

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None:
        if steps:
            # Steps of unfinished episodes are dropped on resume, so only an episode's end needs
            # its steps on disk (before its line): an fsync per round would stall every round.
            append_records(self.out / STEPS_FILE, steps, durable=bool(ended))
        if ended:
            append_records(self.out / EPISODES_FILE, ended)
            self.episodes.extend(ended)
        self._count_failures(decisions, aborted)
        if ended or aborted:
            self.save()
        self._agent_steps += len(decisions)
        self._tokens += sum(d.output.prompt_tokens + d.output.completion_tokens for d in decisions)
        if self.bar is not None:
            elapsed = max(time.perf_counter() - self._started, 1e-9)
            self.bar.update(len(ended))
            self.bar.set_postfix(
                success=f"{sum(e.success for e in self.episodes)}/{len(self.episodes)}",
                steps_s=f"{self._agent_steps / elapsed:.1f}",
                tok_s=f"{self._tokens / elapsed:.0f}",
                errors=self.results.backend_errors.failed_calls,
                refresh=False,
            )
        if self.interrupted.is_set():
            raise KeyboardInterrupt

    def _count_failures(self, decisions: list[Decision], aborted: list[str]) -> None:
        errors = self.results.backend_errors
        errors.aborted_episodes.extend(aborted)
        for decision in decisions:
            if decision.output.finish_reason != "error":
                self._failures_in_a_row = 0
                continue
            errors.failed_calls += 1
            errors.last_error = decision.output.error or "unknown backend error"
            self._failures_in_a_row += 1
            if self._failures_in_a_row >= self.max_failures and self.failure is None:
                self.failure = errors.last_error
                self.stopped = True

    def save(self, failure: str | None = None) -> None:
        results = self.results
        counted = [e for e in self.episodes if e.episode_id in self.scheduled_ids]
        results.finished = len(counted)
        results.endpoints = self.endpoint_stats()
        results.summary = summarize(counted) if counted else None
        if failure is not None:
            results.status, results.failure = "failed", failure
        elif results.finished == results.scheduled:
            results.status, results.failure = "complete", None
        else:
            results.status, results.failure = "partial", None
        results.finished_at = datetime.now(UTC) if results.status == "complete" else None
        write_results(self.out / RESULTS_FILE, results)


class EpisodeSink(Protocol):
    """What `_play` takes episodes from and hands records to: the run's `_Sink` here, or a Ray
    worker's, which ships them to the driver's."""

    stopped: bool

    def take(self, count: int) -> list[ScheduledEpisode]: ...

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None: ...


def _play(config: EvalConfig, env: Any, model: ModelAPI, sink: EpisodeSink) -> None:
    """Continuous scheduling: up to `batch_size` episodes in flight, each stepping as soon as
    its own answer arrives, a finished one's slot refilled at once.

    Each round takes every answer that has arrived, steps those episodes together (one masked
    env step over the slots; the waiting ones are left untouched, so timing never changes a
    trajectory), writes their records, refills finished slots and sends the next prompts.
    """
    from env import VectorEnv, episode_key, goal_masks
    from textualizer import observe_batch

    agent: Agent = build_agent(config)
    first = sink.take(config.batch_size)
    if not first:
        return
    slots = len(first)
    vector = VectorEnv(env, slots)

    def task_rows(specs: Sequence[ScheduledEpisode]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        keys = np.stack(
            [
                episode_key(config.seed, s.instruction.goal.id, s.instruction.variant, s.repeat)
                for s in specs
            ]
        )
        required, forbidden = goal_masks([s.instruction.goal for s in specs])
        return keys, required, forbidden

    host = vector.reset(*task_rows(first))
    live: dict[int, _Live] = {}
    for slot, spec in enumerate(first):
        live[slot] = _Live(spec)
        agent.start_episode(slot, spec.instruction.text, spec.plan, spec.instruction.goal)

    dispatcher = Dispatcher(model, agent.choices)

    def send(host: Any, ready: list[int]) -> None:
        if ready:
            observations = observe_batch(host.game, config.variant, indices=ready)
            dispatcher.submit(
                [agent.prepare(s, o) for s, o in zip(ready, observations, strict=True)]
            )

    fallback = agent.fallback_id
    try:
        send(host, list(range(slots)))
        while not sink.stopped:
            if dispatcher.in_flight == 0:
                return
            decisions = [agent.decide(prompt, output) for prompt, output in dispatcher.wait()]
            actions = np.full(slots, fallback, dtype=np.int32)
            active = np.zeros(slots, dtype=bool)
            for decision in decisions:
                actions[decision.slot] = decision.action
                active[decision.slot] = True
            host = vector.step(actions, active)

            step_records = []
            ended: list[EpisodeRecord] = []
            aborted: list[str] = []
            continuing = []
            for decision in decisions:
                slot = decision.slot
                state = live[slot]
                new = _names(host.new_achievements[slot])
                reward = float(host.reward[slot])
                _account(state, decision, reward, new)
                if config.record_steps:
                    step_records.append(_step_record(state, decision, host, slot, reward, new))
                if decision.output.finish_reason == "error":
                    # The backend failed, not the agent: not scored; a rerun plays it again.
                    aborted.append(state.spec.episode_id)
                elif host.done[slot]:
                    game_over: GameOver = None
                    if host.goal_at_game_over[slot]:
                        game_over = "death" if host.game.player_health[slot] <= 0 else "timeout"
                    ended.append(
                        _episode_record(
                            state,
                            int(host.steps[slot]),
                            int(host.termination[slot]),
                            config.seed,
                            game_over,
                        )
                    )
                else:
                    continuing.append(slot)
                    continue
                agent.end_episode(slot)
                del live[slot]
            # A server answers each request on its own: the continuing episodes' prompts go out
            # before anything is written or a new world generated (tens of ms on a busy CPU). An
            # engine batches what it is handed at once, so it gets them with the refilled ones.
            to_prompt = sorted(continuing)
            if model.concurrent_requests:
                send(host, to_prompt)
                to_prompt = []
            sink.record(decisions, step_records, ended, aborted)

            free = [s for s in range(slots) if s not in live]
            specs = sink.take(len(free)) if free else []
            if specs:
                refill_slots = free[: len(specs)]
                host = vector.refill(refill_slots, *task_rows(specs))
                for slot, spec in zip(refill_slots, specs, strict=True):
                    live[slot] = _Live(spec)
                    agent.start_episode(
                        slot, spec.instruction.text, spec.plan, spec.instruction.goal
                    )
                to_prompt = sorted(to_prompt + refill_slots)
            send(host, to_prompt)
    finally:
        dispatcher.close()


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
        finish_reason=decision.output.finish_reason,
        error=decision.output.error,
        cached=decision.output.cached,
        followups=decision.output.followups,
    )


def _episode_record(
    state: _Live, steps: int, termination: int, seed: int, goal_at_game_over: GameOver = None
) -> EpisodeRecord:
    from env import Termination, episode_key

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
        goal_at_game_over=goal_at_game_over,
        reset_key=episode_key(
            seed, spec.instruction.goal.id, spec.instruction.variant, spec.repeat
        ).tolist(),
    )


def _load_plans(path: str | None) -> dict[str, str] | None:
    if path is None:
        return None
    from llm_agents.run_data.plans import load_plans

    return load_plans(path)


def _finished_episodes(out: Path) -> list[EpisodeRecord]:
    path = out / EPISODES_FILE
    if not path.exists():
        return []
    episodes = read_episodes(path, repair=True)
    # Rewritten without duplicates, so later appends extend a clean file.
    rewrite_lines(path, [e.model_dump_json() for e in episodes])
    return episodes


def _drop_unfinished_steps(path: Path, finished_ids: set[str]) -> None:
    """Forget the steps of episodes that did not finish: they are replayed from the start."""
    if path.exists():
        rewrite_lines(
            path, [line for id_, line in episode_ids_of_steps(path) if id_ in finished_ids]
        )
