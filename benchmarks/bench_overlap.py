"""How much of an env step this machine can hide behind the runner's Python work.

The play loop steps the worlds, then textualizes, prompts and records, one after the other. JAX
dispatches a step asynchronously, so the step could in principle be computed on another core
while Python works. This times, for one batch of worlds: the step alone (dispatch, compute, pull
to numpy, as `VectorEnv.step` does), a fixed amount of pure-Python work alone, the two one after
the other, and the two overlapped: the step dispatched before the work and pulled after it, or
run whole on a worker thread. The work is a fixed number of loop iterations, not a wall-clock
wait: a busy loop that runs until a deadline finishes on time even while the step has its core,
and so shows an overlap that a machine without a free core does not give.

    python benchmarks/bench_overlap.py [--variant classic full] [--batch 32] [--work-ms 5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax.numpy as jnp
import numpy as np

from env import CrafTextEnv, EnvConfig, Variant, VectorEnv, episode_key
from env.achievements import NUM_ACHIEVEMENTS
from env.craftext_env import _row_outputs


def python_work(iterations: int) -> None:
    total = 0
    for index in range(iterations):
        total += index * index


def iterations_for(seconds: float) -> int:
    """Loop iterations of `python_work` that take about `seconds` on this machine now."""
    start = time.perf_counter()
    python_work(200_000)
    return max(1, int(seconds / ((time.perf_counter() - start) / 200_000)))


def timed(run: Callable[[], None], repeats: int) -> tuple[float, float]:
    """Wall and CPU (the process's, every thread's) milliseconds per call."""
    start, cpu_start = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        run()
    return (
        (time.perf_counter() - start) / repeats * 1000,
        (time.process_time() - cpu_start) / repeats * 1000,
    )


def measure(variant: Variant, batch: int, work_ms: float | None, repeats: int) -> None:
    vector = VectorEnv(CrafTextEnv(EnvConfig(variant=variant, max_steps=10_000)), batch)
    required = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    required[:, 0] = True
    keys = np.stack([episode_key(0, "bench", 0, row) for row in range(batch)])
    vector.reset(keys, required, np.zeros_like(required))
    env, state = vector.env, vector._require_state()
    actions, active = jnp.ones(batch, jnp.int32), jnp.ones(batch, bool)

    def pull(stepped: tuple[Any, Any]) -> Any:
        """The state after the step, once pulled to numpy as `VectorEnv.step` pulls it."""
        next_state, info = stepped
        VectorEnv._to_host(next_state, _row_outputs(info))
        return next_state

    def step() -> None:
        nonlocal state
        state = pull(env.batched_step(state, actions, active))

    for _ in range(3):
        step()
    step_ms, step_cpu = timed(step, repeats)
    iterations = iterations_for((work_ms or step_ms) / 1000)
    work_wall, work_cpu = timed(lambda: python_work(iterations), repeats)

    def serial() -> None:
        step()
        python_work(iterations)

    def dispatched() -> None:
        nonlocal state
        stepped = env.batched_step(state, actions, active)
        python_work(iterations)
        state = pull(stepped)

    pool = ThreadPoolExecutor(1)

    def threaded() -> None:
        nonlocal state
        future = pool.submit(lambda: pull(env.batched_step(state, actions, active)))
        python_work(iterations)
        state = future.result()

    print(f"{variant.value}, {batch} worlds")
    print(f"  step + pull alone     {step_ms:7.2f} ms wall {step_cpu:7.2f} ms CPU")
    print(f"  Python work alone     {work_wall:7.2f} ms wall {work_cpu:7.2f} ms CPU")
    serial_ms, serial_cpu = timed(serial, repeats)
    print(f"  one after the other   {serial_ms:7.2f} ms wall {serial_cpu:7.2f} ms CPU")
    for name, run in (("dispatched, then work", dispatched), ("on a worker thread", threaded)):
        wall, cpu = timed(run, repeats)
        print(
            f"  {name:<21} {wall:7.2f} ms wall {cpu:7.2f} ms CPU: "
            f"{(serial_ms - wall) / step_ms:5.0%} of the step hidden"
        )
    pool.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", nargs="+", default=["classic", "full"])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument(
        "--work-ms", type=float, default=None, help="Python work per step (default: one step's)"
    )
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    for name in args.variant:
        measure(Variant(name), args.batch, args.work_ms, args.repeats)


if __name__ == "__main__":
    main()
