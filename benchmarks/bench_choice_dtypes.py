"""How far the hf backend's `loglik` choice scores are from a plain forward pass, per dtype and
choice path, on real CrafText agent prompts.

For each dtype, the embedded model (SmolLM2-135M) scores action names after the agent's
conversations twice: by the split-attention path and by the padded (prefix-copying) path,
each first with a fresh prompt prefix (step 1's conversations) and then with the prefix kept
from that call (step 2's conversations). Every score is compared with one plain forward pass
over prompt + action name in the same dtype (the model's default attention, sdpa). Three
yardsticks of the dtype's own rounding come with it: the same plain pass with eager attention
(another, equally valid kernel), the same plain pass run as one batch over all the options
(the same kernels, another batch size), and the plain pass in float32, which the choice scores
are also compared with. A dtype the backend refuses for `loglik` (bfloat16) is still measured,
by calling the scorer past the refusal, and marked `refused`.

    python benchmarks/bench_choice_dtypes.py [--device cpu] [--dtypes float32 bfloat16 float16]
        [--slots 1] [--options 6] [--threads 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

import torch  # noqa: E402
from bench_backends import build_realistic_steps  # noqa: E402

from env.errors import UserError  # noqa: E402
from llm_agents.backends.base import ChatMessage, GenerateConfig  # noqa: E402
from llm_agents.backends.hf import HFModel  # noqa: E402

#: Action names of several token lengths, sharing prefixes (the candidate trie's hard cases).
DEFAULT_OPTIONS = [
    "MAKE_WOOD_PICKAXE",
    "MAKE_STONE_PICKAXE",
    "DO",
    "PLACE_TABLE",
    "NOOP",
    "SLEEP",
    "MOVE_LEFT",
    "PLACE_STONE",
]


def plain_scores(
    model: HFModel, conversation: list[ChatMessage], options: list[str], attention: str
) -> list[float]:
    """Each option's log-likelihood from one uncached forward pass over prompt + option."""
    prompt = model._encode(model._render(conversation))
    config = model.model.config
    default = config._attn_implementation
    config._attn_implementation = attention
    scores = []
    try:
        for option in options:
            ids = model._encode(option)
            with torch.inference_mode():
                logits = model.model(input_ids=torch.tensor([prompt + ids], device=model.device))
            log_probs = logits.logits[0].float().log_softmax(-1)
            scores.append(sum(float(log_probs[len(prompt) - 1 + j, t]) for j, t in enumerate(ids)))
    finally:
        config._attn_implementation = default
    return scores


def batched_plain_scores(
    model: HFModel, conversation: list[ChatMessage], options: list[str]
) -> list[float]:
    """`plain_scores` (sdpa) with every option in one right-padded batch: no cache, no mask."""
    prompt = model._encode(model._render(conversation))
    candidates = [model._encode(option) for option in options]
    width = max(len(ids) for ids in candidates)
    rows = [prompt + ids + [ids[-1]] * (width - len(ids)) for ids in candidates]
    with torch.inference_mode():
        logits = model.model(input_ids=torch.tensor(rows, device=model.device)).logits
    log_probs = logits.float().log_softmax(-1)
    return [
        sum(float(log_probs[k, len(prompt) - 1 + j, t]) for j, t in enumerate(ids))
        for k, ids in enumerate(candidates)
    ]


def scorer(model: HFModel, conversations: list[list[ChatMessage]], options: list[str]) -> Any:
    """`choice_scores` without the dtype check, so a refused dtype can be measured too."""
    prompts = model._prompt_ids(conversations)
    candidates = [model._encode(option) for option in options]
    return model.scorer.log_likelihoods(model.model, prompts, candidates)


def largest_gap(a: list[list[float]], b: list[list[float]]) -> float:
    return max(abs(x - y) for ra, rb in zip(a, b, strict=True) for x, y in zip(ra, rb, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--dtypes", nargs="+", default=["float32", "bfloat16", "float16"])
    parser.add_argument("--variant", default="classic", choices=["classic", "full"])
    parser.add_argument("--slots", type=int, default=1, help="conversations per step")
    parser.add_argument("--options", type=int, default=len(DEFAULT_OPTIONS))
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()

    workload = build_realistic_steps(args.variant, args.slots, 2)
    steps = [
        workload.conversations[: args.slots],
        workload.conversations[args.slots : 2 * args.slots],
    ]
    options = DEFAULT_OPTIONS[: args.options]
    conversations = [c for step in steps for c in step]
    options_kw = {} if args.threads is None else {"threads": args.threads}
    reference = HFModel(
        "smollm2-135m", GenerateConfig(), device=args.device, dtype="float32", **options_kw
    )
    float32 = [plain_scores(reference, c, options, "sdpa") for c in conversations]
    tokens = [len(reference._encode(reference._render(c))) for c in conversations]
    del reference
    rows = []
    for dtype in args.dtypes:
        start = time.perf_counter()
        model = HFModel(
            "smollm2-135m", GenerateConfig(), device=args.device, dtype=dtype, **options_kw
        )
        plain = [plain_scores(model, c, options, "sdpa") for c in conversations]
        eager = [plain_scores(model, c, options, "eager") for c in conversations]
        batched = [batched_plain_scores(model, c, options) for c in conversations]
        try:
            model.check_choice_rule("loglik")
            accepted = "yes"
        except UserError:
            accepted = "refused"
        for split in (True, False):
            model.scorer.split_attention = split
            model.scorer.forget_prefix()
            fresh = scorer(model, steps[0], options)
            reused = scorer(model, steps[1], options)
            rows.append(
                (
                    dtype,
                    "split" if split else "padded",
                    accepted,
                    largest_gap(fresh, plain[: args.slots]),
                    largest_gap(reused, plain[args.slots :]),
                    largest_gap(eager, plain),
                    largest_gap(batched, plain),
                    largest_gap(float32, plain),
                    largest_gap(float32, fresh + reused),
                )
            )
        print(f"{dtype}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    print(
        f"device {args.device}, {args.variant} prompts of {min(tokens)}-{max(tokens)} tokens, "
        f"{len(options)} options; largest |difference| in nats"
    )
    print(
        f"{'dtype':<10}{'path':<8}{'loglik':>8}{'vs plain (fresh)':>18}{'vs plain (reused)':>19}"
        f"{'plain: eager vs sdpa':>22}{'plain: batch n vs 1':>21}{'plain: vs float32':>19}"
        f"{'choice: vs float32':>20}"
    )
    for dtype, path, accepted, fresh_gap, reused_gap, spread, batch_gap, drift, choice in rows:
        print(
            f"{dtype:<10}{path:<8}{accepted:>8}{fresh_gap:>18.4f}{reused_gap:>19.4f}"
            f"{spread:>22.4f}{batch_gap:>21.4f}{drift:>19.4f}{choice:>20.4f}"
        )


if __name__ == "__main__":
    main()
