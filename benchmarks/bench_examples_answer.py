"""Worked examples that answer the text being read: how many texts the old rule showed their own
answer, and what a model reads on those texts under either rule.

The old rule left an example out only when the text phrases its goal; a test paraphrase of a
goal that training states in other words was then shown that goal's exact JSON. The current rule
also leaves out an example whose reading is the text's own (`examples_for`). For each difficulty,
category and number of shots this prints the texts the old rule showed their answer (the current
rule shows none: tests/test_grounding_medium.py checks it). With `--model`, the texts so affected
at `--shots` (EASY, Classic) are read by the model under both rules, greedy, `--max-tokens`.

    python benchmarks/bench_examples_answer.py [--dataset PATH] [--shots-list 1 2 4 8 16]
        [--model hf:/path/to/qwen2.5-coder-0.5b --shots 4 --max-tokens 64]

The dataset defaults to the official repository at 1c518ae when `../shared/data` holds its
archive (unpacked into a temporary folder).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from env.dataset import Dataset, Instruction, load_dataset  # noqa: E402
from env.goals import DIFFICULTY_CATEGORIES, Difficulty  # noqa: E402
from env.variant import Variant  # noqa: E402
from llm_agents.agents.grounding import (  # noqa: E402
    GroundingExample,
    grounding_messages,
    parse_grounding,
    training_examples,
)
from llm_agents.run_data.readings import reading_of  # noqa: E402

OFFICIAL_ARCHIVE = REPO.parent / "shared" / "data" / "craftext_official_1c518ae.zip"


def old_rule(examples: Sequence[GroundingExample]) -> list[GroundingExample]:
    """The examples as the old rule offered them: left out by phrasing only (a reading that
    equals nothing, so the current rule's second test never fires)."""
    return [example.model_copy(update={"reading": None}) for example in examples]


def shown_own_answer(
    instruction: Instruction, examples: Sequence[GroundingExample], shots: int
) -> bool:
    """Whether the old rule's first `shots` examples for the text hold its own goal."""
    truth = reading_of(instruction.goal)
    offered = [e for e in examples if instruction.text not in e.texts][:shots]
    return any(e.reading == truth for e in offered)


def texts(dataset: Dataset, difficulty: Difficulty, category: str) -> list[Instruction]:
    try:
        return dataset.instructions([category], difficulty=difficulty)
    except Exception:  # a split the dataset lacks (Hard's test splits)
        return []


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", help="dataset source (default: the official archive)")
    parser.add_argument("--shots-list", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--model", help="read the affected EASY texts with this model spec")
    parser.add_argument("--shots", type=int, default=4)
    parser.add_argument("--max-tokens", type=int, default=64)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as scratch:
        source = args.dataset
        if source is None and OFFICIAL_ARCHIVE.exists():
            with zipfile.ZipFile(OFFICIAL_ARCHIVE) as archive:
                archive.extractall(scratch)
            [source] = [str(p) for p in Path(scratch).iterdir() if p.is_dir()]
        dataset = load_dataset(source)

        print("Texts the old rule showed their own answer, by number of shots:")
        print(f"{'difficulty':<10} {'category':<12} {'texts':>5}  " + "  ".join(
            f"{shots:>3}" for shots in args.shots_list
        ))  # fmt: skip
        difficulties: tuple[Difficulty, ...] = ("easy", "medium", "hard")
        for difficulty in difficulties:
            examples = training_examples(dataset, difficulty)
            for category in DIFFICULTY_CATEGORIES[difficulty]:
                asked = texts(dataset, difficulty, category)
                if not asked:
                    continue
                counts = [
                    sum(shown_own_answer(i, examples, shots) for i in asked)
                    for shots in args.shots_list
                ]
                print(f"{difficulty:<10} {category:<12} {len(asked):>5}  " + "  ".join(
                    f"{count:>3}" for count in counts
                ))  # fmt: skip

        if args.model:
            read_affected(dataset, args.model, args.shots, args.max_tokens)


def read_affected(dataset: Dataset, spec: str, shots: int, max_tokens: int) -> None:
    from llm_agents.backends import get_model
    from llm_agents.backends.base import GenerateConfig

    examples = training_examples(dataset, "easy")
    affected = [
        i
        for category in DIFFICULTY_CATEGORIES["easy"]
        for i in texts(dataset, "easy", category)
        if shown_own_answer(i, examples, shots)
    ]
    model = get_model(spec, GenerateConfig(max_tokens=max_tokens))
    print(f"\n{spec}, {shots} shots, the {len(affected)} EASY texts affected (Classic):")
    for rule, offered in (("old", old_rule(examples)), ("current", list(examples))):
        conversations = [
            grounding_messages(
                i.text, Variant.CLASSIC, None, "easy", offered, shots, answer=reading_of(i.goal)
            )
            for i in affected
        ]
        outputs = model.generate(conversations)
        right = sum(
            parse_grounding(o.text, Variant.CLASSIC).matches(reading_of(i.goal))
            for i, o in zip(affected, outputs, strict=True)
        )
        print(f"  {rule} rule: {right} of {len(affected)} read exactly right")
    model.close()


if __name__ == "__main__":
    main()
