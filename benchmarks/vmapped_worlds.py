"""Whether Craftax makes the same world from a key alone and inside a vmap, and what that does to
goals checked in a new world (the official rule's game-over step).

    python -m benchmarks.vmapped_worlds [--worlds 16] [--seed 7] [--dataset PATH]

Prints the lanes of a `jax.vmap` of Craftax-Classic's `reset_env` over `--worlds` keys whose
map differs from the world the same key makes alone, then, for every Medium train goal whose
verdict in a new world reads its blocks (localization placing, lines), the player dying on its
first step: in how many lanes the goal is met in the world made alone and in the vmapped one.
The env checks the world made alone (`CrafTextEnv._met_in_new_world`, row by row); the official
wrapper, stepped inside a vmap over environments as its training loop does, checks the vmapped
one, so on this backend its verdict on a game-over step can depend on the environment's lane.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from env.craftext_env import CrafTextEnv, EnvConfig, _step_keys, make_task  # noqa: E402
from env.dataset import load_dataset  # noqa: E402
from env.scenario_checker import goal_met  # noqa: E402
from env.scenario_tasks import encode_goals  # noqa: E402
from env.variant import Variant  # noqa: E402


def main(argv: Sequence[str] | None = None) -> int:
    from benchmarks.official_wrapper import add_repository_arguments, repository_root

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=16)
    parser.add_argument("--seed", type=int, default=7)
    add_repository_arguments(parser)
    args = parser.parse_args(argv)
    root = repository_root(args)
    env = CrafTextEnv(EnvConfig(variant=Variant.CLASSIC, success_rule="official"))
    goals = [
        goal
        for goal in load_dataset(root).split("medium_train")
        if goal.kind in ("localization_placing", "build_line")
    ]
    encoded = encode_goals(goals, Variant.CLASSIC)
    keys = jax.random.key_data(jax.random.split(jax.random.key(args.seed), args.worlds))
    first = make_task(encoded.required[0], encoded.forbidden[0], encoded.kind[0], encoded.params[0])
    starts = [env.jitted_reset(k.astype(jnp.uint32), first) for k in keys]
    before = jax.tree.map(lambda *leaves: jnp.stack(leaves), *starts)
    reset_keys = jax.vmap(lambda k: jax.random.split(k)[1])(_step_keys(before))
    make = jax.jit(lambda k: env.craftax.reset_env(k, env.params)[1])
    alone = jax.tree.map(lambda *leaves: jnp.stack(leaves), *[make(k) for k in reset_keys])
    vmapped = jax.jit(jax.vmap(lambda k: env.craftax.reset_env(k, env.params)[1]))(reset_keys)
    maps_alone, maps_vmapped = np.asarray(alone.map), np.asarray(vmapped.map)
    differing = [
        i for i in range(args.worlds) if not np.array_equal(maps_alone[i], maps_vmapped[i])
    ]
    print(
        f"jax {jax.__version__} on {jax.default_backend()}, {args.worlds} worlds, seed {args.seed}: "
        f"lanes whose vmapped world differs from the key's own: {differing or 'none'}"
    )
    for lane in differing:
        blocks = int((maps_alone[lane] != maps_vmapped[lane]).sum())
        print(f"  lane {lane}: {blocks} of {maps_alone[lane].size} blocks differ")
    check = jax.jit(
        jax.vmap(
            lambda previous, world, kind, required, forbidden, params: goal_met(
                previous, world, kind, required, forbidden, params, Variant.CLASSIC
            ),
            in_axes=(0, 0, None, None, None, None),
        )
    )
    print("goals met in the new world (lanes), world made alone vs vmapped, where they differ:")
    flips = 0
    for g, goal in enumerate(goals):
        row = (encoded.kind[g], encoded.required[g], encoded.forbidden[g], encoded.params[g])
        met_alone = np.asarray(check(before.game, alone, *row))
        met_vmapped = np.asarray(check(before.game, vmapped, *row))
        if (met_alone != met_vmapped).any():
            flips += int((met_alone != met_vmapped).sum())
            print(
                f"  {goal.id} ({goal.kind}): {np.flatnonzero(met_alone).tolist()} vs "
                f"{np.flatnonzero(met_vmapped).tolist()}"
            )
    print(f"(goal, lane) verdicts that differ: {flips} of {len(goals) * args.worlds}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
