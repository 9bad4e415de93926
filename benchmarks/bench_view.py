"""Speed and size of `craftext-llm view`: replaying and rendering a run against playing it.

For each run size, plays a run with a zero-latency mock backend (timed), then builds its report
(timed) and prints, side by side: play time, view time, view / play (the issue's bar: rendering a
run must not take longer than playing it with the mock backend), render time per frame and per
episode, and the report's size. Wall time is what the bar is about; CPU time (all threads of the
process) is printed beside it because on a shared machine the wall time follows the others' load.
Each is measured after a warm-up of the same shapes, so compilation is not counted in either;
the view's one-off startup (tracing, compiling) is estimated from its warm-up and printed apart.

    python benchmarks/bench_view.py [--episodes 64 256] [--max-steps 250] [--variant full]

With `--run DIR` it times `view` on an existing run instead (e.g. an expert Medium run, or a
paper-protocol-sized one with `--sample 100`): the whole command's wall time, what it rendered
and listed, and the report's size.

    python benchmarks/bench_view.py --run runs/medium-expert [--sample 100]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from env import CrafTextEnv, EnvConfig, Variant
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.viewer import Selection, build_view

ANSWERS = ["ACTION: LEFT", "ACTION: DO", "ACTION: UP", "ACTION: RIGHT", "ACTION: DOWN"]
#: The mock script answering them in turn, named in the config as the model that plays.
SCRIPT = "cycle:" + "|".join(ANSWERS)


@dataclass
class Timing:
    wall: float
    cpu: float


@contextmanager
def timed() -> Iterator[Timing]:
    timing = Timing(0.0, 0.0)
    wall, cpu = time.perf_counter(), time.process_time()
    yield timing
    timing.wall, timing.cpu = time.perf_counter() - wall, time.process_time() - cpu


def play(env: CrafTextEnv, out: Path, episodes: int, batch: int) -> Timing:
    config = build_config(
        {
            "model": f"mock:{SCRIPT}",
            "variant": env.variant.value,
            "categories": ["combo", "paraphrased", "new_objects"],
            "max_steps": env.config.max_steps,
            "batch_size": batch,
            "limit": episodes,
            "output_dir": str(out),
        }
    )
    with timed() as timing:
        run_eval(config, MockModel(SCRIPT), env=env)
    return timing


def view_existing(run: Path, sample: int | None, replay_batch: int) -> None:
    """The wall time of `view` on `run` (the first call in this process: startup included)."""
    with timed() as viewed:
        outcome = build_view(
            run, progress=False, batch_size=replay_batch, selection=Selection(sample=sample)
        )
    rendered = len(outcome.statuses)
    print(
        f"view {run}{f' --sample {sample}' if sample else ''}: {viewed.wall:.1f} s wall, "
        f"{viewed.cpu:.1f} s CPU; {rendered} episodes rendered, {outcome.listed} listed, "
        f"{outcome.frames} frames; report {outcome.size_bytes / 1e6:.1f} MB; "
        f"{len(outcome.mismatches)} replays not reproducing"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    parser.add_argument("--batch-size", type=int, default=32, help="episodes in flight")
    parser.add_argument("--replay-batch", type=int, default=16, help="episodes replayed at once")
    parser.add_argument("--run", type=Path, help="time `view` on this run directory instead")
    parser.add_argument("--sample", type=int, help="with --run: render a seeded sample of N")
    args = parser.parse_args()
    if args.run is not None:
        view_existing(args.run, args.sample, args.replay_batch)
        return

    env = CrafTextEnv(EnvConfig(variant=Variant(args.variant), max_steps=args.max_steps))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        warm = workdir / "warm"
        play(env, warm, args.batch_size, args.batch_size)
        with timed() as cold_time:
            cold = build_view(warm, progress=False, batch_size=args.replay_batch)
        for episodes in args.episodes:
            run = workdir / f"run-{episodes}"
            played = play(env, run, episodes, args.batch_size)
            with timed() as viewed:
                outcome = build_view(run, progress=False, batch_size=args.replay_batch)
            rows.append((played, viewed, outcome))
            shutil.rmtree(run)

    print(
        f"{args.variant} Craftax, at most {args.max_steps} steps; mock backend at batch "
        f"{args.batch_size}; replayed {args.replay_batch} at a time"
    )
    table = [
        ["", *(f"{len(outcome.statuses)} episodes" for _, _, outcome in rows)],
        ["frames", *(str(outcome.frames) for _, _, outcome in rows)],
        ["play, wall (mock backend)", *(f"{p.wall:.1f} s" for p, _, _ in rows)],
        ["view, wall (whole command)", *(f"{v.wall:.1f} s" for _, v, _ in rows)],
        ["view / play, wall (<= 1)", *(f"{v.wall / p.wall:.2f}" for p, v, _ in rows)],
        ["play, CPU", *(f"{p.cpu:.1f} s" for p, _, _ in rows)],
        ["view, CPU", *(f"{v.cpu:.1f} s" for _, v, _ in rows)],
        ["view / play, CPU", *(f"{v.cpu / p.cpu:.2f}" for p, v, _ in rows)],
        ["view per frame, wall", *(f"{v.wall / o.frames * 1e3:.2f} ms" for _, v, o in rows)],
        [
            "view per episode, wall",
            *(f"{v.wall / len(o.statuses):.3f} s" for _, v, o in rows),
        ],
        ["report size", *(f"{o.size_bytes / 1e6:.1f} MB" for _, _, o in rows)],
        [
            "report size per episode",
            *(f"{o.size_bytes / len(o.statuses) / 1e3:.0f} kB" for _, _, o in rows),
        ],
        ["replays not reproducing", *(str(len(o.mismatches)) for _, _, o in rows)],
    ]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print(
            "  ".join(
                cell.rjust(w) if i else cell.ljust(w)
                for i, (cell, w) in enumerate(zip(row, widths, strict=True))
            )
        )
    _, viewed, outcome = rows[-1]
    startup = cold_time.wall - cold.frames * viewed.wall / outcome.frames
    print(
        f"view startup (trace, compile or load from the compilation cache; once per command): "
        f"about {startup:.1f} s"
    )


if __name__ == "__main__":
    main()
