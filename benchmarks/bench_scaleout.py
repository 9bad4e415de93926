"""Scale-out: what `--ray` costs over a local run, and what a second server endpoint buys.

1. The same mock run (`mock:hash`, zero latency: the framework's own cost) played locally, then
   with `--ray` on a local Ray cluster started for the run (one worker, then two), each as the
   CLI run by a user. Reported: the whole command's wall time (Ray's start and each worker's
   env and model load included), and episodes/s while playing (from `results.json`: the run's
   start, once the workers are up, to its end).
2. Throughput against a fixed-latency server (a loopback process answering each request after
   `--latency` seconds, at most `--capacity` at once, like one GPU's batch) through one endpoint,
   then two (`openai:M@URL1,URL2`): requests/s of the backend alone (`--requests` requests,
   `--in-flight` at once), and agent-steps/s of an eval run against the servers.

Each batch size is played once before it is measured, so that JAX's persistent compilation
cache holds the game for every measured run (the first run on a machine compiles for minutes).

    python benchmarks/bench_scaleout.py [--episodes 32] [--max-steps 20] [--latency 0.05]
        [--capacity 4] [--requests 400] [--in-flight 32]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FAULT_SERVER = REPO / "tests" / "fault_server.py"
SCRIPT = "mock:hash:ACTION: LEFT|ACTION: RIGHT|ACTION: UP|ACTION: DOWN|ACTION: DO"


def _environment() -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)
    # A cluster that `RAY_ADDRESS` names would measure that cluster, not this machine.
    return {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {"PYTHONPATH": path}


def _eval(args: argparse.Namespace, model: str, out: Path, *extra: str) -> tuple[float, float]:
    """Run `craftext-llm eval`; (wall seconds of the command, episodes/s while playing)."""
    from llm_agents.run_data.store import read_results

    argv = [
        sys.executable, "-m", "llm_agents.cli", "eval", "--model", model, "--variant", "classic",
        "--categories", "combo", "new_objects", "--limit", str(args.episodes),
        "--max-steps", str(args.max_steps), "--batch-size", str(args.batch_size),
        "--output-dir", str(out), "--no-progress", *extra,
    ]  # fmt: skip
    started = time.perf_counter()
    subprocess.run(argv, check=True, env=_environment(), cwd=REPO, capture_output=True)
    wall = time.perf_counter() - started
    results = read_results(out / "results.json")
    assert results.status == "complete" and results.finished_at is not None, results.status
    playing = (results.finished_at - results.started_at).total_seconds()
    return wall, results.finished / playing


def _warm_up(args: argparse.Namespace, root: Path, batch_size: int) -> None:
    """Fill JAX's persistent compilation cache for this batch size, so that no measured run
    pays for compiling the game while the others load it."""
    _eval(
        args, SCRIPT, root / f"warm{batch_size}", "--limit", str(batch_size),
        "--batch-size", str(batch_size),
    )  # fmt: skip


def ray_overhead(args: argparse.Namespace, root: Path) -> None:
    print(
        f"== --ray vs local: {SCRIPT.split(':')[0]}:hash, {args.episodes} episodes x "
        f"{args.max_steps} steps, classic, --batch-size {args.batch_size} (per worker with --ray)"
    )
    _warm_up(args, root, args.batch_size)
    local_wall, local_rate = _eval(args, SCRIPT, root / "local")
    print(f"local            : command {local_wall:6.1f} s, playing {local_rate:7.2f} episodes/s")
    for workers in (1, 2):
        wall, rate = _eval(
            args, SCRIPT, root / f"ray{workers}", "--ray", "--ray-workers", str(workers)
        )
        print(
            f"--ray, {workers} worker{'s' if workers > 1 else ' '}: command {wall:6.1f} s, "
            f"playing {rate:7.2f} episodes/s; ray / local: {rate / local_rate:.2f}x episodes/s, "
            f"{wall / local_wall:.2f}x wall"
        )


def _start_server(args: argparse.Namespace) -> tuple[subprocess.Popen[str], str]:
    options = ["--latency", str(args.latency), "--capacity", str(args.capacity)]
    server = subprocess.Popen(
        [sys.executable, str(FAULT_SERVER), *options], stdout=subprocess.PIPE, text=True
    )
    assert server.stdout is not None
    return server, server.stdout.readline().strip()


def _requests_per_s(args: argparse.Namespace, urls: list[str]) -> tuple[float, float]:
    """Requests/s of the backend alone, and the client's CPU milliseconds per request (this
    process only: the servers are processes of their own)."""
    from llm_agents.backends.base import ChatMessage, GenerateConfig
    from llm_agents.backends.openai import OpenAIModel

    config = GenerateConfig(max_concurrency=args.in_flight, timeout_s=30.0)
    model = OpenAIModel("bench", config, base_url=",".join(urls))
    # One conversation per call from many threads: how the runner's dispatcher feeds a server.
    conversations = [[ChatMessage(role="user", content=f"q{i}")] for i in range(args.requests)]
    started, cpu = time.perf_counter(), time.process_time()
    with concurrent.futures.ThreadPoolExecutor(args.in_flight) as pool:
        outputs = list(pool.map(lambda c: model.generate([c])[0], conversations))
    elapsed, cpu = time.perf_counter() - started, time.process_time() - cpu
    assert all(o.finish_reason != "error" for o in outputs), "a request failed"
    model.close()
    return args.requests / elapsed, cpu / args.requests * 1000


def endpoints_throughput(args: argparse.Namespace, root: Path) -> None:
    ceiling = args.capacity / args.latency
    print(
        f"== fixed-latency servers: {args.latency * 1000:.0f} ms per answer, {args.capacity} at "
        f"once (ceiling {ceiling:.0f} requests/s per server), {args.in_flight} in flight"
    )
    _warm_up(args, root, args.in_flight)
    servers = [_start_server(args) for _ in range(2)]
    try:
        urls = [url for _, url in servers]
        one, one_cpu = _requests_per_s(args, urls[:1])
        two, two_cpu = _requests_per_s(args, urls)
        print(
            f"backend, {args.requests} requests: 1 endpoint {one:6.1f} requests/s, "
            f"2 endpoints {two:6.1f} requests/s: {two / one:.2f}x; client CPU per request "
            f"{one_cpu:.2f} ms and {two_cpu:.2f} ms"
        )
        steps = []
        for count in (1, 2):
            model = f"openai:bench@{','.join(urls[:count])}"
            out = root / f"endpoints{count}"
            _eval(
                args, model, out, "--batch-size", str(args.in_flight),
                "--max-concurrency", str(args.in_flight),
            )  # fmt: skip
            from llm_agents.run_data.store import read_results

            results = read_results(out / "results.json")
            assert results.summary is not None and results.finished_at is not None
            playing = (results.finished_at - results.started_at).total_seconds()
            agent_steps = sum(e.requests - e.errors for e in results.endpoints)
            steps.append(agent_steps / playing)
        print(
            f"eval, {args.episodes} episodes x {args.max_steps} steps, --batch-size "
            f"{args.in_flight}: 1 endpoint {steps[0]:6.1f} agent-steps/s, 2 endpoints "
            f"{steps[1]:6.1f} agent-steps/s: {steps[1] / steps[0]:.2f}x"
        )
    finally:
        for process, _ in servers:
            process.kill()
            process.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--max-steps", type=int, default=20)
    parser.add_argument("--batch-size", type=int, default=8, help="for the --ray comparison")
    parser.add_argument("--latency", type=float, default=0.05, help="seconds per answer")
    parser.add_argument("--capacity", type=int, default=4, help="answers a server makes at once")
    parser.add_argument("--requests", type=int, default=400)
    parser.add_argument("--in-flight", type=int, default=32)
    parser.add_argument("--skip-ray", action="store_true", help="only the endpoints part")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_scaleout_") as tmp:
        root = Path(tmp)
        if not args.skip_ray:
            ray_overhead(args, root)
        endpoints_throughput(args, root)


if __name__ == "__main__":
    main()
