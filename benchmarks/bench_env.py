"""Steps/s of raw Craftax vs the CrafText env (checker included), side by side in one run.

Both are stepped inside one jitted `lax.scan` over the same random actions, so the figure is the
cost of the step itself. A third column drives `VectorEnv` from the host as the runner does
(one compiled call and one pull to numpy per step).

    python benchmarks/bench_env.py [--steps 200] [--batch 1 64] [--variant full classic]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from env import CrafTextEnv, EnvConfig, Variant, VectorEnv, episode_key
from env.achievements import NUM_ACHIEVEMENTS
from env.craftext_env import make_task


def _best_of_interleaved(repeats: int, *runs: Callable[[], Any]) -> list[float]:
    """Best wall time of each run; the runs alternate so a change in machine load hits all alike."""
    best = [float("inf")] * len(runs)
    for _ in range(repeats):
        for i, run in enumerate(runs):
            start = time.perf_counter()
            jax.block_until_ready(run())
            best[i] = min(best[i], time.perf_counter() - start)
    return best


def bench_variant(variant: Variant, batch: int, steps: int, repeats: int) -> dict[str, float]:
    env = CrafTextEnv(EnvConfig(variant=variant, max_steps=10**6))
    raw = env.craftax
    params = env.params
    num_actions = env.num_actions
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    actions = jax.random.randint(jax.random.PRNGKey(1), (steps, batch), 0, num_actions)

    _, raw_state = jax.vmap(raw.reset, in_axes=(0, None))(keys, params)

    @jax.jit
    def raw_rollout(state: Any, actions: jax.Array) -> Any:
        def body(carry: Any, step_actions: jax.Array) -> tuple[Any, jax.Array]:
            state, t = carry
            step_keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, t)
            obs, state, reward, _, _ = jax.vmap(raw.step, in_axes=(0, 0, 0, None))(
                step_keys, state, step_actions, params
            )
            return (state, t + 1), reward.sum() + obs.sum() * 0

        (state, _), rewards = jax.lax.scan(body, (state, 0), actions)
        return state, rewards

    task = make_task(
        np.zeros((batch, NUM_ACHIEVEMENTS), bool), np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    )
    ours_state = jax.jit(jax.vmap(env.reset))(keys, task)

    @jax.jit
    def our_rollout(state: Any, actions: jax.Array) -> Any:
        def body(state: Any, step_actions: jax.Array) -> tuple[Any, jax.Array]:
            state, info = jax.vmap(env.step_from_episode_key)(state, step_actions)
            return state, info.reward.sum()

        return jax.lax.scan(body, state, actions)

    jax.block_until_ready(raw_rollout(raw_state, actions))
    jax.block_until_ready(our_rollout(ours_state, actions))
    raw_s, ours_s = _best_of_interleaved(
        repeats,
        lambda: raw_rollout(raw_state, actions),
        lambda: our_rollout(ours_state, actions),
    )

    vector = VectorEnv(env, batch)
    host_keys = np.stack([episode_key(0, "bench", 0, i) for i in range(batch)])
    empty = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
    vector.reset(host_keys, empty, empty)
    host_actions = np.asarray(actions)
    vector.step(host_actions[0])
    host_steps = min(steps, 100)
    start = time.perf_counter()
    for t in range(host_steps):
        vector.step(host_actions[t])
    host_s = (time.perf_counter() - start) / host_steps * steps

    total = steps * batch
    return {"raw": total / raw_s, "ours": total / ours_s, "host": total / host_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--variant", nargs="+", default=["classic", "full"])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; {args.steps} steps per rollout")
    header = (
        f"{'variant':8} {'N':>4} {'raw craftax steps/s':>20} {'ours steps/s':>14} "
        f"{'ours/raw time':>14} {'host-driven steps/s':>20}"
    )
    print(header)
    print("-" * len(header))
    for name in args.variant:
        for batch in args.batch:
            result = bench_variant(Variant(name), batch, args.steps, args.repeats)
            ratio = result["raw"] / result["ours"]
            print(
                f"{name:8} {batch:>4} {result['raw']:>20,.0f} {result['ours']:>14,.0f} "
                f"{ratio:>13.2f}x {result['host']:>20,.0f}"
            )
    print("target: ours/raw time <= 1.10x (host-driven includes the per-step pull to numpy)")


if __name__ == "__main__":
    jnp.zeros(1).block_until_ready()
    main()
