"""Textualizer speed and text size: `objects` vs the official baseline's `table`, same states.

States come from random-action rollouts (a batch of episodes stepped together, pulled to numpy
as the runner does). For each style it prints the time per state of observation plus text, and
the mean size in characters and in tokens of SmolLM2-135M's tokenizer.

    python benchmarks/bench_textualizer.py [--variant full classic] [--batch 64] [--rounds 8]
        [--tokenizer DIR | auto]

`--tokenizer auto` uses the embedded model's folder (`llm_agents.backends.embedded`); DIR may
be a tokenizer folder or a folder holding one `.gguf` file. Without a tokenizer, tokens are
whitespace-separated words (with a warning).
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from env import CrafTextEnv, EnvConfig, Variant
from textualizer import RENDERERS, observe_batch, render


def load_token_counter(spec: str) -> tuple[str, Callable[[str], int]]:
    """A (description, count function) pair; whitespace words when no tokenizer loads."""
    try:
        from transformers import AutoTokenizer

        if spec == "auto":
            from llm_agents.backends.embedded import embedded_model_dir

            folder = embedded_model_dir()
        else:
            folder = Path(spec)
        ggufs = sorted(folder.glob("*.gguf"))
        if ggufs:
            tokenizer = AutoTokenizer.from_pretrained(str(folder), gguf_file=ggufs[0].name)
        else:
            tokenizer = AutoTokenizer.from_pretrained(str(folder))
    except Exception as error:
        warnings.warn(
            f"no tokenizer ({error}); counting whitespace-separated words instead",
            stacklevel=1,
        )
        return "words", lambda text: len(text.split())
    return f"tokens ({folder.name})", lambda text: len(tokenizer(text)["input_ids"])


def rollout_states(variant: Variant, batch: int, rounds: int, steps_per_round: int) -> list[Any]:
    """`rounds` host batches of `batch` episodes, `steps_per_round` random steps apart."""
    env = CrafTextEnv(EnvConfig(variant=variant))
    craftax, params = env.craftax, env.params

    @jax.jit
    def reset(keys: jax.Array) -> Any:
        return jax.vmap(lambda key: craftax.reset_env(key, params)[1])(keys)

    @jax.jit
    def step(keys: jax.Array, states: Any, actions: jax.Array) -> Any:
        return jax.vmap(lambda k, s, a: craftax.step_env(k, s, a, params)[1])(keys, states, actions)

    rng = np.random.default_rng(0)
    states = reset(jax.random.split(jax.random.PRNGKey(0), batch))
    snapshots = []
    for round_index in range(rounds):
        for step_index in range(steps_per_round):
            keys = jax.random.split(jax.random.PRNGKey(round_index * 1000 + step_index), batch)
            actions = rng.integers(0, env.num_actions, batch).astype(np.int32)
            states = step(keys, states, actions)
        snapshots.append(jax.device_get(states))
    return snapshots


def bench_variant(
    variant: Variant, snapshots: list[Any], count_tokens: Callable[[str], int]
) -> None:
    num_states = sum(s.player_position.shape[0] for s in snapshots)
    start = time.perf_counter()
    observations = [obs for host in snapshots for obs in observe_batch(host, variant)]
    observe_ms = (time.perf_counter() - start) * 1000 / num_states
    tokens: dict[str, float] = {}
    for style in RENDERERS:
        start = time.perf_counter()
        texts = [render(obs, style) for obs in observations]
        render_ms = (time.perf_counter() - start) * 1000 / num_states
        chars = statistics.mean(len(text) for text in texts)
        tokens[style] = statistics.mean(count_tokens(text) for text in texts)
        print(
            f"{variant.value:8} {style:8} {observe_ms + render_ms:8.3f} ms/state "
            f"(observe {observe_ms:.3f} + render {render_ms:.3f})  "
            f"{chars:7.0f} chars  {tokens[style]:7.1f} tokens"
        )
    print(f"{variant.value:8} objects/table token ratio: {tokens['objects'] / tokens['table']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--variant", nargs="+", default=["full", "classic"], choices=[v.value for v in Variant]
    )
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--steps-per-round", type=int, default=8)
    parser.add_argument("--tokenizer", default="auto", help="tokenizer folder, or 'auto'")
    args = parser.parse_args()
    unit, count_tokens = load_token_counter(args.tokenizer)
    print(f"token counts: {unit}; {args.batch * args.rounds} states per variant")
    for name in args.variant:
        variant = Variant(name)
        snapshots = rollout_states(variant, args.batch, args.rounds, args.steps_per_round)
        bench_variant(variant, snapshots, count_tokens)


if __name__ == "__main__":
    main()
