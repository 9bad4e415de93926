"""Plan-episodes per second of `plan-score`: plans read into skills and played in seeded worlds
on the batched env (Classic by default), the figure the scorer is held to (at least 100 a
second on a 2-core CPU, measured with nothing else running). `--plans` takes any plans or
candidates file: the expert's own plans (`python -m benchmarks.plan_figures expert ...`) play
long, successful episodes; the GPT-4 file's mostly fail within a few steps.

Scores the first `--texts` texts of `--split` that a plans file covers (default: the official
GPT-4 plans file on the EASY train split of `../shared/data/craftext_official_easy.json`) in
`--worlds` selection worlds and `--held-out-worlds` held-out worlds each (the first and best
plan of each text), after the same run untimed (it compiles the env and caches the do-nothing
worlds), and prints plan-episodes/s over both (and per CPU second of the process: what the
scorer does with the CPU it is given, where other jobs load the machine), env steps/s, steps
per episode and the success rate.

    python -m benchmarks.bench_plan_score [--plans FILE] [--split easy_train] [--texts 48]
        [--worlds 4] [--held-out-worlds 4] [--batch-size 32 64] [--variant classic]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from benchmarks.bench_expert import REFERENCE, SHARED, convert_reference
from env.variant import Variant
from llm_agents.planning.scoring import JOURNAL, ScoreConfig, score_plans

GPT4_PLANS = SHARED / "easy_gpt4_action_plans.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=Path, default=GPT4_PLANS)
    parser.add_argument("--dataset", type=Path, help="dataset JSON (default: the EASY reference)")
    parser.add_argument("--split", default="easy_train")
    parser.add_argument("--texts", type=int, default=48)
    parser.add_argument("--worlds", type=int, default=4)
    parser.add_argument("--held-out-worlds", type=int, default=4)
    parser.add_argument("--batch-size", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--variant", default="classic")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        dataset = args.dataset or convert_reference(REFERENCE, root)
        for batch in args.batch_size:
            common = {
                "plans": args.plans,
                "dataset": str(dataset),
                "variant": Variant(args.variant),
                "splits": (args.split,),
                "skip_unknown_texts": True,
                "batch_size": batch,
                "held_out_worlds": args.held_out_worlds,
            }
            config = ScoreConfig(
                out=root / f"run{batch}", worlds=args.worlds, limit=args.texts, **common
            )
            # The same run once untimed first: it compiles the env at this batch size for
            # every path the timed run takes (all slots stepped, a few of them, refills).
            score_plans(config.model_copy(update={"out": root / f"warm{batch}"}))
            out = config.out
            started, cpu_started = time.perf_counter(), time.process_time()
            summary = score_plans(config)
            elapsed = time.perf_counter() - started
            # CPU seconds of this process (all its threads): on a machine others load, the
            # episodes per CPU second are what the scorer does with the CPU it gets.
            cpu = time.process_time() - cpu_started
            lines = (out / JOURNAL).read_text().splitlines()[1:]
            outcomes = [json.loads(line) for line in lines]
            steps = sum(o["steps"] for o in outcomes)
            wins = sum(o["success"] for o in outcomes)
            print(
                f"batch {batch}: {summary.episodes} plan-episodes ({summary.texts} texts x "
                f"{args.worlds} + {args.held_out_worlds} worlds) in {elapsed:.1f} s: "
                f"{summary.episodes / elapsed:.1f} plan-episodes/s "
                f"({summary.episodes / cpu:.1f} per CPU second), {steps / elapsed:.0f} env "
                f"steps/s, {steps / len(outcomes):.1f} steps/episode, success "
                f"{wins}/{len(outcomes)}"
            )


if __name__ == "__main__":
    main()
