"""Understanding vs acting on the EASY splits, on this machine's CPU, in one run.

1. `craftext-llm ground` for each model: exact-match rate and per-field recall by category,
   invalid answers, seconds per instruction text.
2. The same episodes (Classic, `--max-steps`, one world per instruction text) played by the
   `expert` (oracle goals), the `guided` agent (the model's reading, played by the expert) and the
   `zero-shot` agent (`--choice loglik`), with the model (and number of worked examples) that
   read best; guided success is also split by whether the model read the goal right.

`--grounding-shots` grounds each model with each number of worked examples (training goals'
instructions answered, never the goal being read), so their effect is printed side by side.

    python benchmarks/bench_ground.py [--models hf:smollm2-135m hf:/path/to/qwen2.5-coder-0.5b]
        [--categories one combo paraphrased new_objects] [--no-paraphrases]
        [--play-categories one combo new_objects] [--play-limit 30] [--max-steps 250]
        [--agents expert guided zero-shot] [--grounding-shots 0 4]
        [--max-tokens 64] [--no-play]
        [--dataset PATH] [--out runs/bench-ground]

The dataset defaults to the official repository at 1c518ae when `../shared/data` holds its
archive (unpacked into the output folder), else the CLI's default. Runs resume: a rerun with the
same settings only prints.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.official_clone import official_clone  # noqa: E402

PLAYERS = ("expert", "guided", "zero-shot")


def _dataset(args: argparse.Namespace, out: Path) -> list[str]:
    dataset = args.dataset or official_clone(out)
    return ["--dataset", dataset] if dataset else []


def _cli(*argv: str) -> float:
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "llm_agents.cli", *argv], cwd=REPO, capture_output=True, text=True
    )
    if done.returncode != 0:
        sys.exit(f"craftext-llm {' '.join(argv[:3])} failed:\n{done.stderr[-3000:]}")
    return time.perf_counter() - started


def _label(model: str) -> str:
    """The model's name without its backend or folders (`hf:smollm2-135m` -> `smollm2-135m`)."""
    return model.split(":", 1)[-1].rsplit("/", 1)[-1]


def _rate(episodes: list[Any]) -> str:
    """Success rate with its 95% Wilson interval clustered by goal (the play samples are small,
    and a goal's texts are not independent)."""
    from llm_agents.run_data.metrics import clustered_rate, goal_cluster

    return clustered_rate((goal_cluster(e), int(e.success), 1) for e in episodes).cell()


def _interval(rate: Any) -> str:
    return "-" if rate is None else f"[{rate.low:.2f}, {rate.high:.2f}]"


@dataclass(frozen=True)
class Reader:
    """A model grounding with a number of worked examples."""

    model: str
    shots: int

    @property
    def label(self) -> str:
        return _label(self.model) + (f" {self.shots}-shot" if self.shots else "")

    @property
    def slug(self) -> str:
        return _label(self.model) + (f"-{self.shots}shot" if self.shots else "")

    @property
    def flags(self) -> list[str]:
        return ["--grounding-shots", str(self.shots)] if self.shots else []


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["hf:smollm2-135m"])
    parser.add_argument(
        "--categories", nargs="+", default=["one", "combo", "paraphrased", "new_objects"]
    )
    parser.add_argument("--no-paraphrases", action="store_true")
    parser.add_argument("--play-categories", nargs="+", default=["one", "combo", "new_objects"])
    parser.add_argument(
        "--play-limit", type=int, default=30, help="episodes per agent and play category"
    )
    parser.add_argument(
        "--agents",
        nargs="+",
        default=list(PLAYERS),
        choices=PLAYERS,
        help="the agents that play (zero-shot costs a model call per step)",
    )
    parser.add_argument("--no-play", action="store_true", help="grounding figures only")
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument(
        "--max-tokens", type=int, default=64, help="per grounding answer (a goal is ~30 tokens)"
    )
    parser.add_argument(
        "--grounding-shots", nargs="+", type=int, default=[0], help="worked examples, per model"
    )
    parser.add_argument("--dataset")
    parser.add_argument("--out", default=str(REPO / "runs" / "bench-ground"))
    args = parser.parse_args()

    from llm_agents.evaluation.grounding_run import read_ground_results, read_groundings
    from llm_agents.run_data.metrics import CLUSTERED_LABEL, understanding
    from llm_agents.run_data.store import read_episodes

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    common = _dataset(args, out)
    paraphrases = ["--no-paraphrases"] if args.no_paraphrases else []
    # Guided asks for the same groundings as `ground` (same prompt and generation settings):
    # answered once, from the shared response cache the second time.
    common += ["--cache", str(out / "answers.sqlite")]

    grounded = {}
    cached = {}
    for model in args.models:
        for shots in args.grounding_shots:
            reader = Reader(model, shots)
            run_dir = out / f"ground-{reader.slug}"
            _cli(
                "ground", "--model", model, "--categories", *args.categories, *paraphrases,
                "--variant", "classic", "--output-dir", str(run_dir), "--no-progress",
                "--max-tokens", str(args.max_tokens), *reader.flags, *common,
            )  # fmt: skip
            grounded[reader] = read_ground_results(run_dir / "results.json")
            cached[reader] = sum(record.cached for record in read_groundings(run_dir))

    print(f"\nGrounding (EASY, {'originals only' if paraphrases else 'every text'}, CPU):")
    header = (
        f"{'model':<28} {'set':<12} {'texts':>5} {'g':>4} {'exact':>6} {'[interval]':>12} "
        f"{'req R':>6} {'forb R':>6} {'invalid':>7}"
    )
    print(header)
    for model, results in grounded.items():
        assert results.summary is not None, f"{model.label}: no answers"
        rows = {"all": results.summary.overall, **results.summary.by_category}
        for name, score in rows.items():
            recall = {f: s.recall.rate if s.recall else None for f, s in score.fields.items()}
            req, forb = recall.get("required"), recall.get("forbidden")
            print(
                f"{model.label:<28} {name:<12} {score.texts:>5} {score.exact.clusters or '-':>4} "
                f"{score.exact.rate:>6.2f} {_interval(score.exact):>12} "
                f"{'-' if req is None else f'{req:.2f}':>6} "
                f"{'-' if forb is None else f'{forb:.2f}':>6} {score.invalid:>7}"
            )
        pace = results.seconds_per_instruction
        if cached[model]:
            measured = f"- ({cached[model]} answers came from the response cache)"
        elif pace is None:
            measured = "- (nothing left to answer: resumed)"
        else:
            measured = f"{pace:.2f}"
        print(f"{model.label:<28} seconds per instruction: {measured}")
    print(f"Intervals: {CLUSTERED_LABEL}; g = goals.")

    if args.no_play:
        return
    # The agents act with the model that read the instructions best.
    player = max(grounded, key=lambda m: grounded[m].summary.overall.exact.rate)  # type: ignore[union-attr]
    print(
        f"\nPlaying the first {args.play_limit} episodes of each of "
        f"{' '.join(args.play_categories)} (Classic, {args.max_steps} steps, one world per text; "
        f"model {player.label}):"
    )
    for agent in args.agents:
        model = (
            []
            if agent == "expert"
            else ["--model", player.model, "--max-tokens", str(args.max_tokens)]
        )
        if agent == "guided":
            model += player.flags
        if agent == "zero-shot":
            # Scored action names (as `make demo`): a small model's free text is mostly unparsable.
            model += ["--choice", "loglik"]
        episodes = []
        seconds = 0.0
        # One run per category, so `--play-limit` takes the same number from each; with
        # --no-paraphrases they are the category's first goals, one text each, as grounded.
        for category in args.play_categories:
            run_dir = (
                out
                / f"play-{agent}-{player.slug if agent == 'guided' else _label(player.model)}-{category}"
            )
            seconds += _cli(
                "eval", "--agent", agent, *model, "--variant", "classic", "--categories",
                category, "--max-steps", str(args.max_steps), "--limit", str(args.play_limit),
                *paraphrases, "--output-dir", str(run_dir), "--no-progress", "--batch-size", "8",
                *common,
            )  # fmt: skip
            episodes += read_episodes(run_dir / "episodes.jsonl")
        by_category = {c: [e for e in episodes if e.category == c] for c in args.play_categories}
        cells = "  ".join(f"{c} {_rate(v)}" for c, v in by_category.items() if v)
        line = f"  {agent:<10} success {_rate(episodes)}  {cells}"
        # Per distinct text: a text is read once, however many worlds play it.
        read = understanding(episodes)
        if read is not None:
            line += (
                f"  | read right (texts) {read.grounded.cell()}, success when right "
                f"{read.success_when_right.cell() if read.success_when_right else '-'}, "
                f"when wrong {read.success_when_wrong.cell() if read.success_when_wrong else '-'}"
            )
        print(f"{line}  [{seconds:.0f} s]")
    print(f"Intervals: {CLUSTERED_LABEL}.")


if __name__ == "__main__":
    main()
