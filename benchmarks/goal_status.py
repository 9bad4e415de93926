"""The goals a do-nothing agent meets and the goals that cannot be met, per difficulty and
variant, with why: the lists docs/goal-status.md shows (issue 31).

Do nothing: `NOOP` at every step in `--worlds` seeded worlds per goal, in the real env with the
real checkers (`env.goal_status`, cached: a rerun only prints). Impossible: derived from each
goal's parameters and the variant's tables; the scripted expert's own limits are listed apart.

    python -m benchmarks.goal_status [--difficulty medium] [--variant classic] [--worlds 8]
        [--max-steps 250] [--success-rule official] [--seed 0] [--dataset PATH]

The dataset defaults to the official repository at 1c518ae (`../shared/data`'s zip, unpacked
into a temporary folder).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from pathlib import Path

from env.dataset import load_dataset
from env.goals import DIFFICULTIES
from llm_agents.evaluation.config import EvalConfig
from llm_agents.judging.goal_flags import goal_status

OFFICIAL_ZIP = (
    Path(__file__).resolve().parents[2] / "shared" / "data" / "craftext_official_1c518ae.zip"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", choices=DIFFICULTIES, default="medium")
    parser.add_argument("--variant", choices=["classic", "full"], default="classic")
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--max-steps", type=int, default=250)
    parser.add_argument("--success-rule", default="official")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dataset")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as work:
        source = args.dataset
        if source is None:
            with zipfile.ZipFile(OFFICIAL_ZIP) as archive:
                archive.extractall(work)
            (source,) = (str(p) for p in Path(work).iterdir())
        goals = [g for g in load_dataset(source).goals if g.difficulty == args.difficulty]
    config = EvalConfig.recorded(
        {
            "variant": args.variant,
            "max_steps": args.max_steps,
            "success_rule": args.success_rule,
            "seed": args.seed,
        }
    )
    started = time.perf_counter()
    status = goal_status(goals, config, worlds=args.worlds)
    seconds = time.perf_counter() - started
    flags = list(status.goals.values())
    impossible = [f for f in flags if f.impossible]
    expert = [f for f in flags if f.expert_cannot and not f.impossible]
    trivial = sorted((f for f in flags if f.trivial), key=lambda f: (-f.do_nothing, f.key))
    print(
        f"{args.difficulty}, {args.variant} Craftax: {len(flags)} goals; do nothing = NOOP only, "
        f"{args.worlds} worlds per goal, seed {args.seed}, {args.max_steps} steps, "
        f"{args.success_rule} rule ({seconds:.0f} s)."
    )
    print(f"\nNot achievable on {args.variant} Craftax ({len(impossible)}):")
    for f in impossible:
        print(f"- `{f.key}` ({f.scenario_class}): {f.impossible}")
    print(f"\nOut of the scripted expert's reach only ({len(expert)}):")
    for f in expert:
        print(f"- `{f.key}` ({f.scenario_class}): {f.expert_cannot}")
    print(f"\nMet by doing nothing ({len(trivial)}):")
    for f in trivial:
        print(f"- `{f.key}` ({f.scenario_class}): {f.do_nothing}/{args.worlds} worlds")


if __name__ == "__main__":
    main()
