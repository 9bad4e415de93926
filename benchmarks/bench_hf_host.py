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
part this change is about), decisions/s of whole `generate` calls and the host's share of
that time (best of `--repeats` rounds, which alternate the configurations in a rotating order
so that a change in the machine's load falls on all of them), and whether the chosen actions equal `after`'s.

    python benchmarks/bench_hf_host.py [--variant full] [--slots 16] [--steps 2] [--repeats 2]
        [--threads 2] [--before f75c7fb]
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


class Pass(BaseModel):
    """One timed pass of a configuration over the timed steps."""

    host_s: float
    """Rendering and encoding every prompt of the steps."""
    total_s: float
    """The steps' `generate` calls."""
    prompt_tokens: int
    """Prompt tokens of all decisions."""
    answers: list[str]
    """The chosen action of every decision, in order."""


def prompt_ids(model: Any, conversations: list[Any]) -> list[Any]:
    """The prompts' token ids as the backend computes them (older revisions: one at a time)."""
    if hasattr(model, "_prompt_ids"):
        return list(model._prompt_ids(conversations))
    return [model._encode(model._render(conversation)) for conversation in conversations]


class Runner:
    """One configuration's model, warmed up on the first step, timed on the others."""

    def __init__(self, steps: list[list[Any]], options: list[str], reuse: bool, **kw: Any):
        from llm_agents.backends.base import ChoiceSet, GenerateConfig
        from llm_agents.backends.hf import HFModel

        self.model = HFModel("smollm2-135m", GenerateConfig(max_tokens=1), **kw)
        if not reuse:
            self.model.reuse_prompt_tokens = False
        self.choices = ChoiceSet(options=tuple(options), rule="loglik")
        self.steps = steps[1:]
        # Lazy initialisation, and the system prompt's first encoding and keys and values.
        self.model.generate(steps[0], self.choices)

    def one_pass(self) -> Pass:
        start = time.perf_counter()
        for step in self.steps:
            prompt_ids(self.model, step)
        host = time.perf_counter() - start
        start = time.perf_counter()
        outputs = [o for step in self.steps for o in self.model.generate(step, self.choices)]
        total = time.perf_counter() - start
        if errors := [o.error for o in outputs if o.finish_reason == "error"]:
            raise RuntimeError(errors[0])
        tokens = sum(o.prompt_tokens for o in outputs)
        return Pass(
            host_s=host, total_s=total, prompt_tokens=tokens, answers=[o.text for o in outputs]
        )


class RevisionRunner:
    """A `Runner` in a child process on the hf backend of a git revision (one pass per line)."""

    def __init__(self, revision: str, workload: dict[str, Any], threads: int | None):
        self.scratch = tempfile.TemporaryDirectory()
        code = Path(self.scratch.name) / "code"
        code.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", revision], check=True, capture_output=True
        )
        subprocess.run(["tar", "-x", "-C", str(code)], input=archive.stdout, check=True)
        workload_path = Path(self.scratch.name) / "workload.json"
        workload_path.write_text(json.dumps(workload))
        command = [sys.executable, __file__, "--child", str(workload_path)]
        if threads is not None:
            command += ["--threads", str(threads)]
        env = {**os.environ, "BENCH_HF_CODE": str(code), "PYTHONPATH": str(code)}
        self.child = subprocess.Popen(
            command, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self._read()  # ready: loaded and warmed up

    def _read(self) -> str:
        assert self.child.stdout is not None
        for line in self.child.stdout:
            if line.startswith(RESULT):
                return line[len(RESULT) :]
        raise RuntimeError(f"the child measuring the old revision ended ({self.child.wait()})")

    def one_pass(self) -> Pass:
        assert self.child.stdin is not None
        self.child.stdin.write("pass\n")
        self.child.stdin.flush()
        return Pass.model_validate_json(self._read())

    def close(self) -> None:
        if self.child.stdin is not None:
            self.child.stdin.close()
        self.child.wait()
        self.scratch.cleanup()


RESULT = "RESULT "


def child(workload_path: Path, options: dict[str, Any]) -> None:
    from llm_agents.backends.base import ChatMessage

    workload = json.loads(workload_path.read_text())
    steps = [[[ChatMessage(**m) for m in c] for c in step] for step in workload["steps"]]
    runner = Runner(steps, workload["options"], reuse=True, **options)
    print(RESULT, flush=True)
    for _ in sys.stdin:
        print(RESULT + runner.one_pass().model_dump_json(), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="full", choices=["classic", "full"])
    parser.add_argument("--slots", type=int, default=16, help="episodes per step (batch)")
    parser.add_argument("--steps", type=int, default=2, help="timed steps (after one warm-up)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds; the best is kept")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--before", default=BASE_REVISION, help="git revision, or 'none'")
    parser.add_argument("--child", metavar="WORKLOAD", help=argparse.SUPPRESS)
    args = parser.parse_args()
    options = {} if args.threads is None else {"threads": args.threads}
    if args.child:
        child(Path(args.child), options)
        return

    from bench_backends import build_realistic_steps

    built = build_realistic_steps(args.variant, args.slots, args.steps + 1)
    steps = [
        built.conversations[step * args.slots : (step + 1) * args.slots]
        for step in range(args.steps + 1)
    ]
    runners: dict[str, Any] = {
        "after": Runner(steps, built.choices, reuse=True, **options),
        "no reuse": Runner(steps, built.choices, reuse=False, **options),
    }
    if args.before != "none":
        workload = {
            "steps": [[[m.model_dump() for m in c] for c in step] for step in steps],
            "options": built.choices,
        }
        runners[f"before {args.before}"] = RevisionRunner(args.before, workload, args.threads)
    # Rounds alternate the configurations, each round starting at the next one, so that a
    # change in the machine's load, and whatever costs the first pass of a round, falls on all.
    passes: dict[str, list[Pass]] = {name: [] for name in runners}
    names = list(runners)
    try:
        for round_index in range(args.repeats):
            shift = round_index % len(names)
            for name in names[shift:] + names[:shift]:
                passes[name].append(runners[name].one_pass())
    finally:
        for runner in runners.values():
            if isinstance(runner, RevisionRunner):
                runner.close()
    import torch

    decisions = args.slots * args.steps
    after = passes["after"]
    print(
        f"hf loglik on real {args.variant} prompts "
        f"({after[0].prompt_tokens / decisions:.0f} tokens on average), {args.slots} per call, "
        f"{len(built.choices)} actions, {args.steps} timed steps x {args.repeats} rounds "
        f"(best kept), torch threads {torch.get_num_threads()}, CPU"
    )
    print(
        f"{'configuration':<18}{'host ms/decision':>18}{'decisions/s':>13}"
        f"{'host share':>12}{'same answers':>14}"
    )
    best = {}
    for name, runs in passes.items():
        host = min(p.host_s for p in runs)
        total = min(p.total_s for p in runs)
        best[name] = (host, total)
        same = all(p.answers == after[0].answers for p in runs)
        print(
            f"{name:<18}{1000 * host / decisions:>18.2f}{decisions / total:>13.3f}"
            f"{host / total:>12.2%}{'yes' if same else 'NO':>14}"
        )
    for name, (host, total) in best.items():
        if name != "after":
            print(
                f"after vs {name}: host time {host / best['after'][0]:.1f}x lower, "
                f"decisions/s {total / best['after'][1]:.2f}x"
            )


if __name__ == "__main__":
    main()
