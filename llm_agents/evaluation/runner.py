"""A run from start to end: checked before anything is written, the model opened, the run
directory opened or resumed, the episodes played, the results saved.

A run has two phases. `prepare_run` does every cheap check (settings, dataset, plans, templates,
fallback action, output directory, the identity of a run already in that directory) and writes
nothing; only then is the model loaded and probed, and `execute_run` plays. `run_schedule` is the
part that is the same wherever the episodes are played (here, or on Ray workers): it opens the
directory, keeps what finished there, and has the episodes still to play played through the
run's sink (`sink`). The episodes themselves are played by the play loop (`play`), in the order
of the schedule (`schedule`): continuously, each episode stepping as soon as its own answer
arrives. Results never depend on timing: an episode's world and randomness derive from its own
key and step index.

A model answer that failed (after the backend's retries) is data, not an answer: the step is
recorded with its error, its episode is cut short and not counted, and a rerun plays it again.
Too many failures in a row stop the run (status `failed`), keeping everything that finished. A
run killed at any point and restarted on the same directory redoes only the episodes that had
not finished: episode worlds derive from their own keys, so with a deterministic backend the
resumed run ends with exactly the results of an uninterrupted one.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import logging
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from env.dataset import load_dataset
from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY, run_category
from env.open_ended import open_ended_dataset
from env.scenario_tasks import encode_goals
from env.variant import DEFAULT_VARIANT, as_variant
from llm_agents.agents import Agent, build_agent
from llm_agents.agents.answer_schemas import agent_schema, reading_schema
from llm_agents.agents.grounding import examples_digest, training_examples
from llm_agents.agents.loading import agent_identity
from llm_agents.agents.skills.catalogue import grammar_digest, skill_offer
from llm_agents.agents.skills.demos import check_demo_count, demos_digest, skill_demos
from llm_agents.agents.strategies.zero_shot import FRAMES_TEMPLATE
from llm_agents.backends import model_revision
from llm_agents.backends.base import HUB_REVISION_KEY, ModelAPI, OutputSchema
from llm_agents.backends.endpoints import EndpointStats
from llm_agents.backends.reasoning import ANSWER_ONLY_TEMPLATE
from llm_agents.evaluation.config import EvalConfig, ModelSettings
from llm_agents.evaluation.play import play_episodes
from llm_agents.evaluation.schedule import EpisodeQueue, ScheduledEpisode, build_schedule
from llm_agents.evaluation.sink import (
    RunSink,
    finished_episodes,
    recorded_actions,
)
from llm_agents.run_data.metrics import Summary
from llm_agents.run_data.provenance import code_version, hardware
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunIdentity,
    RunResults,
    check_output_dir,
    file_sha256,
    keep_steps_of,
    make_output_dir,
    read_results,
    split_digests,
)

logger = logging.getLogger(__name__)


class BackendFailure(Exception):
    """The backend failed too often in a row; the run stopped with status `failed`."""


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


def versions(model: ModelAPI) -> dict[str, str]:
    """Versions of everything that shaped the results."""
    found = {}
    for package in ("craftext-llm", "craftax", "jax", "jaxlib", "flax"):
        try:
            found[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            found[package] = "not installed"
    found["code"] = code_version()
    found.update({f"model.{key}": value for key, value in model.info().items()})
    return found


def _template_hashes(config: EvalConfig, agent: Agent) -> dict[str, str]:
    """The templates whose text reaches the model: the agent's own (through the override
    folder), what an image observation's frames show, and, for an agent calling a model, the
    backends' answer-only follow-up (packaged)."""
    from prompts import template_digests

    templates_dir = config.templates_dir
    rendered = template_digests(agent.templates, templates_dir)
    if config.observation != "text":
        rendered |= template_digests([FRAMES_TEMPLATE], templates_dir)
    if agent.needs_model:
        rendered |= template_digests([ANSWER_ONLY_TEMPLATE])
    return rendered


def prepare_run(config: EvalConfig) -> PreparedRun:
    """Check everything that can be checked without the model; write nothing.

    Raises `UserError` for any mistake: an unusable output directory, a dataset without the
    requested categories, an unreadable plans file, a template that does not render, a
    fallback action the variant lacks, or a directory holding a different run.
    """
    out = Path(config.output_dir)
    check_output_dir(out)
    # The open-ended task reads no dataset: its one goal is our own.
    dataset = open_ended_dataset() if config.task == "open_ended" else load_dataset(config.dataset)
    instructions = dataset.instructions(
        config.categories, include_paraphrases=config.paraphrases, difficulty=config.difficulty
    )
    if not instructions:
        raise UserError(
            f"the dataset has no {config.difficulty} instructions in categories "
            f"{', '.join(config.categories)}"
        )
    # A goal the variant cannot score (a block or item it lacks) is refused before anything runs.
    encode_goals([i.goal for i in instructions], config.variant)
    present = {run_category(i.goal) for i in instructions}
    for category in config.categories:
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
    training = (
        training_examples(dataset, config.difficulty)
        if config.grounding_shots or config.skill_demos
        else ()
    )
    examples = examples_digest(training) if config.grounding_shots else None
    if config.skill_demos:
        demos = skill_demos(training, config.variant, config.difficulty)
        scheduled = {(item.instruction.text, item.instruction.goal) for item in schedule}
        check_demo_count(demos, config.skill_demos, scheduled, config.difficulty)
        examples = demos_digest(demos)
    agent: Agent = build_agent(config)
    first = schedule[0]
    agent.check_templates(first.instruction.text, first.plan, first.instruction.goal)
    identity = RunIdentity(
        model_revision=hub_commit(config) if agent.needs_model else None,
        settings=config.result_settings(),
        templates=_template_hashes(config, agent),
        plans=file_sha256(Path(config.plans), "plans file") if config.plans else None,
        dataset=dataset.source.sha256,
        goals=split_digests(dataset, config.categories, config.difficulty),
        examples=examples,
        grammar=grammar_digest(skill_offer(config.variant, config.difficulty))
        if config.agent == "skills" and config.choice == "guided"
        else None,
        agent=agent_identity(config.agent),
    )
    return PreparedRun(
        config=config,
        output_dir=out,
        dataset_source=dataset.source.model_dump(mode="json")
        | {
            "goals": dataset.category_goals(),
            "scenario_goals": dataset.scenario_goals(),
            "split_sha256": dataset.split_sha256(),
        },
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
    previous.check_resumed_by(
        identity, out, EvalConfig.predated(previous.identity.settings), "a run"
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


def hub_commit(settings: ModelSettings) -> str | None:
    """The hub commit the settings' model is at now (`backends.model_revision`): resolved when a
    run is prepared, recorded in its identity, and the one its model is then loaded at."""
    return model_revision(settings.backend_spec, settings.backend_option_values)


def output_schema_of(settings: ModelSettings) -> OutputSchema | None:
    """The JSON schema a run's answers are held to (`--structured-output`): its agent's
    (`eval`), a goal reading's (`ground`); None in free text."""
    if not getattr(settings, "structured_output", False):
        return None
    variant = as_variant(getattr(settings, "variant", DEFAULT_VARIANT))
    difficulty = getattr(settings, "difficulty", DEFAULT_DIFFICULTY)
    agent = getattr(settings, "agent", None)
    if agent is None:
        return reading_schema(variant, difficulty)
    return agent_schema(agent, variant, difficulty)


def open_model(settings: ModelSettings, commit: str | None = None) -> ModelAPI:
    """Load the model the settings name and check it answers (unless `probe` is off). A hub-id
    model is loaded at `commit` where given (the one the run's identity recorded, `hub_commit`),
    else at its `revision` option's commit now."""
    from llm_agents.backends import get_model

    options = settings.backend_option_values | ({HUB_REVISION_KEY: commit} if commit else {})
    model = get_model(settings.backend_spec, settings.generation, **options)
    choice = getattr(settings, "choice", None)
    if choice is not None:
        model.check_choice_rule(choice)
    schema = output_schema_of(settings)
    if schema is not None:
        try:
            model.check_schema(schema)
        except BaseException:
            model.close()
            raise
    if getattr(settings, "observation", "text") != "text":
        try:
            model.check_images()
        except BaseException:
            model.close()
            raise
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


def check_commit(identity: RunIdentity, model_info: dict[str, str]) -> None:
    """Refuse a model loaded at another hub commit than the one the run recorded (the branch
    moved between the run's preparation and the model's loading)."""
    loaded = model_info.get(HUB_REVISION_KEY)
    if identity.model_revision is not None and loaded != identity.model_revision:
        raise UserError(
            f"the model was loaded at hub commit {loaded}, the run was prepared at "
            f"{identity.model_revision}: open it with open_model(config, "
            "prepared.identity.model_revision), or prepare the run again"
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
    `CrafTextEnv` of the same settings; without one the run plays on `env.shared_env`'s. Raises
    `BackendFailure` (after saving) when the backend failed too often in a row.
    """
    from env import shared_env

    config = prepared.config
    check_model(config, model)
    check_commit(prepared.identity, model.info())
    if probe:
        model.probe()
        if config.observation != "text":
            model.check_images()
    env_config = config.env_config()
    if env is None:
        env = shared_env(env_config)
    elif env.config != env_config:
        raise ValueError("the env passed to run_eval does not match the config")
    return run_schedule(
        prepared,
        versions(model),
        lambda sink: play_episodes(config, env, model, sink),
        progress=progress,
        endpoint_stats=model.endpoint_stats,
    )


def run_schedule(
    prepared: PreparedRun,
    model_versions: dict[str, str],
    play: Callable[[RunSink], None],
    *,
    progress: ProgressFactory | None = None,
    endpoint_stats: Callable[[], list[EndpointStats]] = list,
    worker_hardware: Callable[[], list[dict[str, str]]] | None = None,
) -> RunOutcome:
    """Open the run directory (keeping the episodes that finished there), have `play` run the
    pending ones through the sink, and save the results: the part of a run that is the same
    wherever the episodes are played (in this process, or on Ray workers, whose machines
    `worker_hardware` gives: the results record them instead of this one's).

    Raises `BackendFailure` (after saving) when the backend failed too often in a row.
    """
    config, out = prepared.config, prepared.output_dir
    make_output_dir(out)
    finished = finished_episodes(out)
    done_ids = {e.episode_id for e in finished}
    # Steps of episodes that did not finish are dropped: those are played again from the start.
    keep_steps_of(out / STEPS_FILE, done_ids)
    pending = [spec for spec in prepared.schedule if spec.episode_id not in done_ids]

    results = RunResults(
        config=config.model_dump(mode="json"),
        identity=prepared.identity,
        versions=model_versions,
        dataset=prepared.dataset_source
        | {"missing_plans": len(prepared.missing_plans), "instructions": prepared.instructions},
        schedule=[spec.episode_id for spec in prepared.schedule],
        started_at=prepared.previous.started_at if prepared.previous else datetime.now(UTC),
        played_seconds=prepared.previous.played_seconds if prepared.previous else 0.0,
        hardware=hardware(),
    )
    sink = RunSink(
        out,
        results,
        finished,
        EpisodeQueue(pending),
        config.max_consecutive_failures,
        endpoint_stats,
        actions=recorded_actions(out, done_ids) if config.record_steps else None,
        worker_hardware=worker_hardware,
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
        sink.episodes = finished_episodes(out)
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


def _load_plans(path: str | None) -> dict[str, str] | None:
    if path is None:
        return None
    from llm_agents.run_data.plans import load_plans

    return load_plans(path)
