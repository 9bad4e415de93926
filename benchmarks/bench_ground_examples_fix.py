"""Few-shot grounding of every EASY text before and after the worked-example fix, with the
per-text and the clustered intervals side by side.

Before the fix an example was left out only when the asked text phrases its goal, so a text
whose goal training states in other words was shown its own answer. `--rule old` reproduces that
rule here (explicitly: the examples' readings are hidden from `examples_for`, so only the text
test fires); `current` is what `craftext-llm ground` does. Both rules read the texts through
`prepare_grounding` / `execute_grounding`, each in its own run directory, sharing one response
cache: decoding is greedy, so a text whose prompt the fix leaves unchanged is asked once and the
second rule reads it from the cache.

The texts whose prompt the fix changed are read first, then the others in a seeded random
order, both rules a chunk at a time, so an interrupted run (or `--only-print`) has read every
changed text and a random sample of the rest, the same under both rules; a rerun resumes.

    python benchmarks/bench_ground_examples_fix.py --model hf:/path/to/qwen2.5-coder-0.5b
        [--shots 4] [--categories one combo paraphrased new_objects] [--max-tokens 64]
        [--threads 2] [--chunk 16] [--seed 0] [--dataset PATH]
        [--out runs/bench-ground-examples-fix] [--only-print]

Printed: for each category and overall, texts read exactly right under each rule, with the
per-text binomial (Wilson) interval, which treats the ~6 phrasings of a goal as independent, and
the interval clustered by goal (`clustered_rate`) that `ground` reports; then the texts whose
prompt the fix changed and how each rule read them.
"""

from __future__ import annotations

import argparse
import random
import sys
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.official_clone import official_clone  # noqa: E402
from env.dataset import Instruction  # noqa: E402
from env.goals import DIFFICULTY_CATEGORIES  # noqa: E402
from llm_agents.agents.grounding import GroundingExample  # noqa: E402
from llm_agents.backends.base import GenerateConfig  # noqa: E402
from llm_agents.evaluation.grounding_run import (  # noqa: E402
    GroundConfig,
    GroundingRecord,
    PreparedGrounding,
    execute_grounding,
    prepare_grounding,
    read_groundings,
)
from llm_agents.run_data.metrics import SuccessRate, clustered_rate, wilson_interval  # noqa: E402

RULES = ("old", "current")


def old_rule(examples: Sequence[GroundingExample]) -> tuple[GroundingExample, ...]:
    """The examples as the rule before the fix offered them: a reading that equals nothing, so
    an example is left out only when the asked text phrases its goal."""
    return tuple(example.model_copy(update={"reading": None}) for example in examples)


def _dataset(args: argparse.Namespace, out: Path) -> str | None:
    return str(args.dataset) if args.dataset else official_clone(out)


def _prepare(args: argparse.Namespace, out: Path, rule: str) -> PreparedGrounding:
    config = GroundConfig(
        model=args.model,
        generation=GenerateConfig(max_tokens=args.max_tokens),
        backend_options={"threads": args.threads} if args.model.startswith("hf:") else {},
        cache=str(out / "responses.sqlite"),
        dataset=_dataset(args, out),
        difficulty="easy",
        categories=tuple(args.categories),
        grounding_shots=args.shots,
        output_dir=str(out / f"{rule}-{args.shots}shots"),
        requests_per_call=args.chunk,
    )
    prepared = prepare_grounding(config)
    if rule == "old":
        prepared.examples = old_rule(prepared.examples)
    return prepared


def _order(prepared: dict[str, PreparedGrounding], seed: int) -> list[Instruction]:
    """The texts whose prompt the fix changed, then the others in a seeded random order: a
    partial run has read every changed text and a random sample of the rest."""
    texts = list(prepared["current"].instructions)
    changed = [i for i in texts if _changed(prepared, i)]
    rest = [i for i in texts if i not in changed]
    random.Random(seed).shuffle(rest)
    return changed + rest


def _changed(prepared: dict[str, PreparedGrounding], instruction: Instruction) -> bool:
    return prepared["current"].messages(instruction) != prepared["old"].messages(instruction)


def _cell(records: Sequence[GroundingRecord]) -> tuple[str, str]:
    right = sum(r.correct for r in records)
    low, high = wilson_interval(right, len(records))
    clustered: SuccessRate = clustered_rate(
        ((r.split, r.goal_id), int(r.correct), 1) for r in records
    )
    rate = f"{right}/{len(records)} = {right / len(records):.2f}"
    return (
        f"{rate} [{low:.2f}, {high:.2f}]",
        f"[{clustered.low:.2f}, {clustered.high:.2f}] ({clustered.clusters} goals)",
    )


def _print(args: argparse.Namespace, prepared: dict[str, PreparedGrounding]) -> None:
    read = {rule: {r.key: r for r in read_groundings(p.output_dir)} for rule, p in prepared.items()}
    both = [k for k in read["current"] if k in read["old"]]
    texts = prepared["current"].instructions
    every_changed = sum(_changed(prepared, i) for i in texts)
    changed = [i for i in texts if i.key in both and _changed(prepared, i)]
    print(
        f"{args.model}, {args.shots} shots, EASY, Classic, greedy, max {args.max_tokens} tokens: "
        f"{len(both)} of {len(texts)} texts read under both rules"
        + (
            ""
            if len(both) == len(texts)
            else f" (the {len(changed)} whose prompt the fix changed, and a seeded random "
            f"sample of {len(both) - len(changed)} of the other {len(texts) - every_changed}, "
            f"seed {args.seed})"
        )
    )
    print(
        f"{'category':<12} {'rule':<8} {'exact (per-text Wilson)':>30}  {'clustered by goal':>26}"
    )
    categories = [*args.categories, "all"]
    for category in categories:
        for rule in RULES:
            records = [
                read[rule][k]
                for k in both
                if category == "all" or read[rule][k].category == category
            ]
            if not records:
                continue
            plain, clustered = _cell(records)
            print(f"{category:<12} {rule:<8} {plain:>30}  {clustered:>26}")

    print(
        f"\nTexts whose prompt the fix changed (the old rule showed their answer): {len(changed)}"
    )
    for instruction in changed:
        marks = " ".join(
            f"{rule}={'right' if read[rule][instruction.key].correct else 'wrong'}"
            for rule in RULES
        )
        print(f"  {instruction.key:<40} {marks}  {instruction.text[:60]!r}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="a model spec, e.g. hf:/path/to/model")
    parser.add_argument("--shots", type=int, default=4)
    parser.add_argument("--categories", nargs="+", default=list(DIFFICULTY_CATEGORIES["easy"]))
    parser.add_argument("--max-tokens", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2, help="hf: CPU threads")
    parser.add_argument("--chunk", type=int, default=16, help="texts read per rule in turn")
    parser.add_argument("--seed", type=int, default=0, help="the order the texts are read in")
    parser.add_argument("--dataset")
    parser.add_argument("--out", default=str(REPO / "runs" / "bench-ground-examples-fix"))
    parser.add_argument("--only-print", action="store_true", help="print what was read")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    prepared = {rule: _prepare(args, out, rule) for rule in RULES}
    order = _order(prepared, args.seed)
    for rule in RULES:
        prepared[rule].instructions = order

    if not args.only_print:
        from llm_agents.evaluation.runner import open_model

        with open_model(prepared["current"].config) as model:
            try:
                for end in range(args.chunk, len(order) + args.chunk, args.chunk):
                    for rule in RULES:
                        prepared[rule].instructions = order[:end]
                        execute_grounding(prepared[rule], model)
                    print(f"read {min(end, len(order))} texts", flush=True)
            except KeyboardInterrupt:
                print("interrupted: printing what was read", file=sys.stderr)
            finally:
                for rule in RULES:
                    prepared[rule].instructions = order
    _print(args, prepared)


if __name__ == "__main__":
    main()
