"""JAX compiles in a first and a second process: the persistent compilation cache at work.

Each process (a fresh one, sharing one new cache directory) creates the env, resets a batch,
steps every slot, steps a few ready slots (the grouped step), refills one slot and most slots:
everything a run compiles. Printed side by side: XLA compiles, cache hits and misses, seconds
spent in XLA (compiling, or loading from the cache) and in tracing and lowering (which no
cache skips), and each process's wall time.

    python benchmarks/bench_compile_cache.py [--variant full] [--batch 32]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

CHILD = """
import json, sys, time
start = time.perf_counter()
from collections import Counter
from jax import monitoring
events, seconds = Counter(), Counter()
monitoring.register_event_listener(lambda name, **_: events.update([name]))
monitoring.register_event_duration_secs_listener(
    lambda name, duration, **_: (events.update([name]), seconds.update({name: duration}))
)
import numpy as np
from env import CrafTextEnv, EnvConfig, Variant, VectorEnv, episode_key
from env.achievements import NUM_ACHIEVEMENTS
variant, batch = sys.argv[1], int(sys.argv[2])
env = CrafTextEnv(EnvConfig(variant=Variant(variant), max_steps=10))
vector = VectorEnv(env, batch)
keys = np.stack([episode_key(0, "g", 0, i) for i in range(batch)])
required = np.zeros((batch, NUM_ACHIEVEMENTS), bool)
required[:, 0] = True
forbidden = np.zeros_like(required)
vector.reset(keys, required, forbidden)
vector.step(np.zeros(batch, np.int32))
active = np.zeros(batch, bool)
active[:3] = True
vector.step(np.ones(batch, np.int32), active)
vector.refill([0], keys[:1], required[:1], forbidden[:1])
most = list(range(batch // 2 + 1))
vector.refill(most, keys[most], required[most], forbidden[most])
print(json.dumps({
    "compiles": events["/jax/core/compile/backend_compile_duration"],
    "hits": events["/jax/compilation_cache/cache_hits"],
    "misses": events["/jax/compilation_cache/cache_misses"],
    "compile_s": seconds["/jax/core/compile/backend_compile_duration"],
    "trace_lower_s": seconds["/jax/core/compile/jaxpr_trace_duration"]
    + seconds["/jax/core/compile/jaxpr_to_mlir_module_duration"],
    "wall_s": time.perf_counter() - start,
}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    parser.add_argument("--batch", type=int, default=32)
    args = parser.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": cache}
        for name in ("first process", "second process"):
            started = time.perf_counter()
            done = subprocess.run(
                [sys.executable, "-c", CHILD, args.variant, str(args.batch)],
                env=env,
                capture_output=True,
                text=True,
            )
            if done.returncode:
                sys.exit(f"{name} failed:\n{done.stderr}")
            rows[name] = json.loads(done.stdout.strip().splitlines()[-1])
            rows[name]["process_s"] = time.perf_counter() - started
    print(f"{args.variant} Craftax, {args.batch} slots, one new cache directory")
    print(
        f"{'':<15} {'XLA requests':>12} {'cache hits':>10} {'misses':>6} {'XLA s':>9} "
        f"{'trace+lower s':>13} {'process s':>9}"
    )
    for name, row in rows.items():
        print(
            f"{name:<15} {row['compiles']:>12} {row['hits']:>10} {row['misses']:>6} "
            f"{row['compile_s']:>9.1f} {row['trace_lower_s']:>13.1f} {row['process_s']:>9.1f}"
        )
    first, second = rows["first process"], rows["second process"]
    print(
        f"second / first process time: {second['process_s'] / first['process_s']:.2f}; "
        f"second process misses: {second['misses']} (target 0)"
    )


if __name__ == "__main__":
    main()
