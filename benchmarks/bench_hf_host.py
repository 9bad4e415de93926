"""hf backend decisions/s on CPU before and after the lean host path, on real CrafText prompts.

Each call is one agent step of `--slots` episodes answered in `loglik` choice mode (the action
names) by the embedded model (SmolLM2-135M). Three configurations run the same steps:

- `after`: this checkout's backend: a system prompt's tokens are kept, only the rest of every
  prompt is encoded, in one batched tokenizer call, and tensors are built from numpy arrays;
- `no reuse`: the same backend with `reuse_prompt_tokens` off (every prompt encoded whole, still
  batched): what keeping the system prompt's tokens saves;
- `before` (`--before REV`, default f75c7fb; `--before none` skips it): the backend as it was at
  that git revision (each prompt rendered and encoded alone, tensors from Python lists), run in
  a child process on the same workload, from a copy of that revision (`git archive`).

Printed per configuration: host time per decision (rendering and encoding the prompts, the
part this change is about), decisions/s of whole `generate` calls (best of `--repeats` passes
over the steps), and whether the chosen actions equal `after`'s.

    python benchmarks/bench_hf_host.py [--variant full] [--slots 16] [--steps 3] [--threads 2]
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
# A child measuring another revision puts that revision's code first.
sys.path.insert(0, os.environ.get("BENCH_HF_CODE", str(REPO)))
sys.path.insert(1, str(REPO / "benchmarks"))

BASE_REVISION = "f75c7fb"


class Measured(BaseModel):
    """One configuration's figures."""

    name: str
    """`after`, `no reuse` or `before REV`."""
    host_ms: float
    """Rendering and encoding the prompts, per decision (best pass)."""
    decisions_per_s: float
    """Decisions per second of whole `generate` calls (best pass)."""
    prompt_tokens: float
    """Mean prompt tokens per decision."""
    answers: list[str]
    """The chosen action of every decision, in order."""


def prompt_ids(model: Any, conversations: list[Any]) -> list[Any]:
    """The prompts' token ids as the backend computes them (older revisions: one at a time)."""
    if hasattr(model, "_prompt_ids"):
        return list(model._prompt_ids(conversations))
    return [model._encode(model._render(conversation)) for conversation in conversations]


def measure(
    name: str, steps: list[list[Any]], options: list[str], repeats: int, **kw: Any
) -> Measured:
    from llm_agents.backends.base import ChoiceSet, GenerateConfig
    from llm_agents.backends.hf import HFModel

    reuse = kw.pop("reuse", True)
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=1), **kw)
    if not reuse:
        model.reuse_prompt_tokens = False
    choices = ChoiceSet(options=tuple(options), rule="loglik")
    # Warm-up on the first step: lazy initialisation, and the system prompt's first encoding.
    model.generate(steps[0], choices)
    timed = steps[1:]
    decisions = sum(len(step) for step in timed)
    best_host = best_total = float("inf")
    answers: list[str] = []
    tokens = 0
    for _ in range(repeats):
        start = time.perf_counter()
        for step in timed:
            prompt_ids(model, step)
        best_host = min(best_host, time.perf_counter() - start)
        start = time.perf_counter()
        outputs = [output for step in timed for output in model.generate(step, choices)]
        best_total = min(best_total, time.perf_counter() - start)
        if errors := [o.error for o in outputs if o.finish_reason == "error"]:
            raise RuntimeError(f"{name}: {errors[0]}")
        answers = [o.text for o in outputs]
        tokens = sum(o.prompt_tokens for o in outputs)
    return Measured(
        name=name,
        host_ms=1000 * best_host / decisions,
        decisions_per_s=decisions / best_total,
        prompt_tokens=tokens / decisions,
        answers=answers,
    )


def measure_revision(revision: str, workload: dict[str, Any], args: argparse.Namespace) -> Measured:
    """`measure` in a child process running the hf backend of a git revision."""
    with tempfile.TemporaryDirectory() as scratch:
        code = Path(scratch) / "code"
        code.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", revision], check=True, capture_output=True
        )
        subprocess.run(["tar", "-x", "-C", str(code)], input=archive.stdout, check=True)
        workload_path, result_path = Path(scratch) / "workload.json", Path(scratch) / "out.json"
        workload_path.write_text(json.dumps(workload))
        command = [sys.executable, __file__, "--child", str(workload_path), str(result_path)]
        command += ["--repeats", str(args.repeats)]
        if args.threads is not None:
            command += ["--threads", str(args.threads)]
        env = {**os.environ, "BENCH_HF_CODE": str(code), "PYTHONPATH": str(code)}
        subprocess.run(command, env=env, check=True)
        return Measured.model_validate_json(result_path.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="full", choices=["classic", "full"])
    parser.add_argument("--slots", type=int, default=16, help="episodes per step (batch)")
    parser.add_argument("--steps", type=int, default=3, help="timed steps (after one warm-up)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--before", default=BASE_REVISION, help="git revision, or 'none'")
    parser.add_argument("--child", nargs=2, metavar=("WORKLOAD", "RESULT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    options = {} if args.threads is None else {"threads": args.threads}

    from llm_agents.backends.base import ChatMessage

    if args.child:
        workload_path, result_path = map(Path, args.child)
        workload = json.loads(workload_path.read_text())
        steps = [[[ChatMessage(**m) for m in c] for c in step] for step in workload["steps"]]
        revision = workload["revision"]
        measured = measure(
            f"before {revision}", steps, workload["options"], args.repeats, **options
        )
        result_path.write_text(measured.model_dump_json())
        return

    from bench_backends import build_realistic_steps

    built = build_realistic_steps(args.variant, args.slots, args.steps + 1)
    steps = [
        built.conversations[step * args.slots : (step + 1) * args.slots]
        for step in range(args.steps + 1)
    ]
    rows = [
        measure("after", steps, built.choices, args.repeats, **options),
        measure("no reuse", steps, built.choices, args.repeats, reuse=False, **options),
    ]
    if args.before != "none":
        workload = {
            "steps": [[[m.model_dump() for m in c] for c in step] for step in steps],
            "options": built.choices,
            "revision": args.before,
        }
        rows.append(measure_revision(args.before, workload, args))
    import torch

    after = rows[0]
    print(
        f"hf loglik on real {args.variant} prompts ({after.prompt_tokens:.0f} tokens on average), "
        f"{args.slots} per call, {len(built.choices)} actions, {args.steps} timed steps, "
        f"torch threads {torch.get_num_threads()}, CPU"
    )
    print(
        f"{'configuration':<18}{'host ms/decision':>18}{'decisions/s':>13}"
        f"{'vs after':>10}{'same answers':>14}"
    )
    for row in rows:
        print(
            f"{row.name:<18}{row.host_ms:>18.2f}{row.decisions_per_s:>13.2f}"
            f"{row.decisions_per_s / after.decisions_per_s:>10.2f}"
            f"{'yes' if row.answers == after.answers else 'NO':>14}"
        )
    for row in rows[1:]:
        print(
            f"after vs {row.name}: host time {row.host_ms / after.host_ms:.1f}x lower, "
            f"decisions/s {after.decisions_per_s / row.decisions_per_s:.2f}x"
        )


if __name__ == "__main__":
    main()
