"""`eval --ray` on a real local Ray cluster (CPU only, two workers): the episodes of a local run,
a worker killed mid-run, a driver killed and restarted, an agent from outside the package shipped
to the workers, and the install hint without Ray."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fault_server import FaultServer
from outside_agents import EXAMPLE_AGENT, write_outside_package

from env import EnvConfig, Variant, shared_env
from env.errors import UserError
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import BackendFailure, prepare_run, run_eval
from llm_agents.judging.report import report_run
from llm_agents.run_data.store import read_episodes, read_results

ray = pytest.importorskip("ray")

from llm_agents.evaluation.ray_runner import LOCAL_CLUSTER_SYSTEM_CONFIG, run_on_ray  # noqa: E402

MAX_STEPS = 6
EPISODES = 8
SCRIPT = "mock:hash:ACTION: LEFT|I will go RIGHT|<action>DO</action>|zzz"
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cluster() -> Iterator[str]:
    """A local Ray cluster on loopback for the module; yields its address."""
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        logging_level=logging.WARNING,
        _node_ip_address="127.0.0.1",
        _system_config=LOCAL_CLUSTER_SYSTEM_CONFIG,
    )
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


def config(out: Path, **overrides: Any) -> Any:
    settings = {
        "model": SCRIPT,
        "variant": "classic",
        "categories": ["combo", "new_objects"],
        "max_steps": MAX_STEPS,
        "batch_size": 2,
        "limit": EPISODES,
        "output_dir": str(out),
        "ray_workers": 2,
    }
    return build_config(settings | overrides)


def episodes(run_dir: Path) -> list[dict[str, Any]]:
    return sorted(
        (e.model_dump() for e in read_episodes(run_dir / "episodes.jsonl")),
        key=lambda e: e["episode_id"],
    )


def steps(run_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (run_dir / "steps.jsonl").read_text().splitlines()]


def decisions(run_dir: Path) -> list[tuple[str, int, str, str]]:
    """Every step's identity and outcome, timing left out, in a canonical order."""
    return sorted(
        (s["episode_id"], s["step"], s["prompt_hash"], s["action_name"]) for s in steps(run_dir)
    )


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("local")
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(out), model, env=env)
    return out


def test_the_workers_play_at_the_drivers_priority(cluster: str) -> None:
    @ray.remote
    def niceness() -> int:
        return os.nice(0)

    assert ray.get(niceness.remote()) == os.nice(0)


def test_a_ray_run_gives_the_episodes_of_a_local_run(
    cluster: str, local_run: Path, tmp_path: Path
) -> None:
    outcome = run_on_ray(prepare_run(config(tmp_path, ray=True)))
    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.finished == EPISODES
    assert outcome.results.versions["ray"] == ray.__version__
    assert episodes(tmp_path) == episodes(local_run)
    assert decisions(tmp_path) == decisions(local_run)
    assert report_run(tmp_path) == report_run(local_run)


def test_a_ray_run_records_its_workers_machines_not_the_drivers(
    cluster: str, tmp_path: Path
) -> None:
    cores = os.sched_getaffinity(0)
    if len(cores) < 2:
        pytest.skip("the driver is told from its workers by pinning it to one of two cores")
    # The workers were started by the cluster's raylet, on every core; the driver sees one.
    os.sched_setaffinity(0, {min(cores)})
    try:
        run_on_ray(prepare_run(config(tmp_path, ray=True, limit=2)))
    finally:
        os.sched_setaffinity(0, cores)
    results = read_results(tmp_path / "results.json")
    assert len(results.worker_hardware) == 2
    assert {machine["cpu_cores"] for machine in results.worker_hardware} == {str(len(cores))}
    assert results.hardware == results.worker_hardware[0] | {"workers": "2"}


def _parent(pid: int) -> int:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    return int(stat.rpartition(")")[2].split()[1])


def worker_pids() -> list[int]:
    """Processes of the Ray episode workers of this test's cluster (its raylet is our child),
    found by their titles."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            title = (entry / "cmdline").read_bytes().split(b"\0")[0]
        except OSError:
            continue
        if not title.startswith(b"ray::EpisodeWorker"):
            continue
        ancestor = int(entry.name)
        while ancestor > 1 and ancestor != os.getpid():
            ancestor = _parent(ancestor)
        if ancestor == os.getpid():
            found.append(int(entry.name))
    return found


@pytest.mark.slow
def test_a_worker_killed_mid_run_has_its_episodes_played_elsewhere(
    cluster: str, local_run: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    killed: list[int] = []

    def kill_a_worker_after_the_first_episode() -> None:
        deadline = time.monotonic() + 120
        episodes_file = tmp_path / "episodes.jsonl"
        while time.monotonic() < deadline:
            if episodes_file.exists() and episodes_file.read_text().count("\n") >= 1:
                pids = worker_pids()
                if pids:
                    os.kill(pids[0], signal.SIGKILL)
                    killed.append(pids[0])
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_a_worker_after_the_first_episode, daemon=True)
    killer.start()
    # A slow answer (50 ms) keeps the run going long enough for the kill to land mid-run.
    slow = config(tmp_path, ray=True, backend_options={"latency_s": 0.05})
    with caplog.at_level(logging.WARNING, logger="llm_agents.evaluation.ray_runner"):
        run_on_ray(prepare_run(slow))
    killer.join()
    assert killed, "no worker was running to kill"
    lost = [r.getMessage() for r in caplog.records if "lost" in r.getMessage()]
    assert lost and "its 0 unfinished" not in lost[0], lost
    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.finished == EPISODES
    assert episodes(tmp_path) == episodes(local_run)
    # The dead worker's unfinished episodes left no steps behind: each step is there once.
    assert decisions(tmp_path) == decisions(local_run)


@pytest.mark.slow
def test_a_killed_driver_is_resumed_by_the_same_command(
    cluster: str, local_run: Path, tmp_path: Path
) -> None:
    argv = [
        sys.executable, "-m", "llm_agents.cli", "eval", "--ray", "--model", SCRIPT,
        "--variant", "classic", "--categories", "combo", "new_objects", "--max-steps", str(MAX_STEPS),
        "--batch-size", "2", "--limit", str(EPISODES), "--ray-workers", "2",
        "--backend-option", "latency_s=0.1", "--output-dir", str(tmp_path), "--no-progress",
    ]  # fmt: skip
    environment = os.environ | {"RAY_ADDRESS": cluster, "PYTHONPATH": str(REPO)}
    driver = subprocess.Popen(argv, cwd=REPO, env=environment, stderr=subprocess.DEVNULL)
    episodes_file = tmp_path / "episodes.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and driver.poll() is None:
        if episodes_file.exists() and episodes_file.read_text().count("\n") >= 2:
            break
        time.sleep(0.02)
    driver.kill()
    driver.wait()
    # The kill may land between an episode's line and the results file: the line counts.
    assert 2 <= len(read_episodes(episodes_file)) < EPISODES
    assert read_results(tmp_path / "results.json").status == "partial"

    resumed = subprocess.run(argv, cwd=REPO, env=environment, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.finished == EPISODES
    assert episodes(tmp_path) == episodes(local_run)
    assert decisions(tmp_path) == decisions(local_run)


def test_a_model_that_does_not_answer_stops_a_ray_run_by_the_integrity_rules(
    cluster: str, tmp_path: Path
) -> None:
    # The probe, in each worker, refuses the model before anything is written.
    with pytest.raises(UserError, match="could not start: mock:error:gone does not answer: gone"):
        run_on_ray(prepare_run(config(tmp_path, ray=True, model="mock:error:gone")))
    assert not tmp_path.joinpath("results.json").exists()
    # Without the probe, failed answers trip the circuit breaker, counted across the workers.
    unprobed = config(
        tmp_path, ray=True, model="mock:error:gone", probe=False, max_consecutive_failures=3
    )
    with pytest.raises(BackendFailure, match="3 failed model answers in a row"):
        run_on_ray(prepare_run(unprobed))
    results = read_results(tmp_path / "results.json")
    assert results.status == "failed" and results.finished == 0
    assert results.backend_errors.failed_calls >= 3


def test_the_workers_counts_per_server_add_up_in_the_results(
    cluster: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    servers = [FaultServer(max_requests=1000).start() for _ in range(2)]
    try:
        spec = f"openai:test-model@{servers[0].url},{servers[1].url}"
        run_on_ray(prepare_run(config(tmp_path, ray=True, model=spec, limit=4, max_steps=4)))
    finally:
        for server in servers:
            server.stop()
    results = read_results(tmp_path / "results.json")
    assert results.status == "complete" and results.backend_errors.failed_calls == 0
    chats = [sum(not r.key.startswith("GET ") for r in s.requests) for s in servers]
    # Each worker's probe sends a one-token chat to each server (they list no models).
    probes = 2
    assert [(e.url, e.requests) for e in results.endpoints] == [
        (servers[0].url, chats[0] - probes),
        (servers[1].url, chats[1] - probes),
    ]
    assert sum(e.requests for e in results.endpoints) == len(steps(tmp_path))


def test_an_agent_from_a_folder_is_shipped_to_the_workers_and_plays_as_locally(
    cluster: str,
    tmp_path_factory: pytest.TempPathFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The folder is on the driver's path only: the workers import the agent from what the run
    # ships them.
    outside = write_outside_package(tmp_path_factory.mktemp("outside"))
    monkeypatch.syspath_prepend(str(outside))
    local = tmp_path / "local"
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(local, agent=EXAMPLE_AGENT, limit=4), model, env=env)
    on_ray = tmp_path / "ray"
    run_on_ray(prepare_run(config(on_ray, ray=True, agent=EXAMPLE_AGENT, limit=4)))
    results = read_results(on_ray / "results.json")
    assert results.status == "complete" and results.finished == 4
    assert results.identity.agent == read_results(local / "results.json").identity.agent
    assert results.identity.agent is not None
    assert results.identity.agent.path == EXAMPLE_AGENT
    assert episodes(on_ray) == episodes(local)
    assert decisions(on_ray) == decisions(local)


def test_workers_the_cluster_cannot_hold_are_refused(cluster: str, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="need 1 GPU in all, and the cluster has 0"):
        run_on_ray(prepare_run(config(tmp_path, ray=True, ray_workers=1, ray_worker_gpus=1)))


def test_without_ray_installed_the_error_says_how_to_install_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(UserError, match=r"pip install 'craftext-llm\[ray\]'"):
        run_on_ray(prepare_run(config(tmp_path, ray=True)))
    assert not tmp_path.joinpath("results.json").exists()
