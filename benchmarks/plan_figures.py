"""Helpers for the plan-score figures.

`expert`: write the expert's own plans as a plans file (each text's goal planned by the expert's
planner, `skill_demos.planned_skills`, in the catalogue's words), the ceiling a plan can reach
by execution; goals no skill sequence expresses are left out and counted.

`table`: print the per-split table of one or more `plan-score` folders (first and best
candidate, clustered by goal; steps read and unread), Markdown.

    python -m benchmarks.plan_figures expert DATASET.json OUT.json [--splits easy_train ...]
        [--variant classic]
    python -m benchmarks.plan_figures table LABEL=DIR [LABEL=DIR ...]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

from env.dataset import load_dataset
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
    shown = commands.add_parser("table")
    shown.add_argument("entries", nargs="+")
    args = parser.parse_args()
    if args.command == "expert":
        plans, missing = expert_plans(args.dataset, args.splits, Variant(args.variant))
        args.out.write_text(json.dumps(plans, indent=2, ensure_ascii=False) + "\n")
        print(f"wrote {len(plans)} texts' plans to {args.out}; goals without one: {dict(missing)}")
    else:
        print(table(args.entries))


if __name__ == "__main__":
    main()
