"""Seconds per request of hf free generation with prefix reuse, by rows decoded together and
prompts computed per forward pass.

Real zero-shot Classic prompts (`bench_backends.build_realistic_steps`: `--requests` episodes,
two steps each; free text by default, the prompt that asks for a short thought before the
action, or `--choice-prompt` for the one that asks for the action's name only). The prefix
store is warmed on the first step (system prompt and each episode's prompt kept, as a run has
them by its second step); each setting then answers the second step's prompts from a copy of
that warmed store, so all of them compute the same tokens. Greedy, `--max-tokens` tokens at
most per answer. Printed per setting (`--rows` decoded together x `--prefill-rows` prompts per
forward pass, at most the rows): CPU seconds (this process, all threads) and wall seconds per
request, and whether the answers equal the first setting's. The hf backend's per-device
defaults (`ROWS_PER_FORWARD`, `PREFILL_ROWS` in llm_agents/backends/hf/model.py) come from this
measurement.

    nice python benchmarks/bench_rows_per_forward.py [--model qwen2.5-coder-0.5b]
        [--device cpu] [--rows 1 2 4 8 16] [--prefill-rows 1 2 16] [--requests 16]
        [--max-tokens 256] [--threads 1] [--choice-prompt]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="qwen2.5-coder-0.5b", help="hf model name")
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda, ...)")
    parser.add_argument("--rows", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--prefill-rows", type=int, nargs="+", default=[1, 2, 16])
    parser.add_argument("--requests", type=int, default=16, help="episodes (requests per pass)")
    parser.add_argument("--max-tokens", type=int, default=256)
    parser.add_argument(
        "--choice-prompt", action="store_true", help="the prompt asking for the name only"
    )
    # One thread: on a shared CPU, idle threads of a pool spin and count as CPU seconds.
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (cpu)")
    args = parser.parse_args()

    import torch
    from bench_backends import build_realistic_steps

    from llm_agents.backends.base import GenerateConfig
    from llm_agents.backends.hf import HFModel

    options: dict[str, Any] = {"device": args.device}
    if args.device == "cpu":
        options["threads"] = args.threads
    model = HFModel(args.model, GenerateConfig(max_tokens=args.max_tokens), **options)
    built = build_realistic_steps(
        "classic", args.requests, 2, choice_rule="loglik" if args.choice_prompt else None
    )
    first, second = built.conversations[: args.requests], built.conversations[args.requests :]
    model.rows_per_forward = model.prefill_rows = args.requests
    warm_config = model.config
    model.config = GenerateConfig(max_tokens=1)
    model.generate(first)
    model.config = warm_config
    warmed = model.prefixes
    prompt = "choice prompt" if args.choice_prompt else "free text"
    print(
        f"hf:{args.model} {prompt}, {args.requests} requests, max_tokens {args.max_tokens}, "
        f"device {model.device} ({model.dtype}), torch threads {torch.get_num_threads()}"
    )
    print(
        f"{'rows':>5}{'prefill':>8}{'CPU s/request':>15}{'wall s/request':>16}"
        f"{'computed':>10}{'answer tok':>11}{'same':>6}"
    )
    reference = None
    settings = sorted(
        {(rows, min(prefill, rows)) for rows in args.rows for prefill in args.prefill_rows}
    )
    for rows, prefill in settings:
        model.rows_per_forward, model.prefill_rows = rows, prefill
        model.prefixes = warmed.copy()
        cpu, wall = time.process_time(), time.perf_counter()
        outputs = model.generate(second)
        if args.device != "cpu":
            torch.cuda.synchronize()
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        answers = [o.text for o in outputs]
        reference = reference or answers
        computed = sum(o.computed_prompt_tokens or 0 for o in outputs) / len(outputs)
        answered = sum(o.completion_tokens for o in outputs) / len(outputs)
        print(
            f"{rows:>5}{prefill:>8}{cpu / len(outputs):>15.2f}{wall / len(outputs):>16.2f}"
            f"{computed:>10.0f}{answered:>11.1f}{'yes' if answers == reference else 'no':>6}",
            flush=True,
        )


if __name__ == "__main__":
    main()
