"""The framework's own cost per agent-step: everything but the model, with episodes in flight.

A zero-latency mock backend answers at once, so the run's wall time is the framework's: env
steps (masked, batched), pulling states to numpy, textualization, prompt rendering, parsing,
records and JSON lines. Printed per agent-step for each number of episodes in flight, with
where the time went (wall and CPU time inside each part; the rest is scheduling and
bookkeeping). CPU time is the process's (every thread, JAX's included): a loaded machine
inflates it far less than wall time, so compare it across runs on a shared machine.
`--profile N` runs the timed runs under cProfile and prints their N costliest functions (own
time, then cumulative): the profiler slows every Python call, so read its shares, not its times.

    python benchmarks/bench_runner.py [--in-flight 32 128] [--max-steps 20] [--variant full]
        [--profile 25]
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import io
import pstats
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

ANSWERS = ["ACTION: LEFT", "ACTION: DO", "ACTION: UP", "ACTION: RIGHT", "ACTION: DOWN"]
#: The mock script answering them in turn, named in the config as the model that plays.
SCRIPT = "cycle:" + "|".join(ANSWERS)

#: part name -> (object, attribute) whose calls are timed.
PARTS = {
    "env step": ("env:VectorEnv", "step"),
    "env refill": ("env:VectorEnv", "refill"),
    "observe": ("textualizer", "observe_batch"),
    "prompt (render text, template)": (
        "llm_agents.agents.strategies.zero_shot:ZeroShotAgent",
        "prepare",
    ),
    "decide (parse, hash)": ("llm_agents.agents.strategies.zero_shot:ZeroShotAgent", "decide"),
    "records + JSON lines": ("llm_agents.evaluation.sink:RunSink", "record"),
    "  of which results.json": ("llm_agents.evaluation.sink:RunSink", "save"),
}


def _timed(spent: dict[str, float], name: str, function: Callable[..., Any]) -> Any:
    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start, cpu_start = time.perf_counter(), time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            spent[name] += time.perf_counter() - start
            spent[f"{name} cpu"] += time.process_time() - cpu_start

    return wrapper


def instrument(spent: dict[str, float]) -> None:
    import importlib

    for name, (target, attribute) in PARTS.items():
        module_name, _, class_name = target.partition(":")
        owner: Any = importlib.import_module(module_name)
        if class_name:
            owner = getattr(owner, class_name)
        setattr(owner, attribute, _timed(spent, name, getattr(owner, attribute)))


def timed_run(
    env: Any,
    in_flight: int,
    episodes: int,
    workdir: Path,
    spent: dict[str, float],
    profiler: cProfile.Profile | None = None,
) -> tuple[float, float, int]:
    """Wall and CPU seconds for the run and agent-steps taken, after a warm-up run of the same
    shape (`profiler`, when given, profiles the timed run only)."""
    from llm_agents.backends.mock import MockModel
    from llm_agents.evaluation.config import build_config
    from llm_agents.evaluation.runner import run_eval

    settings = {
        "model": f"mock:{SCRIPT}",
        "variant": env.variant.value,
        "categories": ["one", "combo", "paraphrased", "new_objects"],
        "max_steps": env.config.max_steps,
        "batch_size": in_flight,
        "probe": False,
    }
    # One episode more than the slots, so the warm-up also refills one (that compiles too).
    warm = settings | {"output_dir": str(workdir / f"warm{in_flight}"), "limit": in_flight + 1}
    run_eval(build_config(warm), MockModel(SCRIPT), env=env)
    config = build_config(
        settings | {"output_dir": str(workdir / f"run{in_flight}"), "limit": episodes}
    )
    model = MockModel(SCRIPT)
    spent.clear()
    start, cpu_start = time.perf_counter(), time.process_time()
    if profiler is not None:
        profiler.enable()
    outcome = run_eval(config, model, env=env)
    if profiler is not None:
        profiler.disable()
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    assert outcome.summary is not None and outcome.summary.overall.episodes == episodes
    return elapsed, cpu, len(model.requests)


def print_profile(profiler: cProfile.Profile, top: int) -> None:
    for order in ("tottime", "cumulative"):
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).strip_dirs().sort_stats(order).print_stats(top)
        print(f"--- profile of the timed runs, by {order}")
        print(text.getvalue().split("\n\n", 1)[-1].rstrip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--in-flight", type=int, nargs="+", default=[32, 128])
    parser.add_argument(
        "--episodes-per-slot", type=int, default=2, help="episodes = this x in flight"
    )
    parser.add_argument("--max-steps", type=int, default=20)
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    parser.add_argument(
        "--profile", type=int, default=0, metavar="N", help="print the N costliest functions"
    )
    args = parser.parse_args()

    from env import CrafTextEnv, EnvConfig, Variant

    env = CrafTextEnv(EnvConfig(variant=Variant(args.variant), max_steps=args.max_steps))
    spent: dict[str, float] = defaultdict(float)
    instrument(spent)
    profiler = cProfile.Profile() if args.profile else None
    print(
        f"{args.variant} Craftax, {args.max_steps} steps per episode, "
        f"{args.episodes_per_slot} episodes per slot, zero-latency mock (one batch per call)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for in_flight in args.in_flight:
            episodes = in_flight * args.episodes_per_slot
            elapsed, cpu, steps = timed_run(env, in_flight, episodes, Path(tmp), spent, profiler)
            print(
                f"{in_flight:>4} in flight: {elapsed / steps * 1000:.2f} ms per agent-step, "
                f"{cpu / steps * 1000:.2f} ms CPU ({steps} agent-steps in {elapsed:.1f} s)"
            )
            print(f"       {'part':<32} {'wall':>9} {'CPU':>9}")
            for name in PARTS:
                wall, part_cpu = (spent[key] / steps * 1000 for key in (name, f"{name} cpu"))
                print(f"       {name:<32} {wall:6.3f} ms {part_cpu:6.3f} ms")
    print("target: <= 0.5 ms per agent-step at 32 in flight")
    if profiler is not None:
        print_profile(profiler, args.profile)


if __name__ == "__main__":
    main()
