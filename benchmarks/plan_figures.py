"""Helpers for the plan-score figures.

`expert`: write the expert's own plans as a plans file (each text's goal planned by the expert's
planner, `skill_demos.planned_skills`, in the catalogue's words), the ceiling a plan can reach
by execution; goals no skill sequence expresses are left out and counted.

`one-text`: write a dataset of one text per goal, the texts a before/after comparison plans
for: each goal's instruction, except in the paraphrased splits, whose goals share their
instruction with train goals and are new only in their paraphrases: there, the first paraphrase.

`restrict`: write the plans of a plans file for the texts of a dataset only (another source's
plans for the same texts).

`table`: print the per-split table of one or more `plan-score` folders (first and best
candidate, clustered by goal; steps read and unread), Markdown.

    python -m benchmarks.plan_figures expert DATASET.json OUT.json [--splits easy_train ...]
        [--variant classic]
    python -m benchmarks.plan_figures one-text DATASET.json OUT.json
    python -m benchmarks.plan_figures restrict PLANS.json DATASET.json OUT.json
    python -m benchmarks.plan_figures table LABEL=DIR [LABEL=DIR ...]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

from env.dataset import load_dataset
from env.goals import Dataset
from env.variant import Variant
from llm_agents.agents.skills.catalogue import skill_offer
from llm_agents.agents.skills.demos import planned_skills
from llm_agents.run_data.readings import reading_of


def expert_plans(
    dataset: str, splits: list[str], variant: Variant
) -> tuple[dict[str, str], Counter[str]]:
    plans: dict[str, str] = {}
    missing: Counter[str] = Counter()
    for goal in load_dataset(dataset).goals:
        if splits and goal.split not in splits:
            continue
        skills = planned_skills(reading_of(goal), skill_offer(variant, goal.difficulty))
        if skills is None:
            missing[goal.split] += 1
            continue
        plan = "\n".join(f"{i}. {skill}" for i, skill in enumerate(skills, 1))
        plans.update(dict.fromkeys(goal.texts, plan))
    return plans, missing


def one_text_per_goal(dataset: str) -> Dataset:
    """Each goal with one text: its instruction, or in a paraphrased split its first paraphrase."""
    source = load_dataset(dataset)
    goals = []
    for goal in source.goals:
        paraphrased = goal.split.endswith("_paraphrased") and goal.paraphrases
        text = goal.paraphrases[0] if paraphrased else goal.instruction
        goals.append(goal.model_copy(update={"instruction": text, "paraphrases": ()}))
    return Dataset(source=source.source, goals=tuple(goals))


def restricted(plans: dict[str, object], dataset: str) -> dict[str, object]:
    texts = {text for goal in load_dataset(dataset).goals for text in goal.texts}
    return {text: plan for text, plan in plans.items() if text in texts}


def _cell(rate: dict[str, float]) -> str:
    return f"{rate['rate']:.2f} [{rate['low']:.2f}, {rate['high']:.2f}]"


def table(entries: list[str]) -> str:
    lines = [
        "| plans | split | texts | plans scored | first candidate | best candidate | steps read / unread |",
        "|---|---|---|---|---|---|---|",
    ]
    for entry in entries:
        label, _, folder = entry.partition("=")
        scores = json.loads((Path(folder) / "scores.json").read_text())
        for split, row in scores["splits"].items():
            lines.append(
                f"| {label} | {split} | {row['texts']} | {row['plans']} | {_cell(row['first'])} "
                f"| {_cell(row['best'])} | {row['steps_read']} / {row['steps_unread']} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    expert = commands.add_parser("expert")
    expert.add_argument("dataset")
    expert.add_argument("out", type=Path)
    expert.add_argument("--splits", nargs="*", default=[])
    expert.add_argument("--variant", default="classic")
    one = commands.add_parser("one-text")
    one.add_argument("dataset")
    one.add_argument("out", type=Path)
    only = commands.add_parser("restrict")
    only.add_argument("plans", type=Path)
    only.add_argument("dataset")
    only.add_argument("out", type=Path)
    shown = commands.add_parser("table")
    shown.add_argument("entries", nargs="+")
    args = parser.parse_args()
    if args.command == "expert":
        plans, missing = expert_plans(args.dataset, args.splits, Variant(args.variant))
        args.out.write_text(json.dumps(plans, indent=2, ensure_ascii=False) + "\n")
        print(f"wrote {len(plans)} texts' plans to {args.out}; goals without one: {dict(missing)}")
    elif args.command == "one-text":
        written = one_text_per_goal(args.dataset)
        written.save_json(args.out)
        print(f"wrote {len(written.goals)} goals, one text each, to {args.out}")
    elif args.command == "restrict":
        kept = restricted(json.loads(args.plans.read_text(encoding="utf-8")), args.dataset)
        args.out.write_text(json.dumps(kept, indent=2, ensure_ascii=False) + "\n")
        print(f"wrote the plans of {len(kept)} texts to {args.out}")
    else:
        print(table(args.entries))


if __name__ == "__main__":
    main()
