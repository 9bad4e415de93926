"""CPU seconds per agent step of hf free generation, with prefix reuse and without.

Zero-shot free text (the agent's default: think briefly, then `ACTION: <NAME>`) on Craftax-
Classic, `--episodes` episodes in flight (one instruction of the EASY train split each), for
`--steps` steps. Two configurations play the same episodes side by side on one loaded model,
each with its own agents and worlds:

- `without`: every prompt computed from its first token (the hf backend before prefix reuse);
- `with`: the backend's prefix store (`llm_agents/backends/hf/prefix.py`): the system prompt
  computed once, each episode's prompt reused through its instruction from the step before.

Every step runs both configurations back to back, in alternating order, so a change in the
machine's load falls on both. Printed per configuration: CPU seconds (this process, all
threads) and wall seconds per agent step, prompt tokens and computed prompt tokens per step;
then the CPU ratio and whether the answers are the same (each step's raw answers compared; an
episode whose answer differs plays on its own answer).

    nice python benchmarks/bench_prefix_reuse.py [--model qwen2.5-coder-0.5b] [--device cpu]
        [--episodes 16] [--steps 2] [--max-tokens 256] [--threads 1] [--rows-per-forward N]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Tally:
    """What one configuration spent and answered."""

    cpu_s: float = 0.0
    wall_s: float = 0.0
    model_cpu_s: float = 0.0
    """The part of `cpu_s` spent in the backend's `generate`."""
    steps: int = 0
    prompt_tokens: int = 0
    computed_tokens: int = 0
    completion_tokens: int = 0
    answers: list[str] = field(default_factory=list)


class Side:
    """One configuration's agents, worlds and prefix store."""

    def __init__(self, name: str, store: Any, instructions: list[str], variant: str, world: Any):
        from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
        from llm_agents.agents.types import EpisodeStart

        self.name, self.store, self.world = name, store, world
        self.agent = ZeroShotAgent(variant=variant)
        self.states = [world.reset(slot) for slot in range(len(instructions))]
        for slot, text in enumerate(instructions):
            self.agent.start_episode(slot, EpisodeStart(text))
        self.tally = Tally()

    def step(self, model: Any) -> None:
        import textualizer

        cpu, wall = time.process_time(), time.perf_counter()
        prompts = [
            self.agent.prepare(
                slot, textualizer.observe(self.world.game(state), self.world.variant)
            )
            for slot, state in enumerate(self.states)
        ]
        model.prefixes = self.store
        model_cpu = time.process_time()
        outputs = model.generate([prompt.messages for prompt in prompts])
        self.tally.model_cpu_s += time.process_time() - model_cpu
        if errors := [o.error for o in outputs if o.finish_reason == "error"]:
            raise RuntimeError(f"{self.name}: {errors[0]}")
        decisions = [self.agent.decide(p, o) for p, o in zip(prompts, outputs, strict=True)]
        self.states = [
            self.world.step(state, decision.action)
            for state, decision in zip(self.states, decisions, strict=True)
        ]
        tally = self.tally
        tally.cpu_s += time.process_time() - cpu
        tally.wall_s += time.perf_counter() - wall
        tally.steps += len(outputs)
        tally.prompt_tokens += sum(o.prompt_tokens for o in outputs)
        tally.computed_tokens += sum(
            o.prompt_tokens if o.computed_prompt_tokens is None else o.computed_prompt_tokens
            for o in outputs
        )
        tally.completion_tokens += sum(o.completion_tokens for o in outputs)
        tally.answers.extend(o.text for o in outputs)


class World:
    """Classic worlds, reset and stepped by jitted functions (compiled before timing)."""

    def __init__(self, variant: str):
        import jax
        import jax.numpy as jnp
        import numpy as np

        import env

        self.variant = variant
        self._jnp, self._np, self._jax, self._env = jnp, np, jax, env
        craftext = env.CrafTextEnv(env.EnvConfig(variant=env.Variant(variant)))
        required = np.zeros(22, dtype=bool)
        required[0] = True
        self._task = env.make_task(required, np.zeros(22, dtype=bool))
        self._reset = jax.jit(craftext.reset)
        self._step = jax.jit(craftext.step_from_episode_key)
        self.step(self.reset(0), 0)

    def reset(self, slot: int) -> Any:
        return self._reset(self._jnp.asarray(self._env.episode_key(0, "g", 0, slot)), self._task)

    def step(self, state: Any, action: int) -> Any:
        new, _ = self._step(state, self._jnp.int32(action))
        return new

    def game(self, state: Any) -> Any:
        return self._jax.tree.map(self._np.asarray, state.game)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="qwen2.5-coder-0.5b", help="hf model name")
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda, ...)")
    parser.add_argument("--episodes", type=int, default=16, help="episodes in flight")
    parser.add_argument("--steps", type=int, default=2, help="agent steps per episode")
    parser.add_argument("--max-tokens", type=int, default=None, help="default: the run's")
    # One thread: on a shared CPU, idle threads of a pool spin and count as CPU seconds.
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (cpu)")
    parser.add_argument("--rows-per-forward", type=int, default=None, help="default: backend's")
    args = parser.parse_args()

    import torch

    import env
    from llm_agents.backends.base import GenerateConfig
    from llm_agents.backends.hf import HFModel
    from llm_agents.backends.hf.prefix import PrefixStore

    options: dict[str, Any] = {"device": args.device}
    if args.device == "cpu":
        options["threads"] = args.threads
    if args.rows_per_forward is not None:
        options["rows_per_forward"] = args.rows_per_forward
    config = GenerateConfig()
    if args.max_tokens is not None:
        config = GenerateConfig(max_tokens=args.max_tokens)
    model = HFModel(args.model, config, **options)
    budget = model.prefixes.budget_tokens
    goals = [goal for goal in env.load_dataset().goals if goal.split == "easy_train"]
    instructions = [goals[slot % len(goals)].texts[0] for slot in range(args.episodes)]
    world = World("classic")
    sides = [
        Side("without", PrefixStore(0), instructions, "classic", world),
        Side("with", PrefixStore(budget), instructions, "classic", world),
    ]
    _ = model.model  # the weights load lazily: outside the timing
    for step in range(args.steps):
        order = sides if step % 2 == 0 else sides[::-1]
        for side in order:
            side.step(model)
            print(
                f"step {step + 1}/{args.steps} {side.name}: {side.tally.cpu_s:.0f} CPU s so far",
                flush=True,
            )
    without, with_reuse = (side.tally for side in sides)
    same = sum(a == b for a, b in zip(without.answers, with_reuse.answers, strict=True))
    print(
        f"\nhf:{args.model} zero-shot free text, Classic, {args.episodes} episodes x "
        f"{args.steps} steps, max_tokens {config.max_tokens}, rows decoded together "
        f"{model.rows_per_forward} (prompts per forward pass {model.prefill_rows}), device {model.device} ({model.dtype}), torch threads "
        f"{torch.get_num_threads()}, load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"{'configuration':<15}{'CPU s/step':>12}{'of it model':>13}{'wall s/step':>13}"
        f"{'prompt tok':>12}"
        f"{'computed':>10}{'completion':>12}"
    )
    for side in sides:
        tally = side.tally
        print(
            f"{side.name:<15}{tally.cpu_s / tally.steps:>12.2f}"
            f"{tally.model_cpu_s / tally.steps:>13.2f}{tally.wall_s / tally.steps:>13.2f}"
            f"{tally.prompt_tokens / tally.steps:>12.0f}{tally.computed_tokens / tally.steps:>10.0f}"
            f"{tally.completion_tokens / tally.steps:>12.1f}"
        )
    print(
        f"with / without: CPU {with_reuse.cpu_s / without.cpu_s:.2f}x "
        f"({without.cpu_s / with_reuse.cpu_s:.2f}x fewer CPU s), wall "
        f"{with_reuse.wall_s / without.wall_s:.2f}x; same answers: {same}/{len(without.answers)}"
    )


if __name__ == "__main__":
    main()
