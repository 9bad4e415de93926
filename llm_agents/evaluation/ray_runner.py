"""`craftext-llm eval --ray`: the episode schedule played by Ray actors, written by this process.

The driver (this process) prepares the run as a local run does and owns the run directory
through the same `run_schedule`: the same files, the same resume, the same failure rules. The
episodes are played by `ray_workers` Ray actors, spread over the cluster's nodes, each with its
own env and backend (an in-process engine on its node's GPU, or an `openai:` spec). A worker
plays with the runner's own play loop (`play_episodes`), `batch_size` episodes at once under continuous scheduling;
the driver hands it episodes so that it always holds a batch beyond the one it plays, and
collects each episode's records when it ends.

An agent from outside this package that is not installed (a folder on the driver's path) is
shipped to the workers: its package's files go with each worker's start, and the worker imports
it from a folder of its own; a worker whose agent differs from the driver's (another version
installed on its node) is refused.

A worker ships an episode's steps only with its end, so a worker that dies leaves nothing of its
unfinished episodes behind: the driver puts them back at the head of the schedule, where another
worker takes them, and Ray restarts the dead actor (at most `MAX_RESTARTS` times). Every
episode's world and answers derive from its own key and prompts, so which worker plays it, and
when, changes nothing: with a deterministic backend a `--ray` run ends with the episodes of a
local one. A driver killed and started again resumes from the run directory like a local run.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import tempfile
import threading
from collections import defaultdict, deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, Field

from env.errors import UserError
from llm_agents.agents.types import Decision
from llm_agents.backends.endpoints import EndpointStats, merge_endpoint_stats
from llm_agents.evaluation.config import EvalConfig
from llm_agents.evaluation.play import play_episodes
from llm_agents.evaluation.runner import (
    PreparedRun,
    ProgressFactory,
    RunOutcome,
    run_schedule,
    versions,
)
from llm_agents.evaluation.schedule import ScheduledEpisode
from llm_agents.run_data.provenance import hardware
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.store import AgentIdentity

if TYPE_CHECKING:
    from llm_agents.backends.base import ModelAPI
    from llm_agents.evaluation.sink import RunSink

logger = logging.getLogger(__name__)

#: Deaths of one worker after which the driver stops using it (Ray restarts it each time).
MAX_RESTARTS = 3
#: Longest a worker holds the driver's call while it has nothing new to report.
COLLECT_WAIT_S = 30.0
INSTALL_HINT = "--ray needs the package 'ray': pip install 'craftext-llm[ray]'"


class WorkerFailure(BaseModel):
    """Why a worker could not start or stopped playing."""

    message: str
    """One line: the exception's type (unless it is a user mistake) and message."""
    user_error: bool
    """True for a `UserError` (a setting or a model that cannot work): the run stops with it."""


class WorkerReady(BaseModel):
    """A worker's answer once its env and model are up."""

    versions: dict[str, str] = Field(default_factory=dict)
    """What `versions(model)` says on that worker."""
    pid: int = 0
    """The worker's process id."""
    hardware: dict[str, str] = Field(default_factory=dict)
    """The machine the worker runs on (`provenance.hardware` there)."""
    agent: AgentIdentity | None = None
    """The import path and version of the agent the worker plays, when it comes from outside
    this package (`agent_identity`): the driver's, or the worker is refused."""
    failure: WorkerFailure | None = None
    """Set when the worker could not load its env or model."""


class Round(BaseModel):
    """One round of a worker's play, as the runner's sink receives it locally."""

    decisions: list[Decision]
    """The answers of the round (their observation text left out: the steps carry it)."""
    steps: list[StepRecord]
    """Every step of the episodes that ended or were aborted in this round."""
    ended: list[EpisodeRecord]
    """Episodes that finished."""
    aborted: list[str]
    """Episodes cut short by a failed answer."""


class WorkerReport(BaseModel):
    """What a worker sends back to the driver for each call."""

    rounds: list[Round] = Field(default_factory=list)
    """Rounds played since the last report."""
    endpoints: list[EndpointStats] = Field(default_factory=list)
    """The worker's backend's per-server counts so far."""
    hardware: dict[str, str] = Field(default_factory=dict)
    """The machine the worker runs on: a worker Ray restarted may run on another node."""
    failure: WorkerFailure | None = None
    """Set when the worker's play stopped on an exception."""


def _failure(err: BaseException) -> WorkerFailure:
    if isinstance(err, UserError):
        return WorkerFailure(message=str(err), user_error=True)
    return WorkerFailure(message=f"{type(err).__name__}: {err}", user_error=False)


class _WorkerSink:
    """The run's sink inside a worker: episodes come from the driver, records go back to it.

    `take` waits while the worker has nothing to play (rather than ending the play loop), and an
    episode's steps are held until it ends, so that a worker lost mid-episode leaves no trace.
    """

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._pending: deque[ScheduledEpisode] = deque()
        self._live = 0
        self._held: dict[str, list[StepRecord]] = defaultdict(list)
        self._rounds: list[Round] = []
        self.stopped = False
        self.finished = False

    def give(self, episodes: list[ScheduledEpisode]) -> None:
        with self._changed:
            self._pending.extend(episodes)
            self._changed.notify_all()

    def take(self, count: int) -> list[ScheduledEpisode]:
        with self._changed:
            self._changed.wait_for(lambda: self._pending or self._live or self.stopped)
            if self.stopped:
                return []
            taken = [self._pending.popleft() for _ in range(min(count, len(self._pending)))]
            self._live += len(taken)
            return taken

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None:
        with self._changed:
            for step in steps:
                self._held[step.episode_id].append(step)
            closed = [episode.episode_id for episode in ended] + aborted
            self._live -= len(closed)
            self._rounds.append(
                Round(
                    decisions=[d.model_copy(update={"observation_text": ""}) for d in decisions],
                    steps=[step for id_ in closed for step in self._held.pop(id_, [])],
                    ended=ended,
                    aborted=aborted,
                )
            )
            self._changed.notify_all()

    def finish(self) -> None:
        with self._changed:
            self.finished = True
            self._changed.notify_all()

    def collect(self, wait_s: float) -> list[Round]:
        """The rounds played since the last call, waiting up to `wait_s` for at least one."""
        with self._changed:
            self._changed.wait_for(lambda: self._rounds or self.finished, wait_s)
            rounds, self._rounds = self._rounds, []
            return rounds


class EpisodeWorker:
    """A Ray actor (see `run_on_ray`): its own env and model, playing the episodes it is given."""

    def __init__(
        self,
        config: EvalConfig,
        commit: str | None = None,
        agent_files: dict[str, bytes] | None = None,
    ) -> None:
        """`commit`: the hub commit the driver resolved the model to; `agent_files`: an outside
        agent's package, shipped by the driver (`shipped_agent`)."""
        self._config = config
        self._sink = _WorkerSink()
        self._player: threading.Thread | None = None
        self._failure: WorkerFailure | None = None
        self._model: ModelAPI | None = None
        self._agent: AgentIdentity | None = None
        self._hardware = hardware()
        try:
            from env import shared_env
            from llm_agents.agents import NoModel, agent_class
            from llm_agents.agents.loading import agent_identity
            from llm_agents.evaluation.runner import open_model

            if agent_files:
                _unpack(agent_files)
            self._agent = agent_identity(config.agent)
            self._env = shared_env(config.env_config())
            # A hub-id model is loaded at the commit the driver recorded (`hub_commit`).
            needs_model = agent_class(config.agent).needs_model
            self._model = open_model(config, commit) if needs_model else NoModel()
        except Exception as err:  # reported by `ready`, where the driver can say it in one line
            self._failure = _failure(err)

    def ready(self) -> WorkerReady:
        if self._failure is not None or self._model is None:
            return WorkerReady(failure=self._failure, pid=os.getpid())
        return WorkerReady(
            versions=versions(self._model),
            pid=os.getpid(),
            hardware=self._hardware,
            agent=self._agent,
        )

    def exchange(self, episodes: list[ScheduledEpisode]) -> WorkerReport:
        """Take more episodes; return the rounds played since the last call."""
        self._sink.give(episodes)
        if self._player is None:
            self._player = threading.Thread(target=self._play, name="play", daemon=True)
            self._player.start()
        rounds = self._sink.collect(COLLECT_WAIT_S)
        endpoints = self._model.endpoint_stats() if self._model is not None else []
        return WorkerReport(
            rounds=rounds, endpoints=endpoints, hardware=self._hardware, failure=self._failure
        )

    def _play(self) -> None:
        try:
            assert self._model is not None, "exchange before a successful start"
            play_episodes(self._config, self._env, self._model, self._sink)
        except BaseException as err:
            self._failure = _failure(err)
        finally:
            self._sink.finish()


class _Driver:
    """Hands episodes to the workers and records what they send back, through the run's sink."""

    def __init__(
        self, ray: Any, workers: list[Any], config: EvalConfig, machines: list[dict[str, str]]
    ):
        self.ray = ray
        # Each worker's machine as it last said: one Ray restarted may have moved.
        self.machines = machines
        self.workers = workers
        self.ahead = 2 * config.batch_size
        self.held: list[dict[str, ScheduledEpisode]] = [{} for _ in workers]
        self.deaths = [0] * len(workers)
        self.endpoints: list[list[EndpointStats]] = [[] for _ in workers]
        self.endpoints_of_lost: list[EndpointStats] = []

    def endpoint_stats(self) -> list[EndpointStats]:
        return merge_endpoint_stats([self.endpoints_of_lost, *self.endpoints])

    def play(self, sink: RunSink) -> None:
        calls: dict[Any, int] = {}
        idle: set[int] = set()
        alive = set(range(len(self.workers)))

        def feed(index: int) -> None:
            held = self.held[index]
            given = sink.take(max(0, self.ahead - len(held)))
            held.update((spec.episode_id, spec) for spec in given)
            if held:
                idle.discard(index)
                calls[self.workers[index].exchange.remote(given)] = index
            else:
                idle.add(index)

        for index in sorted(alive):
            feed(index)
        while calls:
            [done], _ = self.ray.wait(list(calls), num_returns=1)
            index = calls.pop(done)
            try:
                report: WorkerReport = self.ray.get(done)
            except self.ray.exceptions.RayActorError as err:
                self._lost(index, sink, err)
                if self.deaths[index] > MAX_RESTARTS:
                    alive.discard(index)
                if not alive:
                    raise UserError(
                        "every Ray worker died too often; finished episodes are kept: fix the "
                        "cause (see the Ray logs) and rerun the same command to resume"
                    ) from None
                for other in sorted(alive & (idle | {index})):
                    feed(other)
                continue
            if report.failure is not None:
                self._fail(report.failure)
            held = self.held[index]
            for round_ in report.rounds:
                sink.record(round_.decisions, round_.steps, round_.ended, round_.aborted)
                for id_ in [e.episode_id for e in round_.ended] + round_.aborted:
                    held.pop(id_, None)
            self.endpoints[index] = report.endpoints
            self.machines[index] = report.hardware
            if sink.stopped:
                return
            feed(index)

    def _lost(self, index: int, sink: RunSink, err: BaseException) -> None:
        """A worker died (or cannot be reached): its episodes go back to the schedule."""
        self.deaths[index] += 1
        lost = list(self.held[index].values())
        logger.warning(
            "Ray worker %d lost (%s); its %d unfinished episodes go to the others",
            index,
            type(err).__name__,
            len(lost),
        )
        sink.put_back(lost)
        self.held[index] = {}
        self.endpoints_of_lost = merge_endpoint_stats(
            [self.endpoints_of_lost, self.endpoints[index]]
        )
        self.endpoints[index] = []
        # A worker only unreachable for a while would still play its old episodes: killing it
        # (Ray then restarts it) makes sure every lost episode is played once, elsewhere.
        self.ray.kill(self.workers[index], no_restart=False)

    def _fail(self, failure: WorkerFailure) -> None:
        if failure.user_error:
            raise UserError(failure.message)
        raise RuntimeError(f"a Ray worker failed: {failure.message}")


def _import_ray() -> Any:
    try:
        import ray
    except ModuleNotFoundError as err:
        if err.name != "ray":
            raise
        raise UserError(INSTALL_HINT) from None
    return ray


#: Ray starts its workers 15 points nicer than the driver, for a driver that does the work. Here the
#: workers play the episodes and the driver waits: beside any other busy process they would get
#: a few percent of a core (the test suite's Ray runs took 60-114 s beside a busy worker).
LOCAL_CLUSTER_SYSTEM_CONFIG = {"worker_niceness": 0}


def _connect(ray: Any, config: EvalConfig) -> bool:
    """Join the cluster `RAY_ADDRESS` names, else start a local one; True when this process
    must disconnect (or stop it) at the end."""
    if ray.is_initialized():
        return False  # a caller (a notebook, a test) chose the cluster already
    address = os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address, logging_level=logging.WARNING)
    else:
        # "local": never join a cluster some earlier `ray start` left running here by chance.
        ray.init(
            address="local",
            num_cpus=config.ray_workers,
            include_dashboard=False,
            logging_level=logging.WARNING,
            _system_config=LOCAL_CLUSTER_SYSTEM_CONFIG,
        )
    return True


def _check_resources(ray: Any, config: EvalConfig) -> None:
    """Refuse workers the cluster cannot hold: Ray would leave them waiting for ever."""
    available = ray.cluster_resources()
    wanted = {"CPU": float(config.ray_workers), "GPU": config.ray_workers * config.ray_worker_gpus}
    for resource, amount in wanted.items():
        if amount > available.get(resource, 0.0):
            raise UserError(
                f"{config.ray_workers} Ray workers need {amount:g} {resource} in all, and the "
                f"cluster has {available.get(resource, 0.0):g}: lower --ray-workers"
                + (" or --ray-worker-gpus" if resource == "GPU" else "")
            )


def shipped_agent(config: EvalConfig) -> dict[str, bytes]:
    """The files of an outside agent's package that the workers need shipped (`agent_shipment`:
    one that is not installed), by path relative to the folder it is imported from; empty when
    there is none to ship."""
    from llm_agents.agents.loading import agent_shipment

    place = agent_shipment(config.agent)
    if place is None:
        return {}
    files = [place] if place.is_file() else sorted(place.rglob("*"))
    return {
        path.relative_to(place.parent).as_posix(): path.read_bytes()
        for path in files
        if path.is_file() and "__pycache__" not in path.parts
    }


def _unpack(files: dict[str, bytes]) -> None:
    """Write the shipped package into a folder of this worker and put it first on its path (a
    node of a cluster need not hold the driver's folders)."""
    root = Path(tempfile.mkdtemp(prefix="craftext-agent-"))
    for name, data in files.items():
        target = root / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    sys.path.insert(0, str(root))
    importlib.invalidate_caches()


def _check_worker_agent(answer: WorkerReady, driver: AgentIdentity | None) -> None:
    """Refuse a worker whose outside agent is not the one the driver recorded (another version
    installed on its node): its episodes would not be this run's."""
    if answer.agent != driver:
        theirs = answer.agent.described() if answer.agent else "built-in"
        ours = driver.described() if driver else "built-in"
        raise UserError(
            f"a Ray worker plays agent {theirs}, the driver {ours}: install the same agent "
            "version on every node"
        )


def run_on_ray(prepared: PreparedRun, *, progress: ProgressFactory | None = None) -> RunOutcome:
    """Play the prepared run on Ray workers, writing the run directory here (see the module)."""
    ray = _import_ray()
    config = prepared.config
    disconnect = _connect(ray, config)
    workers: list[Any] = []
    try:
        _check_resources(ray, config)
        actor = ray.remote(EpisodeWorker).options(
            num_cpus=1,
            num_gpus=config.ray_worker_gpus,
            # Unbounded for Ray: the driver counts deaths itself, since it also restarts a worker
            # it cannot reach (`_Driver._lost`).
            max_restarts=-1,
            max_task_retries=0,
            scheduling_strategy="SPREAD",
        )
        commit = prepared.identity.model_revision
        # Passed by value, not `ray.put`: Ray warns that a restarted actor cannot rebuild from
        # an argument in the object store, and an agent's package is small.
        agent_files = shipped_agent(config)
        workers = [actor.remote(config, commit, agent_files) for _ in range(config.ray_workers)]
        ready: list[WorkerReady] = ray.get([worker.ready.remote() for worker in workers])
        for answer in ready:
            if answer.failure is not None:
                raise UserError(f"a Ray worker could not start: {answer.failure.message}")
            _check_worker_agent(answer, prepared.identity.agent)
        driver = _Driver(ray, workers, config, [answer.hardware for answer in ready])
        return run_schedule(
            prepared,
            ready[0].versions | {"ray": ray.__version__, "ray.workers": str(len(workers))},
            driver.play,
            progress=progress,
            endpoint_stats=driver.endpoint_stats,
            worker_hardware=lambda: list(driver.machines),
        )
    finally:
        for worker in workers:
            ray.kill(worker)
        if disconnect:
            ray.shutdown()
