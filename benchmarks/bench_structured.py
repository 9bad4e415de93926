"""What holding answers to a JSON schema costs on the hf backend, on this machine's CPU.

1. Goal readings: the same grounding requests (EASY instruction texts, Classic) answered in free
   text and under the reading schema (`--structured-output`, llguidance), seconds per answer and
   per generated token, and the share of answers that parse as a goal. The target: structured
   decoding at most 1.2x the free-text time per answer.
2. Action choices (`--choice guided`): the same step prompts answered under the options' token
   trie (`backends/hf/guided.py`) and under an llguidance grammar of the same options, seconds
   per answer, and whether every answer is an option.

Each measurement runs `--repeats` times, the two sides taking turns, after one warm-up call of
each (the model load and the grammar's compile are not timed); the figure is the median.
`--threads` sets torch's CPU threads (on a machine other jobs load, fewer threads than cores
wait less on each other).

    python benchmarks/bench_structured.py [--model hf:smollm2-135m] [--texts 8]
        [--max-tokens 64] [--repeats 3] [--threads N] [--out runs/bench-structured]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.official_clone import official_clone  # noqa: E402
from env import Variant  # noqa: E402
from env.dataset import load_dataset  # noqa: E402
from llm_agents.agents.answer_schemas import reading_schema  # noqa: E402
from llm_agents.agents.answers.actions import action_names  # noqa: E402
from llm_agents.agents.grounding import grounding_messages, parse_grounding  # noqa: E402
from llm_agents.backends import get_model  # noqa: E402
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig  # noqa: E402
from llm_agents.backends.hf.structured import SchemaLogitsProcessor  # noqa: E402

VARIANT = Variant.CLASSIC


def timed(sides: list[Callable[[], Any]], repeats: int) -> list[float]:
    """Median seconds of each side's call, the sides taking turns `repeats` times."""
    seconds: list[list[float]] = [[] for _ in sides]
    for _ in range(repeats):
        for side, kept in zip(sides, seconds, strict=True):
            start = time.perf_counter()
            side()
            kept.append(time.perf_counter() - start)
    return [statistics.median(kept) for kept in seconds]


def texts(out: Path, count: int) -> list[str]:
    dataset = load_dataset(official_clone(out))
    goals = [g for g in dataset.goals if g.difficulty == "easy" and "test" in g.split]
    return [goal.instruction for goal in goals[:count]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="hf:smollm2-135m")
    parser.add_argument("--texts", type=int, default=8)
    parser.add_argument("--max-tokens", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-structured")
    args = parser.parse_args()
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)

    model: Any = get_model(args.model, GenerateConfig(max_tokens=args.max_tokens))
    schema = reading_schema(VARIANT, "easy")
    requests = [grounding_messages(text, VARIANT) for text in texts(args.out, args.texts)]
    n = len(requests)
    print(f"{args.model}, {n} EASY texts, max_tokens {args.max_tokens}, {args.repeats} repeats")

    outputs: dict[str, list[Any]] = {}

    def free() -> list[Any]:
        outputs["free"] = model.generate(requests)
        return outputs["free"]

    def structured() -> list[Any]:
        outputs["structured"] = model.generate(requests, schema=schema)
        return outputs["structured"]

    free(), structured()  # warm-up: weights, grammar
    free_s, structured_s = timed([free, structured], args.repeats)
    for name, seconds in (("free text", free_s), ("structured", structured_s)):
        answers = outputs["free" if name == "free text" else "structured"]
        tokens = sum(o.completion_tokens for o in answers)
        parsed = sum(parse_grounding(o.text, VARIANT).outcome == "valid" for o in answers)
        print(
            f"  readings, {name:<10}: {seconds / n:.3f} s/answer, "
            f"{1000 * seconds / max(tokens, 1):.1f} ms/token ({tokens} tokens), "
            f"{parsed}/{n} parse as a goal"
        )
    print(f"  structured / free text per answer: {structured_s / free_s:.2f}x (target <= 1.2x)")

    # -- action choices: the token trie against llguidance over the same options
    names = action_names(VARIANT)
    prompts: list[Sequence[ChatMessage]] = [
        [
            ChatMessage(role="system", content="You play Crafter. Answer with one action name."),
            ChatMessage(role="user", content=f"{text}\nWhich action now?"),
        ]
        for text in texts(args.out, args.texts)
    ]
    choices = ChoiceSet(options=tuple(names), rule="guided")
    grammars = model._schema_grammars()
    llg = grammars._llg
    lark = "start: " + " | ".join(f'"{name}"' for name in names)
    grammar = llg.LLMatcher.grammar_from_lark(lark)

    def trie() -> list[Any]:
        outputs["trie"] = model.generate(prompts, choices)
        return outputs["trie"]

    def llguidance() -> list[Any]:
        guide = SchemaLogitsProcessor(llg, grammars.tokenizer, grammar, model._eos_ids())
        outputs["llguidance"] = model._generate_raw(
            model._prompt_ids(prompts), [False] * len(prompts), guide
        )
        return outputs["llguidance"]

    trie(), llguidance()
    trie_s, llg_s = timed([trie, llguidance], args.repeats)
    for name, seconds in (("trie", trie_s), ("llguidance", llg_s)):
        exact = sum(o.text in names for o in outputs[name])
        print(
            f"  action choice, {name:<10}: {seconds / len(prompts):.3f} s/answer, "
            f"{exact}/{len(prompts)} answers an option"
        )
    same = sum(
        a.text == b.text for a, b in zip(outputs["trie"], outputs["llguidance"], strict=True)
    )
    print(f"  the two pick the same option in {same}/{len(prompts)} prompts")


if __name__ == "__main__":
    main()
