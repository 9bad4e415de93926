"""Steps/s of raw Craftax vs the CrafText env (checker included), side by side in one run.

Both are stepped inside one jitted `lax.scan` over the same random actions, so the figure is the
cost of the step itself. The env is timed with EASY (achievements) goals in every slot and with a
batch that mixes every scenario kind (achievements, conditional placing, localization, line,
square, star: one goal of each, repeated over the slots); `--per-kind` adds a column per kind.
A last column drives `VectorEnv` from the host as the runner does (one compiled call and one pull
to numpy per step).

    python benchmarks/bench_env.py [--steps 200] [--batch 1 64] [--variant full classic] [--per-kind]
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
from env.goals import (
    GOAL_KINDS,
    BuildLineGoal,
    BuildSquareGoal,
    BuildStarGoal,
    ConditionalPlacingGoal,
    Goal,
    LocalizationGoal,
)
from env.scenario_tasks import encode_goals


def _one_goal_per_kind() -> list[Any]:
    """A goal of every kind, with blocks both variants have."""
    text: dict[str, Any] = {
        "split": "medium_train", "scenario": "medium", "instruction": "bench", "paraphrases": ()
    }  # fmt: skip
    return [
        Goal(
            id="A",
            category="combo",
            required=("PLACE_TABLE",),
            forbidden=("COLLECT_SAPLING",),
            **text,
        ),
        ConditionalPlacingGoal(
            id="C", collect="wood", collect_count=2, place="CRAFTING_TABLE", place_count=1, **text
        ),
        LocalizationGoal(id="L", place="STONE", target="WATER", side="left", distance=2, **text),
        BuildLineGoal(id="BL", block="STONE", size=4, diagonal=True, **text),
        BuildSquareGoal(id="BS", block="STONE", size=3, **text),
        BuildStarGoal(id="ST", block="PLANT", size=2, cross="combined", **text),
    ]


def _best_of_interleaved(repeats: int, *runs: Callable[[], Any]) -> list[float]:
    """Best wall time of each run; the runs alternate so a change in machine load hits all alike."""
    best = [float("inf")] * len(runs)
    for _ in range(repeats):
        for i, run in enumerate(runs):
            start = time.perf_counter()
            jax.block_until_ready(run())
            best[i] = min(best[i], time.perf_counter() - start)
    return best


def _tasks(variant: Variant, batch: int, kinds: list[int]) -> Any:
    """Tasks for `batch` slots cycling over the goals of `kinds` (indices into GOAL_KINDS)."""
    goals = [g for g in _one_goal_per_kind() if GOAL_KINDS.index(g.kind) in kinds]
    encoded = encode_goals([goals[i % len(goals)] for i in range(batch)], variant)
    return make_task(encoded.required, encoded.forbidden, encoded.kind, encoded.params)


def bench_variant(
    variant: Variant, batch: int, steps: int, repeats: int, per_kind: bool
) -> dict[str, float]:
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

    task_sets = {"easy": [0], "mixed": list(range(len(GOAL_KINDS)))}
    if per_kind:
        task_sets |= {kind: [index] for index, kind in enumerate(GOAL_KINDS)}
    reset = jax.jit(jax.vmap(env.reset))
    states = {name: reset(keys, _tasks(variant, batch, kinds)) for name, kinds in task_sets.items()}

    @jax.jit
    def our_rollout(state: Any, actions: jax.Array) -> Any:
        def body(state: Any, step_actions: jax.Array) -> tuple[Any, jax.Array]:
            state, info = env.step_batch(state, step_actions)
            return state, info.reward.sum()

        return jax.lax.scan(body, state, actions)

    jax.block_until_ready(raw_rollout(raw_state, actions))
    for state in states.values():
        jax.block_until_ready(our_rollout(state, actions))
    raw_s, *ours_s = _best_of_interleaved(
        repeats,
        lambda: raw_rollout(raw_state, actions),
        *[lambda state=state: our_rollout(state, actions) for state in states.values()],
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
    return {
        "raw": total / raw_s,
        **{name: total / seconds for name, seconds in zip(states, ours_s, strict=True)},
        "host": total / host_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--variant", nargs="+", default=["classic", "full"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--per-kind", action="store_true", help="a column per scenario kind")
    args = parser.parse_args()

    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; {args.steps} steps per rollout")
    print("ours/raw: the env's step time (checker included) over raw Craftax's, per goal set")
    printed_header = False
    for name in args.variant:
        for batch in args.batch:
            result = bench_variant(Variant(name), batch, args.steps, args.repeats, args.per_kind)
            sets = [key for key in result if key not in ("raw", "host")]
            if not printed_header:
                header = (
                    f"{'variant':8} {'N':>4} {'raw steps/s':>12} "
                    + " ".join(f"{s + '/raw':>22}" for s in sets)
                    + f" {'host-driven steps/s':>20}"
                )
                print(header)
                print("-" * len(header))
                printed_header = True
            print(
                f"{name:8} {batch:>4} {result['raw']:>12,.0f} "
                + " ".join(f"{result['raw'] / result[s]:>21.2f}x" for s in sets)
                + f" {result['host']:>20,.0f}"
            )
    print(
        "target: ours/raw time <= 1.2x with the mixed batch (host-driven includes the per-step "
        "pull to numpy)"
    )


if __name__ == "__main__":
    jnp.zeros(1).block_until_ready()
    main()
