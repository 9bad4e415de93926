"""How much of an env step this machine can hide behind the runner's host work.

The play loop steps the worlds, then textualizes, prompts and records, one after the other. JAX
dispatches a step asynchronously, so the step could in principle be computed on another core
while the host works. This times, for one batch of worlds: the step alone (dispatch, compute,
pull to numpy, as `VectorEnv.step` does; each of the three also timed apart), some host work
alone, the two one after the other, and the two overlapped: the step dispatched before the work
and pulled after it, or run whole on a worker thread. Two kinds of work, side by side:
- a fixed number of pure-Python loop iterations (about one step's time): the best case. It is a
  count, not a wall-clock wait: a busy loop that runs until a deadline finishes on time even
  while the step has its core, and so shows an overlap that a machine without a free core does
  not give;
- the runner's own work on the batch: textualizing every world and rendering its zero-shot
  prompt (`observe_batch`, `ZeroShotAgent.prepare`), what a pipelined runner would do for one
  half of its slots while the other half's worlds compute.

    python benchmarks/bench_overlap.py [--variant classic full] [--batch 32] [--work-ms 5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
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
    # Timed a phase at a time; waiting for the compute before pulling costs the step nothing.
    phases = np.zeros(3)
    cpu_start = time.process_time()
    for _ in range(repeats):
        start = time.perf_counter()
        stepped = env.batched_step(state, actions, active)
        dispatched_at = time.perf_counter()
        jax.block_until_ready(stepped)
        computed_at = time.perf_counter()
        state = pull(stepped)
        phases += [
            dispatched_at - start,
            computed_at - dispatched_at,
            time.perf_counter() - computed_at,
        ]
    step_cpu = (time.process_time() - cpu_start) / repeats * 1000
    dispatch_ms, compute_ms, pull_ms = phases / repeats * 1000
    step_ms = dispatch_ms + compute_ms + pull_ms
    iterations = iterations_for((work_ms or step_ms) / 1000)

    print(f"{variant.value}, {batch} worlds")
    print(
        f"  step + pull alone     {step_ms:7.2f} ms wall {step_cpu:7.2f} ms CPU "
        f"(dispatch {dispatch_ms:.2f}, compute {compute_ms:.2f}, pull to numpy {pull_ms:.2f} ms)"
    )
    pool = ThreadPoolExecutor(1)
    runner_work = _runner_work(vector)
    for label, work in (
        ("pure-Python loop", lambda: python_work(iterations)),
        ("runner's work (observe + prompt)", runner_work),
    ):

        def serial(work: Callable[[], None] = work) -> None:
            step()
            work()

        def dispatched(work: Callable[[], None] = work) -> None:
            nonlocal state
            stepped = env.batched_step(state, actions, active)
            work()
            state = pull(stepped)

        def threaded(work: Callable[[], None] = work) -> None:
            nonlocal state
            future = pool.submit(lambda: pull(env.batched_step(state, actions, active)))
            work()
            state = future.result()

        work_wall, work_cpu = timed(work, repeats)
        print(f"  {label}")
        print(f"    work alone            {work_wall:7.2f} ms wall {work_cpu:7.2f} ms CPU")
        serial_ms, serial_cpu = timed(serial, repeats)
        print(f"    one after the other   {serial_ms:7.2f} ms wall {serial_cpu:7.2f} ms CPU")
        for name, run in (("dispatched, then work", dispatched), ("on a worker thread", threaded)):
            wall, cpu = timed(run, repeats)
            print(
                f"    {name:<21} {wall:7.2f} ms wall {cpu:7.2f} ms CPU: "
                f"{(serial_ms - wall) / step_ms:5.0%} of the step hidden"
            )
    pool.shutdown()


def _runner_work(vector: VectorEnv) -> Callable[[], None]:
    """The runner's host work for every world of the batch, on its current state: observations,
    then each episode's zero-shot step prompt."""
    from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
    from llm_agents.agents.types import EpisodeStart
    from textualizer import observe_batch

    agent = ZeroShotAgent(vector.variant)
    for slot in range(vector.batch_size):
        agent.start_episode(slot, EpisodeStart("collect wood", episode=f"bench-{slot}"))
    game = vector._fresh_host().game

    def work() -> None:
        for slot, observation in enumerate(observe_batch(game, vector.variant)):
            agent.prepare(slot, observation)

    return work


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", nargs="+", default=["classic", "full"])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument(
        "--work-ms",
        type=float,
        default=None,
        help="the pure-Python loop's length (default: one step's)",
    )
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    for name in args.variant:
        measure(Variant(name), args.batch, args.work_ms, args.repeats)


if __name__ == "__main__":
    main()
