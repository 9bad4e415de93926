"""Batching speed-up of the evaluation runner, and the framework's own cost per agent-step.

1. Wall time of the same episodes at batch 1, 8 and 32 with a mock backend that takes a fixed
   latency per request, requests of a batch served concurrently (like a vLLM server): the
   speed-up over batch 1 against the ideal linear one.
   Two lanes at batch 32 overlap one half's model call with the other half's env and text work.
2. At batch 32 with a zero-latency mock: seconds per agent-step spent in everything but the
   LLM (env step, pull to numpy, textualization, prompt rendering, parsing, logging).

    python benchmarks/bench_runner.py [--latency 0.1] [--episodes 32] [--max-steps 20]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from env import CrafTextEnv, EnvConfig, Variant
from llm_agents.backends.mock import MockModel
from llm_agents.config import build_config
from llm_agents.runner import run_eval

ANSWERS = ["ACTION: LEFT", "ACTION: DO", "ACTION: UP", "ACTION: RIGHT", "ACTION: DOWN"]


def timed_run(
    env: CrafTextEnv, batch: int, episodes: int, latency: float, workdir: Path, lanes: int = 1
) -> tuple[float, int]:
    """Seconds for the run, and agent-steps taken (after a warm-up run compiling this batch size)."""
    settings = {
        "model": "mock:cycle:LEFT",
        "variant": env.variant.value,
        "splits": ["combo", "paraphrased", "new_objects"],
        "max_steps": env.config.max_steps,
        "batch_size": batch,
        "lanes": lanes,
        "limit": episodes,
    }
    warm = build_config(
        settings | {"output_dir": str(workdir / f"warm{batch}-{lanes}"), "limit": batch}
    )
    run_eval(warm, MockModel(outputs=ANSWERS), env=env)
    config = build_config(settings | {"output_dir": str(workdir / f"b{batch}-{lanes}-{latency}")})
    model = MockModel(outputs=ANSWERS, latency_s=latency)
    start = time.perf_counter()
    outcome = run_eval(config, model, env=env)
    elapsed = time.perf_counter() - start
    assert outcome.summary is not None and outcome.summary.overall.episodes == episodes
    return elapsed, len(model.requests)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency", type=float, default=0.1, help="seconds per request")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--max-steps", type=int, default=20)
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    args = parser.parse_args()

    env = CrafTextEnv(EnvConfig(variant=Variant(args.variant), max_steps=args.max_steps))
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        print(
            f"{args.episodes} episodes x {args.max_steps} steps, {args.variant} Craftax, "
            f"mock latency {args.latency * 1000:.0f} ms per request (a batch's requests concurrent)"
        )
        print(
            f"{'batch':>5} {'lanes':>5} {'wall s':>8} {'speed-up':>9} {'ideal':>6} {'efficiency':>11}"
        )
        baseline = None
        for batch, lanes in ((1, 1), (8, 1), (32, 1), (32, 2)):
            elapsed, _ = timed_run(env, batch, args.episodes, args.latency, workdir, lanes)
            baseline = baseline or elapsed
            speedup = baseline / elapsed
            print(
                f"{batch:>5} {lanes:>5} {elapsed:>8.1f} {speedup:>8.1f}x {batch:>5}x "
                f"{speedup / batch:>10.2f}"
            )
        print("target: efficiency (speed-up / ideal) >= 0.8")

        elapsed, steps = timed_run(env, 32, args.episodes, 0.0, workdir)
        print(
            f"framework cost at batch 32 (zero-latency mock): {elapsed / steps * 1000:.2f} ms "
            f"per agent-step ({steps} agent-steps in {elapsed:.1f} s)"
        )


if __name__ == "__main__":
    main()
