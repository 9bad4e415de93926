"""Plans files side by side on the CrafText splits: coverage, plan length, vocabulary.

Every file is measured on the same instruction texts (instructions and paraphrases of the chosen
splits, by default every split the dataset has, EASY, Medium and Hard), with the planner's own
parser, limits and Craftax vocabulary, so a file we generated and CrafText's official GPT-4 file
compare directly. `covered` says how many of a split's texts a file has a plan for (docs/commands/plan.md
gives the official file's coverage of each split).

    python -m benchmarks.compare_plans OURS.json [--official FILE] [--dataset SOURCE]
        [--splits easy_train ...] [--variant full|classic] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path

from pydantic import BaseModel

from env.dataset import SPLITS, AnyGoal, check_split, load_dataset
from env.errors import UserError
from env.variant import Variant
from llm_agents.planning import (
    PlanLimits,
    check_plan,
    goal_instructions,
    is_known,
    load_plans,
    word_tokens,
)

DEFAULT_OFFICIAL = (
    Path(__file__).resolve().parents[1].parent / "shared" / "data" / "easy_gpt4_action_plans.json"
)


class PlanStats(BaseModel):
    """How one plans file does on one set of instruction texts."""

    instructions: int
    """Instruction texts asked about."""
    covered: int
    """Of those, texts the file has a plan for."""
    coverage: float
    """covered / instructions."""
    steps_per_plan: float
    """Mean number of steps of the covered plans."""
    max_steps: int
    """Most steps of any covered plan."""
    words_per_step: float
    """Mean words per step."""
    within_limits: float
    """Share of covered plans with steps, at most `max_steps` of them, none too long."""
    oov_rate: float
    """Share of step words that are neither Craftax names nor common words."""
    plans_with_oov: float
    """Share of covered plans with at least one such word."""
    valid: float
    """Share of covered plans that pass every check of the planner."""


def plan_stats(
    plans: dict[str, str], instructions: Sequence[str], limits: PlanLimits, variant: Variant
) -> PlanStats:
    """Measure the plans of `instructions` found in `plans`."""
    covered = [plans[text] for text in instructions if text in plans]
    checks = [check_plan(plan, limits, variant) for plan in covered]
    steps = [step for check in checks for step in check.steps]
    words = sum(len(step.split()) for step in steps)
    tokens = [token for step in steps for token in word_tokens(step)]
    unknown = sum(not is_known(token, variant) for token in tokens)
    limit_kinds = {"no_steps", "too_many_steps", "step_too_long"}

    def share(count: int) -> float:
        return count / len(checks) if checks else 0.0

    return PlanStats(
        instructions=len(instructions),
        covered=len(covered),
        coverage=len(covered) / len(instructions) if instructions else 0.0,
        steps_per_plan=statistics.fmean(len(c.steps) for c in checks) if checks else 0.0,
        max_steps=max((len(c.steps) for c in checks), default=0),
        words_per_step=words / len(steps) if steps else 0.0,
        within_limits=share(sum(not {i.kind for i in c.issues} & limit_kinds for c in checks)),
        oov_rate=unknown / len(tokens) if tokens else 0.0,
        plans_with_oov=share(sum(bool(c.unknown) for c in checks)),
        valid=share(sum(c.ok for c in checks)),
    )


def _format(value: float | int) -> str:
    return str(value) if isinstance(value, int) else f"{value:.3f}"


def side_by_side(columns: dict[str, PlanStats]) -> str:
    """A text table: one row per statistic, one column per file."""
    names = list(PlanStats.model_fields)
    header = ["", *columns]
    rows = [
        [name, *(_format(getattr(stats, name)) for stats in columns.values())] for name in names
    ]
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    lines = [
        "  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True))
        for row in [header, *rows]
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ours", type=Path, help="the plans file to compare")
    parser.add_argument(
        "--official", type=Path, default=DEFAULT_OFFICIAL, help="the reference plans file"
    )
    parser.add_argument(
        "--dataset", default=None, help="dataset source (see env.dataset.load_dataset)"
    )
    parser.add_argument(
        "--splits", nargs="+", default=None, help="splits to measure (default: all the dataset has)"
    )
    parser.add_argument("--variant", default=Variant.FULL.value, choices=[v.value for v in Variant])
    parser.add_argument("--max-steps", type=int, default=PlanLimits().max_steps)
    parser.add_argument("--max-step-words", type=int, default=PlanLimits().max_step_words)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    try:
        limits = PlanLimits(max_steps=args.max_steps, max_step_words=args.max_step_words)
        variant = Variant(args.variant)
        dataset = load_dataset(args.dataset)
        files = {"ours": load_plans(args.ours), "official": load_plans(args.official)}
        names = args.splits or [split for split in SPLITS if dataset.has_split(split)]
        splits = [check_split(name) for name in names]
        by_split: dict[str, list[AnyGoal]] = {split: dataset.split(split) for split in splits}
    except UserError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    report: dict[str, dict[str, PlanStats]] = {}
    for scope in [*splits, "all"]:
        goals = (
            [g for split in splits for g in by_split[split]] if scope == "all" else by_split[scope]
        )
        texts = goal_instructions(goals)
        report[scope] = {
            name: plan_stats(plans, texts, limits, variant) for name, plans in files.items()
        }
        print(f"\n== {scope} ({len(texts)} instruction texts)")
        print(side_by_side(report[scope]))
    print(f"\nours: {args.ours}\nofficial: {args.official}\ndataset: {dataset.source.path}")
    if args.json:
        data = {
            scope: {n: s.model_dump() for n, s in cols.items()} for scope, cols in report.items()
        }
        args.json.write_text(json.dumps(data, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
