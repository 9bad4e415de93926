"""`--choice loglik` under each scoring rule (`--choice-scoring`), side by side, on CPU.

The zero-shot agent plays the same episodes (Classic, the first `--limit` goals of each
category, original instructions, one world each) under each rule of `--play`: success with its
95% interval clustered by goal (`clustered_rate`; one world per goal, so it equals the plain
Wilson interval here), the commonest action's share of the steps, and each run's wall and CPU
seconds (its process's, model loading included). Every step of every run of a rule that scores
names is also scored under every other such rule from the same log-probabilities (one scoring
pass gives them all), so each rule's commonest action is also measured on the very states the
played rule reached ("on the same states"), at no extra model cost: the bias of a rule shows
there even where there was no time to play it. `letters` asks another question (a letter of a
list shuffled per step), so its runs are played, not scored on the others' states.

    python benchmarks/bench_choice_scoring.py [--model hf:/path/to/qwen2.5-coder-0.5b]
        [--play sum mean bytes pmi letters] [--categories one new_objects] [--limit 8]
        [--max-steps 250] [--dataset PATH] [--out runs/bench-choice-scoring]

Runs resume: a rerun with the same settings plays only what is missing, then prints; an
interrupted run (Ctrl-C) prints what it played, "(N st)" being the most steps an episode got,
its unfinished episodes counted as not successful. Choose a default on the training categories
(`one`, `combo`) only; `new_objects` is a test split.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, get_args

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.official_clone import official_clone  # noqa: E402
from llm_agents.backends.base import (  # noqa: E402
    ChoiceScoring,
    ChoiceSet,
    Conversation,
    ModelOutput,
    ranked_choices,
    scored_choices,
)

RULES: tuple[ChoiceScoring, ...] = get_args(ChoiceScoring)
#: The rules that score the action names themselves: one scoring pass gives them all.
NAME_RULES = tuple(rule for rule in RULES if rule != "letters")
#: Each run's record of every rule's pick at every step (the run's own folder).
SHADOW_FILE = "picks_by_rule.jsonl"


def _dataset(args: argparse.Namespace, out: Path) -> list[str]:
    dataset = args.dataset or official_clone(out)
    return ["--dataset", dataset] if dataset else []


def _record_every_rule(shadow: Path) -> None:
    """Make the hf backend write, for each prompt of names it ranks, the pick of every rule
    that scores names."""
    from llm_agents.backends.hf import HFModel

    own_choose = HFModel._choose

    def choose(
        self: HFModel,
        conversations: Sequence[Conversation],
        choices: ChoiceSet,
        candidates: list[list[int]],
    ) -> list[ModelOutput]:
        if choices.scoring == "letters":
            return own_choose(self, conversations, choices, candidates)
        start = time.perf_counter()
        prompts = self._prompt_ids(conversations)
        scores = self._option_logliks(prompts, candidates)
        pmi = choices.model_copy(update={"scoring": "pmi"})
        content_free = self._content_free_rows(conversations, pmi, candidates)
        picks: dict[str, list[str]] = {}
        for rule in NAME_RULES:
            rows = scored_choices(
                choices.model_copy(update={"scoring": rule}), candidates, scores, content_free
            )
            picks[rule] = [
                choices.options[max(range(len(row)), key=row.__getitem__)] for row in rows
            ]
        with shadow.open("a", encoding="utf-8") as file:
            for index in range(len(conversations)):
                file.write(json.dumps({rule: picks[rule][index] for rule in NAME_RULES}) + "\n")
        return ranked_choices(
            choices, prompts, candidates, scores, time.perf_counter() - start, content_free
        )

    HFModel._choose = choose  # type: ignore[method-assign]


def _play(argv: list[str], shadow: Path) -> None:
    from llm_agents.cli import main

    _record_every_rule(shadow)
    code = main(argv)
    if code != 0:
        sys.exit(f"craftext-llm eval failed (exit {code})")


def _rate(outcomes: Sequence[tuple[str, bool]]) -> str:
    """Successes of (goal, success) episodes, with the 95% interval clustered by goal."""
    from llm_agents.run_data.metrics import clustered_rate

    rate = clustered_rate((goal, int(success), 1) for goal, success in outcomes)
    return f"{rate.successes}/{rate.episodes} = {rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}]"


def _commonest(actions: Counter[str]) -> str:
    if not actions:
        return "-"
    name, count = actions.most_common(1)[0]
    return f"{name} {count / sum(actions.values()):.2f}"


def _children_cpu_s() -> float:
    """CPU seconds (user and system) of the finished child processes so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="hf:smollm2-135m", help="an hf: model spec")
    parser.add_argument("--play", nargs="+", choices=RULES, default=list(RULES))
    parser.add_argument("--categories", nargs="+", default=["one", "new_objects"])
    parser.add_argument("--limit", type=int, default=8)
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dataset")
    parser.add_argument("--out", default=str(REPO / "runs" / "bench-choice-scoring"))
    parser.add_argument("--only-print", action="store_true", help="print what was played")
    parser.add_argument("--run-one", nargs=2, metavar=("RULE", "CATEGORY"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def run_dir(rule: str, category: str) -> Path:
        return out / f"{rule}-{category}-{args.limit}x{args.max_steps}"

    def played_dir(rule: str, category: str) -> Path:
        """The run of `rule` on `category`: this step cap's, else another's (--only-print)."""
        own = run_dir(rule, category)
        if own.exists() or not args.only_print:
            return own
        return next(iter(sorted(out.glob(f"{rule}-{category}-{args.limit}x*"))), own)

    if args.run_one:
        rule, category = args.run_one
        target = run_dir(rule, category)
        argv = [
            "eval", "--agent", "zero-shot", "--model", args.model, "--choice", "loglik",
            "--choice-scoring", rule, "--variant", "classic", "--categories", category,
            "--no-paraphrases", "--max-steps", str(args.max_steps), "--limit", str(args.limit),
            "--batch-size", str(args.limit), "--backend-option", f"threads={args.threads}",
            "--output-dir", str(target), "--no-progress", *_dataset(args, out),
        ]  # fmt: skip
        _play(argv, target / SHADOW_FILE)
        return

    import subprocess

    from llm_agents.run_data.store import read_episodes, read_steps

    for rule in args.play:
        for category in args.categories:
            target = run_dir(rule, category)
            done = (target / "results.json").exists() and json.loads(
                (target / "results.json").read_text()
            ).get("status") == "complete"
            if args.only_print or done:
                continue
            # A process per run: the backend's recording hook and the model stay in one run.
            # A resumed run appends to the record; only a fresh one starts it anew.
            if not (target / "results.json").exists():
                (target / SHADOW_FILE).unlink(missing_ok=True)
            started = time.perf_counter()
            cpu = _children_cpu_s()
            subprocess.run(
                [sys.executable, __file__, *sys.argv[1:], "--run-one", rule, category], check=True
            )
            print(
                f"played {rule} on {category} in {time.perf_counter() - started:.0f} s wall, "
                f"{_children_cpu_s() - cpu:.0f} s CPU"
            )

    print(
        f"zero-shot --choice loglik, {args.model}, Classic, first {args.limit} goals of each "
        f"category, {'steps as played' if args.only_print else f'{args.max_steps} steps'}"
    )
    header = "  ".join(f"{c:>32}" for c in args.categories)
    print(f"{'played rule':<12}{header}  {'all':>26}  commonest action (played)")
    for rule in args.play:
        cells, played = [], Counter[str]()
        outcomes: list[tuple[str, bool]] = []
        for category in args.categories:
            target = played_dir(rule, category)
            if not (target / "steps.jsonl").exists():
                cells.append("-")
                continue
            steps = list(read_steps(target / "steps.jsonl"))
            played.update(step.action_name for step in steps)
            # An interrupted run counts its unfinished episodes as not (yet) successful.
            won = {e.episode_id for e in read_episodes(target / "episodes.jsonl") if e.success}
            # An episode id is `category/goal/variant/episode`: its goal is the cluster.
            goals = {step.episode_id: "/".join(step.episode_id.split("/")[:2]) for step in steps}
            mine = [(goal, episode in won) for episode, goal in goals.items()]
            outcomes += mine
            deepest = 1 + max(step.step for step in steps)
            cells.append(f"{_rate(mine)} ({deepest} st)")
        total = _rate(outcomes) if outcomes else "-"
        row = "  ".join(f"{c:>32}" for c in cells)
        print(f"{rule:<12}{row}  {total:>26}  {_commonest(played)}")

    print("\nOn the same states (each rule's pick at every step the played rules reached):")
    print(f"{'rule':<8}" + "".join(f"{c:>66}" for c in args.categories))
    records: dict[str, list[dict[str, Any]]] = {}
    for category in args.categories:
        records[category] = []
        for rule in args.play:
            shadow = played_dir(rule, category) / SHADOW_FILE
            if shadow.exists():
                records[category] += [json.loads(line) for line in shadow.open()]
    for rule in NAME_RULES:
        cells = []
        for category in args.categories:
            picks = Counter(record[rule] for record in records[category])
            top = ", ".join(f"{n} {c / max(1, picks.total()):.2f}" for n, c in picks.most_common(3))
            cells.append(f"{top} (n={picks.total()})" if picks else "-")
        print(f"{rule:<8}" + "".join(f"{c:>66}" for c in cells))


if __name__ == "__main__":
    main()
