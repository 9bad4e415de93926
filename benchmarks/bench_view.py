"""Speed and size of `craftext-llm view`: replaying and rendering a run against playing it.

Plays a run with a zero-latency mock backend (timed), then builds its report (timed) and prints
render time per episode and per frame, the report's size, and render time over play time (the
issue's bar: rendering a run must not take longer than playing it with the mock backend).
Each is measured after a warm-up of the same shapes, so compilation is not counted in either;
the view's one-off startup (tracing, compiling) is estimated from its warm-up and printed apart.

    python benchmarks/bench_view.py [--episodes 64] [--max-steps 250] [--variant full]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from env import CrafTextEnv, EnvConfig, Variant
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.viewer import build_view

ANSWERS = ["ACTION: LEFT", "ACTION: DO", "ACTION: UP", "ACTION: RIGHT", "ACTION: DOWN"]


def play(env: CrafTextEnv, out: Path, episodes: int, batch: int) -> float:
    config = build_config(
        {
            "model": "mock:cycle:LEFT",
            "variant": env.variant.value,
            "splits": ["combo", "paraphrased", "new_objects"],
            "max_steps": env.config.max_steps,
            "batch_size": batch,
            "limit": episodes,
            "output_dir": str(out),
        }
    )
    start = time.perf_counter()
    run_eval(config, MockModel(outputs=ANSWERS), env=env)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    parser.add_argument("--batch-size", type=int, default=32, help="episodes played in lockstep")
    parser.add_argument("--replay-batch", type=int, default=16, help="episodes replayed at once")
    args = parser.parse_args()

    env = CrafTextEnv(EnvConfig(variant=Variant(args.variant), max_steps=args.max_steps))
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        warm = workdir / "warm"
        play(env, warm, args.batch_size, args.batch_size)
        start = time.perf_counter()
        cold = build_view(warm, progress=False, batch_size=args.replay_batch)
        cold_seconds = time.perf_counter() - start

        run = workdir / "run"
        played = play(env, run, args.episodes, args.batch_size)
        start = time.perf_counter()
        outcome = build_view(run, progress=False, batch_size=args.replay_batch)
        rendered = time.perf_counter() - start

    episodes = len(outcome.statuses)
    mismatches = len(outcome.mismatches)
    print(
        f"{episodes} episodes, {outcome.frames} frames ({args.variant} Craftax, "
        f"at most {args.max_steps} steps), mock backend at batch {args.batch_size}, "
        f"replayed {args.replay_batch} at a time"
    )
    print(f"play (mock backend):   {played:8.1f} s")
    print(
        f"view (whole command): {rendered:8.1f} s = {rendered / episodes * 1000:.0f} ms per "
        f"episode, {rendered / outcome.frames * 1000:.2f} ms per frame"
    )
    print(
        f"  of which replay, render, encode and write: {outcome.render_seconds:.1f} s "
        f"({outcome.render_seconds / outcome.frames * 1000:.2f} ms per frame)"
    )
    print(f"view / play:           {rendered / played:8.2f}  (target: <= 1)")
    startup = cold_seconds - cold.frames * rendered / outcome.frames
    print(
        f"view startup (trace, compile or load from the compilation cache; once per command): "
        f"about {startup:.1f} s"
    )
    print(
        f"report size:           {outcome.size_bytes / 1e6:8.1f} MB = "
        f"{outcome.size_bytes / episodes / 1e3:.0f} kB per episode, "
        f"{outcome.size_bytes / outcome.frames:.0f} B per frame"
    )
    print(f"replays not reproducing their record: {mismatches}")


if __name__ == "__main__":
    main()
