"""The evaluation runner and CLI on the mock backend: outputs, refills, invalid answers,
independence from the episodes in flight and answer timing, resume after SIGKILL, Ctrl-C, and clear errors for bad input."""

from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import math
import random
import signal
import subprocess
import sys
import threading
import time
import weakref
from pathlib import Path
from typing import Any

import pytest
from interrupt import interruptible_run

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from env.errors import UserError
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, GenerateConfig
from llm_agents.backends.cache import CachedModel
from llm_agents.backends.mock import MockModel
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import EvalConfig, build_config
from llm_agents.evaluation.runner import open_model, run_eval
from llm_agents.evaluation.schedule import build_schedule
from llm_agents.run_data.records import StepRecord
from llm_agents.run_data.store import read_episodes, read_results

REPO = Path(__file__).resolve().parents[1]
MAX_STEPS = 12
#: Half of the answers cannot be parsed: the fallback must be applied and counted.
SCRIPT = "mock:hash:ACTION: LEFT|I will go RIGHT|<action>DO</action>|hmm, not sure|zzz qqq"


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))


def config(out: Path, **overrides: Any) -> Any:
    settings = {
        "model": SCRIPT,
        "variant": "classic",
        "categories": ["combo", "new_objects"],
        "max_steps": MAX_STEPS,
        "batch_size": 3,
        "limit": 7,
        "output_dir": str(out),
    }
    settings.update(overrides)
    return build_config(settings)


def run(cfg: Any, env: CrafTextEnv) -> Any:
    with get_model(cfg.model, cfg.generation) as model:
        return run_eval(cfg, model, env=env)


def test_runs_of_the_same_settings_in_one_process_share_one_env(tmp_path: Path) -> None:
    """A run made without an env plays on the process's shared one for its settings, so a
    second run of those settings traces nothing again."""
    settings = EnvConfig(variant=Variant.CLASSIC, max_steps=5)
    env = shared_env(settings)
    assert shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=5)) is env
    assert shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=6)) is not env
    traced = []
    for attempt in range(2):
        cfg = config(tmp_path / str(attempt), max_steps=5, limit=3)
        with get_model(cfg.model, cfg.generation) as model:
            run_eval(cfg, model)
        traced.append(env.batched_step._cache_size())
    assert traced == [1, 1]
    # Held weakly: an env nobody holds any more is freed with its compiled functions.
    dropped = weakref.ref(shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=7)))
    gc.collect()
    assert dropped() is None


def canonical(run_dir: Path) -> list[dict[str, Any]]:
    episodes = read_episodes(run_dir / "episodes.jsonl")
    return sorted((e.model_dump() for e in episodes), key=lambda e: e["episode_id"])


def test_run_writes_consistent_steps_episodes_and_results(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    outcome = run(config(tmp_path), short_env)

    episodes = read_episodes(tmp_path / "episodes.jsonl")
    assert len(episodes) == 7 == len({e.episode_id for e in episodes})
    assert {e.category for e in episodes} == {"combo", "new_objects"}
    steps = [json.loads(line) for line in (tmp_path / "steps.jsonl").read_text().splitlines()]
    for episode in episodes:
        own = [s for s in steps if s["episode_id"] == episode.episode_id]
        assert [s["step"] for s in own] == list(range(episode.steps))
        assert sum(s["fallback_used"] for s in own) == episode.invalid_actions
        assert own[-1]["done"] and not any(s["done"] for s in own[:-1])
        assert sum(s["reward"] for s in own) == pytest.approx(episode.episode_return)
        if episode.termination == "timeout":
            assert episode.steps == MAX_STEPS
    fallbacks = [s for s in steps if s["fallback_used"]]
    assert fallbacks and all(s["action_name"] == "NOOP" for s in fallbacks)
    assert all(s["parse_stage"] == "invalid" for s in fallbacks)
    assert any(not s["fallback_used"] for s in steps)

    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.finished_at is not None
    assert results.config["model"] == SCRIPT
    assert results.versions["craftax"] == "1.6.1"
    assert results.dataset["kind"] in {"archive", "wheel", "directory", "json"}
    assert outcome.summary is not None and outcome.summary.overall.episodes == 7


@pytest.mark.parametrize("every_s", [0.0, 3600.0])
def test_results_are_rewritten_at_most_every_results_every_s_and_always_at_the_end(
    tmp_path: Path, short_env: CrafTextEnv, monkeypatch: pytest.MonkeyPatch, every_s: float
) -> None:
    from llm_agents.evaluation import sink

    monkeypatch.setattr(sink, "RESULTS_EVERY_S", every_s)
    monkeypatch.setattr(sink, "RESULTS_TIME_SHARE", math.inf)  # no wait for a rewrite's cost
    written: list[str] = []
    write = sink.write_results
    monkeypatch.setattr(
        sink,
        "write_results",
        lambda path, results: (written.append(results.status), write(path, results)),
    )
    run(config(tmp_path, limit=5), short_env)
    # Without a wait, each round that ends an episode rewrites it (5 episodes, 3 in flight:
    # more than one round); with an hour's, only the run's start and end do.
    assert written[-1] == "complete" == read_results(tmp_path / "results.json").status
    if every_s:
        assert written == ["partial", "complete"]
    else:
        assert len(written) > 3


def test_results_rewrites_wait_longer_when_a_rewrite_is_slow(
    tmp_path: Path, short_env: CrafTextEnv, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.evaluation import sink

    # No fixed wait: each round that ends an episode would rewrite it (the test above); a
    # rewrite as slow as a long run's, kept to a small share of the time, waits past this run.
    monkeypatch.setattr(sink, "RESULTS_EVERY_S", 0.0)
    monkeypatch.setattr(sink, "RESULTS_TIME_SHARE", 0.001)
    written: list[str] = []
    write = sink.write_results

    def slow_write(path: Path, results: sink.RunResults) -> None:
        written.append(results.status)
        time.sleep(0.2)
        write(path, results)

    monkeypatch.setattr(sink, "write_results", slow_write)
    run(config(tmp_path, limit=5), short_env)
    assert written == ["partial", "complete"]
    assert read_results(tmp_path / "results.json").finished == 5


def test_limited_schedule_samples_every_category_originals_first(tmp_path: Path) -> None:
    from env.dataset import load_dataset

    cfg = config(tmp_path, categories=["combo", "paraphrased", "new_objects"], limit=6)
    instructions = load_dataset(None).instructions(cfg.categories)
    schedule = build_schedule(cfg, instructions, None)
    assert [s.category for s in schedule] == ["combo", "paraphrased", "new_objects"] * 2
    assert all(s.instruction.variant == 0 for s in schedule)
    assert len({s.episode_id for s in schedule}) == 6


def test_results_do_not_depend_on_batch_size(tmp_path: Path, short_env: CrafTextEnv) -> None:
    run(config(tmp_path / "b3", limit=5), short_env)
    run(config(tmp_path / "b2", limit=5, batch_size=2), short_env)
    assert canonical(tmp_path / "b3") == canonical(tmp_path / "b2")


def _cli(out: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "llm_agents.cli", "eval", "--model", SCRIPT, "--variant", "classic",
        "--categories", "combo", "new_objects", "--max-steps", str(MAX_STEPS), "--batch-size", "2",
        "--limit", "10", "--output-dir", str(out), "--no-progress", *extra,
    ]  # fmt: skip


def _wait_for_episodes(path: Path, process: subprocess.Popen[bytes], count: int) -> None:
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and process.poll() is None:
        if path.exists() and len(path.read_text().splitlines()) >= count:
            return
        time.sleep(0.02)
    raise AssertionError(f"no {count} episodes before the run ended: {process.poll()}")


@pytest.mark.slow
def test_sigkill_then_resume_equals_an_uninterrupted_run(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    reference = tmp_path / "reference"
    run(config(reference, limit=10, batch_size=2, categories=["combo", "new_objects"]), short_env)

    killed = tmp_path / "killed"
    process = subprocess.Popen(
        _cli(killed), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    _wait_for_episodes(killed / "episodes.jsonl", process, 2)
    process.send_signal(signal.SIGKILL)
    process.wait()
    done_at_kill = len(read_episodes(killed / "episodes.jsonl"))
    assert done_at_kill < 10, "the run finished before it could be killed"
    assert read_results(killed / "results.json").status == "partial"

    resumed = subprocess.run(_cli(killed), cwd=REPO, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    assert canonical(killed) == canonical(reference)
    steps = [json.loads(line) for line in (killed / "steps.jsonl").read_text().splitlines()]
    keys = [(s["episode_id"], s["step"]) for s in steps]
    assert len(keys) == len(set(keys)), "a step was recorded twice"
    assert len(steps) == sum(e["steps"] for e in canonical(killed))
    assert read_results(killed / "results.json").status == "complete"


@pytest.mark.slow
def test_ctrl_c_writes_a_partial_summary(tmp_path: Path) -> None:
    out = tmp_path / "interrupted"
    # Answers slow enough that the run cannot finish between its first episode and the signal,
    # even on a loaded machine: 4 more rounds of 12 steps at 0.25 s each remain.
    slow = _cli(out, "--backend-option", "latency_s=0.25")
    process = interruptible_run(slow, REPO)
    _wait_for_episodes(out / "episodes.jsonl", process, 1)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert len(read_episodes(out / "episodes.jsonl")) < 10, "the run ended before the signal"
    assert process.returncode == 130, stderr.decode()
    results = read_results(out / "results.json")
    assert results.status == "partial"
    assert results.summary is not None
    assert results.summary.overall.episodes == len(read_episodes(out / "episodes.jsonl"))
    assert b"rerun the same command to resume" in stderr


def test_a_ctrl_c_that_something_swallows_still_stops_the_run(
    tmp_path: Path, short_env: CrafTextEnv, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.agents.strategies.zero_shot import ZeroShotAgent

    decide = ZeroShotAgent.decide
    calls = 0

    def decide_then_swallow_a_ctrl_c(self: Any, *args: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls == 5:
            with contextlib.suppress(KeyboardInterrupt):  # as code catching everything would
                signal.raise_signal(signal.SIGINT)
        return decide(self, *args)

    monkeypatch.setattr(ZeroShotAgent, "decide", decide_then_swallow_a_ctrl_c)
    # The latch is installed only over Python's own handler (another one is left alone); an
    # earlier test in the same process (Ray, a server) may have left its own in place.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            run(config(tmp_path, limit=6, batch_size=2), short_env)
    finally:
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(
            signal.SIGINT, previous if previous is not None else signal.default_int_handler
        )
    assert read_results(tmp_path / "results.json").status == "partial"
    assert calls < 6 * MAX_STEPS


def test_resume_refuses_a_directory_of_another_run(
    tmp_path: Path, short_env: CrafTextEnv, capsys: Any
) -> None:
    run(config(tmp_path, limit=1, batch_size=1), short_env)
    code = main(
        ["eval", "--model", "mock:noop", "--variant", "classic", "--output-dir", str(tmp_path)]
    )
    assert code == EXIT_USER_ERROR
    assert "other settings" in capsys.readouterr().err


def test_resume_under_another_choice_scoring_is_refused_naming_both(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    run(config(tmp_path, limit=1, batch_size=1, choice="loglik", choice_scoring="pmi"), short_env)
    with pytest.raises(UserError, match=r'choice_scoring \("pmi" before, "bytes" now\)'):
        run(
            config(tmp_path, limit=1, batch_size=1, choice="loglik", choice_scoring="bytes"),
            short_env,
        )


@pytest.mark.parametrize("choice", ["loglik", "guided"])
def test_a_run_recorded_before_choice_scoring_resumes_under_the_rule_it_played(
    tmp_path: Path, short_env: CrafTextEnv, choice: str
) -> None:
    # Played and recorded as before the setting existed: loglik summed the names' tokens.
    played = config(tmp_path, limit=2, batch_size=1, choice=choice)
    if choice == "loglik":
        played = config(tmp_path, limit=2, batch_size=1, choice=choice, choice_scoring="sum")
    run(played.model_copy(update={"limit": 1}), short_env)
    results = json.loads((tmp_path / "results.json").read_text())
    del results["identity"]["settings"]["choice_scoring"]
    del results["config"]["choice_scoring"]
    (tmp_path / "results.json").write_text(json.dumps(results))
    assert EvalConfig.recorded(results["config"]).choice_scoring == "sum"
    if choice == "loglik":
        # The default now is another rule: resuming under it would mix two rules in one run.
        with pytest.raises(UserError, match=r'choice_scoring \("sum" before, "\w+" now\)'):
            run(config(tmp_path, limit=2, batch_size=1, choice=choice), short_env)
    # Guided never read the scoring: any run of it resumes as it is.
    run(played, short_env)
    assert len(read_episodes(tmp_path / "episodes.jsonl")) == 2


@pytest.mark.parametrize("agent", ["skills", "zero-shot"])
def test_a_run_recorded_before_stuck_after_resumes_as_it_played(
    tmp_path: Path, short_env: CrafTextEnv, agent: str
) -> None:
    # Played and recorded as before the setting existed: the skills agent never stopped asking.
    never = {"stuck_after": 0} if agent == "skills" else {}
    played = config(tmp_path, limit=2, batch_size=1, agent=agent, **never)
    run(played.model_copy(update={"limit": 1}), short_env)
    results = json.loads((tmp_path / "results.json").read_text())
    del results["identity"]["settings"]["stuck_after"]
    del results["config"]["stuck_after"]
    (tmp_path / "results.json").write_text(json.dumps(results))
    assert EvalConfig.recorded(results["config"]).stuck_after == 0
    if agent == "skills":
        with pytest.raises(UserError, match=r"stuck_after \(0 before, 3 now\)"):
            run(config(tmp_path, limit=2, batch_size=1, agent=agent), short_env)
    # Other agents never read it: their runs resume under the defaults.
    run(played, short_env)
    assert len(read_episodes(tmp_path / "episodes.jsonl")) == 2


def test_config_file_is_overridden_by_flags(tmp_path: Path) -> None:
    from llm_agents.evaluation.config import load_config_file

    file = tmp_path / "run.toml"
    file.write_text(
        'model = "mock:noop"\nmax_steps = 40\nsplits = ["combo"]\n[generation]\ntemperature = 0.5\n'
    )
    cfg = build_config(load_config_file(file), {"max_steps": 20, "generation": {"max_tokens": 32}})
    assert (cfg.model, cfg.max_steps, cfg.categories) == ("mock:noop", 20, ("combo",))
    assert (cfg.generation.temperature, cfg.generation.max_tokens) == (0.5, 32)
    yaml_file = tmp_path / "run.yaml"
    yaml_file.write_text("variant: classic\nbatch_size: 4\n")
    assert build_config(load_config_file(yaml_file)).batch_size == 4


def test_report_command_rebuilds_table_and_chart(
    tmp_path: Path, short_env: CrafTextEnv, capsys: Any
) -> None:
    run(config(tmp_path, limit=2, batch_size=2), short_env)
    assert main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "combo" in out and "Qwen QwQ-32B" in out
    assert (tmp_path / "success.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["report", str(tmp_path / "missing")]) == EXIT_USER_ERROR


def test_prompts_carry_real_observations_and_action_outcomes(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    model = MockModel("cycle:ACTION: LEFT")
    run_eval(
        config(tmp_path, model="mock:cycle:ACTION: LEFT", limit=1, batch_size=1),
        model,
        env=short_env,
    )
    users = [messages[-1].content for messages, _ in model.requests]
    assert len(users) == MAX_STEPS
    assert "first step" in users[0]
    assert "Health" in users[0] and "Inventory" in users[0]
    # Every later prompt reports what the previous LEFT did, read off two real observations.
    for user in users[1:]:
        assert "LEFT: moved west" in user or "LEFT: blocked" in user


HASH_SCRIPT = SCRIPT.removeprefix("mock:")


def test_prompts_and_step_records_are_what_validation_and_the_plain_hash_give(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    """The play loop builds its messages and records unvalidated (`env.trusted`) and hashes
    prompts from a kept state: each must be exactly what the straightforward path gives."""
    model = MockModel(HASH_SCRIPT)
    run_eval(config(tmp_path, limit=4, batch_size=2), model, env=short_env)
    lines = (tmp_path / "steps.jsonl").read_text().splitlines()
    records = [StepRecord.model_validate_json(line) for line in lines]
    assert [record.model_dump_json() for record in records] == lines
    plain_hashes = set()
    for messages, _ in model.requests:
        for message in messages:
            assert ChatMessage.model_validate(message.model_dump()) == message
            assert type(message.content) is str
        payload = json.dumps([[m.role, m.content] for m in messages], ensure_ascii=False)
        plain_hashes.add(hashlib.sha256(payload.encode()).hexdigest())
    assert len(records) == len(model.requests) > 4 * 2
    assert {record.prompt_hash for record in records} == plain_hashes


@pytest.mark.parametrize(
    ("make_model", "named"),
    [
        (lambda tmp: MockModel("cycle:ACTION: DO"), "mock:cycle:ACTION: DO"),
        (lambda tmp: MockModel(HASH_SCRIPT, GenerateConfig(max_tokens=7)), "generation"),
        (lambda tmp: CachedModel(MockModel(HASH_SCRIPT), tmp / "x.sqlite"), "x.sqlite"),
    ],
    ids=["another model", "other generation settings", "a cache the config lacks"],
)
def test_a_model_other_than_the_configs_is_refused_before_anything_is_written(
    tmp_path: Path, short_env: CrafTextEnv, make_model: Any, named: str
) -> None:
    out = tmp_path / "run"
    with (
        pytest.raises(ValueError, match="not the config's") as refused,
        make_model(tmp_path) as model,
    ):
        run_eval(config(out, limit=1), model, env=short_env)
    assert named in str(refused.value)
    assert not out.exists()


def test_the_configs_response_cache_is_honoured_and_a_model_without_it_refused(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    cache = tmp_path / "answers.sqlite"
    first = config(tmp_path / "first", limit=2, cache=str(cache))
    with (
        pytest.raises(ValueError, match="response cache"),
        MockModel(HASH_SCRIPT) as plain,
    ):
        run_eval(first, plain, env=short_env)
    assert not (tmp_path / "first").exists()

    with open_model(first) as model:
        run_eval(first, model, env=short_env)
    again = first.model_copy(update={"output_dir": str(tmp_path / "again")})
    with open_model(again) as model:
        run_eval(again, model, env=short_env)
    steps = [
        json.loads(line) for line in (tmp_path / "again" / "steps.jsonl").read_text().splitlines()
    ]
    assert steps and all(step["cached"] for step in steps)
    # The same episodes; only what they cost differs: answers from the cache compute no prompt.
    replayed, played = canonical(tmp_path / "again"), canonical(tmp_path / "first")
    assert all(episode.pop("computed_prompt_tokens") == 0 for episode in replayed)
    for episode in played:
        episode.pop("computed_prompt_tokens")
    assert replayed == played


class JitteryModel(MockModel):
    """The hash mock answering each call after a random delay, either as a server would
    (concurrent one-conversation calls) or as an engine would (one batch at a time)."""

    def __init__(self, concurrent: bool, seed: int, max_concurrency: int = 8):
        super().__init__(
            SCRIPT.removeprefix("mock:"), GenerateConfig(max_concurrency=max_concurrency)
        )
        self.concurrent_requests = concurrent
        self.batch_sizes: list[int] = []
        self.most_in_flight = 0
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._in_flight = 0

    def generate(self, conversations: Any, choices: Any = None, schema: Any = None) -> Any:
        with self._lock:
            delay = self._rng.lognormvariate(-5.0, 1.0)
            self._in_flight += 1
            self.most_in_flight = max(self.most_in_flight, self._in_flight)
            self.batch_sizes.append(len(conversations))
        time.sleep(delay)
        try:
            return super().generate(conversations, choices, schema)
        finally:
            with self._lock:
                self._in_flight -= 1


@pytest.mark.parametrize(
    ("batch_size", "concurrent", "max_concurrency", "limit"),
    [
        (3, True, 8, 7),
        (7, True, 2, 7),
        (4, False, 8, 7),
        (7, False, 8, 7),
        # More slots than one group of the env's grouped step: few ready slots are stepped in
        # groups, most in the masked step, and episodes ending together refill in one reset.
        pytest.param(12, True, 12, 16, marks=pytest.mark.slow),
    ],
)
def test_episodes_do_not_depend_on_episodes_in_flight_or_answer_timing(
    tmp_path: Path,
    short_env: CrafTextEnv,
    batch_size: int,
    concurrent: bool,
    max_concurrency: int,
    limit: int,
) -> None:
    reference = tmp_path / "reference"
    run_eval(
        config(reference, batch_size=1, limit=limit),
        MockModel(SCRIPT.removeprefix("mock:")),
        env=short_env,
    )
    model = JitteryModel(concurrent, seed=batch_size, max_concurrency=max_concurrency)
    out = tmp_path / "jittery"
    generation = {"max_concurrency": max_concurrency}
    run_eval(
        config(out, batch_size=batch_size, limit=limit, generation=generation), model, env=short_env
    )

    assert canonical(out) == canonical(reference)
    if concurrent:
        assert set(model.batch_sizes) == {1}
        assert 1 < model.most_in_flight <= max_concurrency
    else:
        assert model.most_in_flight == 1 and max(model.batch_sizes) > 1
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    for episode in canonical(out):
        own = [s["step"] for s in steps if s["episode_id"] == episode["episode_id"]]
        assert own == list(range(episode["steps"]))
    assert len(steps) == sum(e["steps"] for e in canonical(out))


def test_backend_options_reach_the_backend_and_the_saved_config(tmp_path: Path) -> None:
    out = tmp_path / "run"
    argv = [
        "eval", "--model", "mock:noop", "--variant", "classic", "--categories", "combo",
        "--max-steps", str(MAX_STEPS), "--batch-size", "1", "--limit", "1",
        "--output-dir", str(out), "--no-progress", "--backend-option", "latency_s=0.001",
    ]  # fmt: skip
    assert main(argv) == 0
    results = read_results(out / "results.json")
    assert results.config["backend_options"] == {"latency_s": 0.001}
    steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    assert steps and all(s["latency_s"] == 0.001 for s in steps)
    with pytest.raises(SystemExit) as exit_info:
        main([*argv[:-1], "latency_s"])
    assert exit_info.value.code == 2


def test_a_run_recorded_before_categories_were_named_so_still_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Runs made when the setting was `splits` (flag, config key, identity) keep working.
    out = tmp_path / "run"
    argv = [
        "eval", "--model", "mock:noop", "--variant", "classic", "--splits", "combo",
        "--max-steps", "3", "--batch-size", "1", "--limit", "2", "--output-dir", str(out),
        "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    notice = "craftext-llm eval: warning: --splits is deprecated; use --categories"
    assert notice in capsys.readouterr().err.splitlines()
    results_file = out / "results.json"
    recorded = json.loads(results_file.read_text())
    assert recorded["config"]["categories"] == ["combo"]
    for table in (recorded["config"], recorded["identity"]["settings"]):
        table["splits"] = table.pop("categories")
    results_file.write_text(json.dumps(recorded))

    assert main(argv) == 0
    resumed = read_results(results_file)
    assert (resumed.scheduled, resumed.finished) == (2, 2)
    assert resumed.identity.settings["categories"] == ["combo"]
    # The old name still names the setting: another category is still another run.
    assert main([*argv[:5], "--splits", "new_objects", *argv[7:]]) == EXIT_USER_ERROR
    capsys.readouterr()
    assert main([*argv[:5], "--categories", "combo", *argv[7:]]) == 0
    assert "deprecated" not in capsys.readouterr().err
