"""Success of the scripted expert (`--agent expert`, no model) per category and per goal.

Real runs of the CrafText env (Classic by default, 250 steps): every goal of the chosen
categories, original instruction only (the expert never reads the text), `--episodes` worlds
each. Prints the success rate per category, per goal, and for every failed episode why it ended
(death or timeout) with the task the expert was on at its last step.

    python benchmarks/bench_expert.py [--dataset PATH] [--categories one combo new_objects]
        [--episodes 2] [--variant classic] [--max-steps 250] [--batch-size 32]

`--dataset` takes what `load_dataset` takes, or the reference conversion of the official
repository's EASY splits (`../shared/data/craftext_official_easy.json`, the default when it
exists: it has the 57-goal train split with the `one` goals), converted here to a dataset JSON in
a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

from env.dataset import CATEGORIES, Dataset, DatasetSource, Goal, category_of
from llm_agents.agents import NoModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.store import EPISODES_FILE, STEPS_FILE, read_episodes, read_steps

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "craftext_official_easy.json"


def convert_reference(path: Path, out_dir: Path) -> Path:
    """The reference JSON (`splits` -> goals) as a dataset JSON `load_dataset` reads."""
    data = json.loads(path.read_text(encoding="utf-8"))
    goals = []
    for split, records in data["splits"].items():
        for record in records:
            goals.append(
                Goal(
                    id=record["id"],
                    split=split,
                    category=category_of(split, record["required"], record["forbidden"]),
                    instruction=record["instruction"],
                    paraphrases=tuple(record["paraphrases"]),
                    required=tuple(record["required"]),
                    forbidden=tuple(record["forbidden"]),
                )
            )
    dataset = Dataset(source=DatasetSource(kind="json", path=str(path)), goals=tuple(goals))
    return dataset.save_json(out_dir / "dataset.json")


def last_notes(steps_path: Path) -> dict[str, str]:
    """Each episode's last step's note (the expert's task then)."""
    return {step.episode_id: step.reasoning or "" for step in read_steps(steps_path)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", help="dataset source (default: the reference JSON)")
    parser.add_argument("--categories", nargs="+", default=["one", "combo", "new_objects"])
    parser.add_argument("--episodes", type=int, default=2, help="worlds per goal")
    parser.add_argument("--variant", default="classic", choices=["full", "classic"])
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--goals", nargs="*", help="only these goal ids")
    parser.add_argument("--output-dir", help="keep the run here (default: a temporary folder)")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        dataset = args.dataset
        if dataset is None and REFERENCE.is_file():
            dataset = str(convert_reference(REFERENCE, workdir))
        if args.goals:
            from env.dataset import load_dataset

            full = load_dataset(dataset)
            keep = tuple(g for g in full.goals if g.id in set(args.goals))
            dataset = str(Dataset(source=full.source, goals=keep).save_json(workdir / "some.json"))
        out = Path(args.output_dir) if args.output_dir else workdir / "run"
        config = build_config(
            {
                "agent": "expert",
                "variant": args.variant,
                "categories": args.categories,
                "dataset": dataset,
                "paraphrases": False,
                "episodes_per_instruction": args.episodes,
                "max_steps": args.max_steps,
                "batch_size": args.batch_size,
                "seed": args.seed,
                "output_dir": str(out),
            }
        )
        start = time.perf_counter()
        run_eval(config, NoModel())
        elapsed = time.perf_counter() - start
        episodes = read_episodes(out / EPISODES_FILE)
        notes = last_notes(out / STEPS_FILE)
        from env.dataset import load_dataset

        goals = {goal.id: goal for goal in load_dataset(dataset).select(CATEGORIES)}

    by_category: dict[str, list[bool]] = defaultdict(list)
    by_goal: dict[tuple[str, str], list[bool]] = defaultdict(list)
    for episode in episodes:
        by_category[episode.category].append(episode.success)
        by_goal[(episode.category, episode.goal_id)].append(episode.success)
    steps = sum(e.steps for e in episodes)
    print(
        f"expert, {args.variant}, {args.max_steps} steps, {args.episodes} worlds per goal: "
        f"{len(episodes)} episodes, {steps} steps in {elapsed:.0f} s"
    )
    for category in args.categories:
        results = by_category.get(category, [])
        if results:
            print(
                f"  {category:12s} {sum(results) / len(results):.2f} ({sum(results)}/{len(results)})"
            )
    pooled = by_category.get("combo", []) + by_category.get("new_objects", [])
    if pooled:
        print(f"  combo+new_objects {sum(pooled) / len(pooled):.2f} ({sum(pooled)}/{len(pooled)})")
    print("\nper goal (worst first):")
    for (category, goal), results in sorted(
        by_goal.items(), key=lambda kv: sum(kv[1]) / len(kv[1])
    ):
        print(f"  {sum(results)}/{len(results)} {category:11s} {goal}")
    print("\nfailed episodes: termination, last task")
    reasons: Counter[str] = Counter()
    missing_counts: Counter[str] = Counter()
    for episode in episodes:
        if not episode.success:
            note = notes.get(episode.episode_id, "")
            reasons[f"{episode.termination}: {note}"] += 1
            required = goals[episode.goal_id].required if episode.goal_id in goals else ()
            missing = sorted(set(required) - set(episode.achievements))
            missing_counts.update(missing)
            print(
                f"  {episode.goal_id} ({episode.termination} at {episode.steps}): {note}; "
                f"missing {', '.join(missing)}"
            )
    print("\nfailure reasons (termination: the task at the last step):")
    for reason, count in reasons.most_common():
        print(f"  {count:3d} {reason}")
    print("\nrequired achievements missing in failed episodes:")
    for name, count in missing_counts.most_common():
        print(f"  {count:3d} {name}")


if __name__ == "__main__":
    main()
