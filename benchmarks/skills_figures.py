"""Skills-agent runs side by side: success with its clustered interval, invalid answers, and
what went wrong (`judging.skill_errors`), for each run and on the episodes every run played.

Runs cut short (the CPU runs of issue 47 play a few of their episodes in a session) are
compared on their common episodes, where the same worlds and texts were played; each run's own
figures say how many of its scheduled episodes it played.

    python benchmarks/skills_figures.py RUN_DIR [RUN_DIR ...] [--dataset PATH]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from env.dataset import load_dataset
from env.goals import AnyGoal, run_category
from env.variant import Variant
from llm_agents.judging.skill_errors import SKILL_ERROR_TITLES, skill_error_table
from llm_agents.run_data.metrics import clustered_rate
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import read_episodes


def _rate(episodes: Sequence[EpisodeRecord]) -> str:
    if not episodes:
        return "-"
    rate = clustered_rate((e.goal_id, int(e.success), 1) for e in episodes)
    return f"{rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}] {rate.successes}/{rate.episodes}"


def _decisions(episodes: Sequence[EpisodeRecord]) -> tuple[int, int]:
    records = [r for e in episodes for r in e.skills or []]
    return sum(r.outcome == "invalid" for r in records), len(records)


def describe(
    name: str,
    episodes: Sequence[EpisodeRecord],
    goals: dict[tuple[str, str], AnyGoal],
    scheduled: int | None,
) -> list[str]:
    played = f"{len(episodes)} of {scheduled}" if scheduled else str(len(episodes))
    invalid, decisions = _decisions(episodes)
    lines = [f"{name}: {played} episodes played", f"  success overall: {_rate(episodes)}"]
    for category in ("one", "combo", "new_objects"):
        some = [e for e in episodes if e.category == category]
        if some:
            lines.append(f"  success {category}: {_rate(some)}")
    lines.append(
        f"  decisions: {decisions}, invalid answers: {invalid}"
        + (f" ({invalid / decisions:.2f})" if decisions else "")
        + f"; model calls per episode: {decisions / max(len(episodes), 1):.1f}"
    )
    table = skill_error_table(episodes, goals, Variant.CLASSIC, "easy")
    failed = sum(table.values())
    lines.append(f"  what went wrong ({failed} failed):")
    lines += [
        f"    {label:<22} {count:>3}  {SKILL_ERROR_TITLES[label]}"
        for label, count in table.items()
        if count
    ]
    skills = Counter(r.label for e in episodes for r in e.skills or [])
    lines.append(
        "  skills chosen: " + ", ".join(f"{label} {n}" for label, n in skills.most_common(6))
    )
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--dataset", default=None)
    args = parser.parse_args(argv)
    instructions = load_dataset(args.dataset).instructions(
        ("one", "combo", "new_objects"), include_paraphrases=False, difficulty="easy"
    )
    goals: dict[tuple[str, str], AnyGoal] = {
        (run_category(i.goal), i.goal.id): i.goal for i in instructions
    }
    runs: dict[str, list[EpisodeRecord]] = {}
    for run in args.runs:
        episodes = read_episodes(run / "episodes.jsonl")
        results = json.loads((run / "results.json").read_text())
        runs[run.name] = episodes
        print("\n".join(describe(run.name, episodes, goals, results.get("scheduled"))))
        print()
    common = set.intersection(*({e.episode_id for e in eps} for eps in runs.values()))
    print(f"On the {len(common)} episodes every run played:")
    for name, episodes in runs.items():
        shared = [e for e in episodes if e.episode_id in common]
        invalid, decisions = _decisions(shared)
        print(f"  {name:<24} success {_rate(shared)}; invalid answers {invalid}/{decisions}")


if __name__ == "__main__":
    main()
