"""Success of the scripted expert (`--agent expert`, no model) per goal set and per goal.

Real runs of the CrafText env (Classic by default, 250 steps): every goal of the chosen goal
sets, original instruction only (the expert never reads the text), `--episodes` worlds each.

EASY (the default) prints the success rate per category (one, combo, new_objects), per goal, and
for every failed episode why it ended (death or timeout) with the task the expert was on at its
last step. `--difficulty medium` plays the Medium splits (Train / Paraphrased / New objects) and
prints the paper's Table 2 layout, scenario class (Conditional, Build, Localization,
Achievements) x split with totals per split, beside the paper's published Medium totals.

    python benchmarks/bench_expert.py [--difficulty easy|medium] [--dataset PATH]
        [--categories one combo new_objects] [--episodes 2] [--variant classic]
        [--max-steps 250] [--batch-size 32] [--goals ID ...]

`--dataset` takes what `load_dataset` takes. EASY's default is the reference conversion of the
official repository's EASY splits (`../shared/data/craftext_official_easy.json`: it has the
57-goal train split with the `one` goals), converted here to a dataset JSON in a temporary
folder; Medium's is the official repository's zip (`../shared/data/craftext_official_1c518ae.zip`),
unpacked into a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import zipfile
from collections import Counter, defaultdict
from pathlib import Path

from env.dataset import Dataset, DatasetSource, Goal, category_of, load_dataset
from env.goals import DIFFICULTY_CATEGORIES, AnyGoal, Category, Difficulty, run_category
from llm_agents.agents import NoModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.judging.published import PUBLISHED_MEDIUM, SCENARIO_ROWS
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import EPISODES_FILE, STEPS_FILE, read_episodes, read_steps

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
REFERENCE = SHARED / "craftext_official_easy.json"
OFFICIAL_ZIP = SHARED / "craftext_official_1c518ae.zip"
#: The paper's Table 2 column names.
SPLIT_LABELS = {"train": "Train", "paraphrased": "Paraphrased", "new_objects": "New objects"}
DEFAULT_CATEGORIES: dict[Difficulty, tuple[Category, ...]] = {
    "easy": ("one", "combo", "new_objects"),
    "medium": DIFFICULTY_CATEGORIES["medium"],
    "hard": DIFFICULTY_CATEGORIES["hard"],
}


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


def unpack_official(archive: Path, out_dir: Path) -> Path:
    """The official repository's zip unpacked: the directory `load_dataset` reads."""
    target = out_dir / "official"
    with zipfile.ZipFile(archive) as opened:
        opened.extractall(target)
    (root,) = target.iterdir()
    return root


def default_dataset(difficulty: Difficulty, workdir: Path) -> str | None:
    """The reference data this script plays when no `--dataset` is given (None: the loader's)."""
    if difficulty == "easy" and REFERENCE.is_file():
        return str(convert_reference(REFERENCE, workdir))
    if difficulty != "easy" and OFFICIAL_ZIP.is_file():
        return str(unpack_official(OFFICIAL_ZIP, workdir))
    return None


def last_notes(steps_path: Path) -> dict[str, str]:
    """Each episode's last step's note (the expert's task then)."""
    return {step.episode_id: step.reasoning or "" for step in read_steps(steps_path)}


def _rate(results: list[bool]) -> str:
    if not results:
        return "    -     "
    return f"{sum(results) / len(results):.2f} {sum(results):>2d}/{len(results):<3d}"


def print_easy(episodes: list[EpisodeRecord], categories: list[str]) -> None:
    by_category: dict[str, list[bool]] = defaultdict(list)
    for episode in episodes:
        by_category[episode.category].append(episode.success)
    for category in categories:
        results = by_category.get(category, [])
        if results:
            print(
                f"  {category:12s} {sum(results) / len(results):.2f} ({sum(results)}/{len(results)})"
            )
    pooled = by_category.get("combo", []) + by_category.get("new_objects", [])
    if pooled:
        print(f"  combo+new_objects {sum(pooled) / len(pooled):.2f} ({sum(pooled)}/{len(pooled)})")


def print_table2(episodes: list[EpisodeRecord], categories: list[str]) -> None:
    """Scenario class x split, totals per split, then the paper's published totals."""
    cells: dict[tuple[str, str], list[bool]] = defaultdict(list)
    for episode in episodes:
        cells[(episode.scenario_class, episode.category)].append(episode.success)
        cells[("Total", episode.category)].append(episode.success)
    labels = [SPLIT_LABELS.get(c, c) for c in categories]
    print(f"  {'':14s}" + "".join(f"{label:>14s}" for label in labels))
    for row in (*SCENARIO_ROWS, "Total"):
        print(
            f"  {row:14s}" + "".join(f"{_rate(cells.get((row, c), [])):>14s}" for c in categories)
        )
    print("\n  published Medium totals (the paper's Table 2, trained agents, 50 worlds each):")
    for published in PUBLISHED_MEDIUM:
        rates = [published.rate(c) for c in categories]
        print(
            f"  {published.model:14s}"
            + "".join(f"{'-' if r is None else f'{r:.2f}':>14s}" for r in rates)
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", default="easy", choices=["easy", "medium", "hard"])
    parser.add_argument("--dataset", help="dataset source (default: the reference data)")
    parser.add_argument("--categories", nargs="+", help="goal sets (default: all of the paper's)")
    parser.add_argument("--episodes", type=int, default=2, help="worlds per goal")
    parser.add_argument("--variant", help="classic or full (default: classic, full for hard)")
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--goals", nargs="*", help="only these goal ids")
    parser.add_argument("--output-dir", help="keep the run here (default: a temporary folder)")
    args = parser.parse_args()
    difficulty: Difficulty = args.difficulty
    categories = list(args.categories or DEFAULT_CATEGORIES[difficulty])
    variant = args.variant or ("full" if difficulty == "hard" else "classic")

    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        dataset = args.dataset or default_dataset(difficulty, workdir)
        full = load_dataset(dataset)
        if args.goals:
            keep = tuple(g for g in full.goals if g.id in set(args.goals))
            full = Dataset(source=full.source, goals=keep)
            dataset = str(full.save_json(workdir / "some.json"))
        out = Path(args.output_dir) if args.output_dir else workdir / "run"
        config = build_config(
            {
                "agent": "expert",
                "variant": variant,
                "difficulty": difficulty,
                "categories": categories,
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
        goals: dict[tuple[str, str], AnyGoal] = {
            (run_category(goal), goal.id): goal
            for goal in full.select_goals(categories, difficulty)
        }

    steps = sum(e.steps for e in episodes)
    print(
        f"expert, {difficulty}, {variant}, {args.max_steps} steps, {args.episodes} worlds per goal: "
        f"{len(episodes)} episodes, {steps} steps in {elapsed:.0f} s"
    )
    if difficulty == "easy":
        print_easy(episodes, categories)
    else:
        print_table2(episodes, categories)
    by_goal: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    for episode in episodes:
        by_goal[(episode.category, episode.scenario_class, episode.goal_id)].append(episode.success)
    print("\nper goal (worst first):")
    for (category, scenario, goal), results in sorted(
        by_goal.items(), key=lambda kv: sum(kv[1]) / len(kv[1])
    ):
        print(f"  {sum(results)}/{len(results)} {category:11s} {scenario:12s} {goal}")
    print("\nfailed episodes: termination, last task")
    reasons: Counter[str] = Counter()
    missing_counts: Counter[str] = Counter()
    for episode in episodes:
        if episode.success:
            continue
        note = notes.get(episode.episode_id, "")
        reasons[f"{episode.termination}: {note}"] += 1
        record = goals.get((episode.category, episode.goal_id))
        required = record.required if isinstance(record, Goal) else ()
        missing = sorted(set(required) - set(episode.achievements))
        missing_counts.update(missing)
        detail = f"; missing {', '.join(missing)}" if missing else ""
        print(f"  {episode.goal_id} ({episode.termination} at {episode.steps}): {note}{detail}")
    print("\nfailure reasons (termination: the task at the last step):")
    for reason, count in reasons.most_common():
        print(f"  {count:3d} {reason}")
    if missing_counts:
        print("\nrequired achievements missing in failed episodes:")
        for name, count in missing_counts.most_common():
            print(f"  {count:3d} {name}")


if __name__ == "__main__":
    main()
