"""Parser speed and real-world agreement, printed as figures.

- time per typical answer (target <= 0.1 ms);
- time per character for long answers of growing length (flat per-char time = linear);
- time for 80 KB and 320 KB of reasoning blocks of several shapes (4x the time = linear);
- agreement with the BALROG harness on its 2,250 real Crafter outputs (classic variant):
  on the rows it parsed, and how many of the rows it failed on we turn into an action.

    python benchmarks/bench_parser.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from pathlib import Path

from env.variant import Variant
from llm_agents.agents.answers.parser import parse_action

BALROG = (
    Path(__file__).resolve().parents[1].parent / "shared" / "data" / "balrog_crafter_outputs.jsonl"
)
CRAFTER_MOVES = {
    "Move West": "LEFT",
    "Move East": "RIGHT",
    "Move North": "UP",
    "Move South": "DOWN",
}

TYPICAL_ANSWERS = (
    "DO",
    "Move West",
    "ACTION: MAKE_WOOD_PICKAXE",
    "The tree is one step north, so I move up to face it.\nACTION: UP",
    "<think>I have 2 wood and no table. A table needs wood.</think>\nACTION: PLACE_TABLE",
    '```json\n{"action": "Collect Wood"}\n```',
    "<|ACTION|>Place Stone<|END|>",
    "I should collect wood from the tree in front of me.",
)

PROSE_LINE = (
    "The cow is 3 steps to the north-east and the water 5 south; I could move north, "
    "but the zombie is close, so perhaps attack first or place a stone to block it.\n"
)


def per_call_seconds(run: Callable[[], object], calls: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            run()
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def cpu_seconds(run: Callable[[], object], repeats: int) -> float:
    """Best of `repeats` in this thread's CPU time: other processes on a busy machine do not count."""
    best = float("inf")
    for _ in range(repeats):
        start = time.thread_time()
        run()
        best = min(best, time.thread_time() - start)
    return best


def bench_typical(repeats: int) -> None:
    print("time per typical answer (classic):")
    total = 0.0
    for text in TYPICAL_ANSWERS:
        seconds = per_call_seconds(partial(parse_action, text, Variant.CLASSIC), 2000, repeats)
        total += seconds
        print(f"  {seconds * 1e3:7.4f} ms  {text[:60]!r}")
    print(f"  mean {total / len(TYPICAL_ANSWERS) * 1e3:.4f} ms (target <= 0.1 ms)")


def bench_long(repeats: int) -> None:
    print("time per character for long answers (must stay flat: linear time):")
    shapes = {
        "prose, answer on the last line": lambda n: PROSE_LINE * n + "ACTION: DO",
        "prose, no answer (every stage runs)": lambda n: PROSE_LINE * n,
        "unterminated <think>": lambda n: "<think>" + PROSE_LINE * n,
        "one long line, no newlines": lambda n: PROSE_LINE.replace("\n", " ") * n,
    }
    for label, make in shapes.items():
        figures = []
        for lines in (25, 100, 400, 1600):
            text = make(lines)
            seconds = per_call_seconds(partial(parse_action, text, Variant.FULL), 3, repeats)
            figures.append((len(text), seconds / len(text)))
        per_char = ", ".join(f"{chars:>7} ch: {ns * 1e9:6.1f} ns/ch" for chars, ns in figures)
        growth = figures[-1][1] / figures[0][1]
        print(f"  {label}: {per_char}; per-char ratio longest/shortest {growth:.2f}")


def bench_reasoning_scaling(repeats: int) -> None:
    print("reasoning blocks, 80 KB vs 320 KB, CPU time (ratio 4 = linear, 16 = quadratic):")
    units = {
        "closed <think> blocks": "<think>x</think>",
        "mixed tags and cases": "<thought>a</THOUGHT>b<reasoning>c</reasoning>",
        "nested <think> blocks": "<think>a<think>b</think>c</think>",
        "stray closes": "</think>x",
        "opens of another tag inside one block": "<thinking>",
    }
    for label, unit in units.items():
        timings = []
        for size in (80_000, 320_000):
            text = unit * (size // len(unit)) + "UP"
            timings.append(cpu_seconds(partial(parse_action, text, Variant.CLASSIC), repeats))
        print(
            f"  {label:<40} {timings[0] * 1e3:7.2f} ms -> {timings[1] * 1e3:7.2f} ms"
            f"  (x{timings[1] / timings[0]:.1f})"
        )
    nested = "<think>" + "<thinking>" * 20_000 + "</think>UP"
    seconds = cpu_seconds(partial(parse_action, nested, Variant.CLASSIC), repeats)
    print(f"  one block holding 20,000 other openings: {seconds * 1e3:.2f} ms")


def crafter_to_ours(name: str) -> str:
    return CRAFTER_MOVES.get(name) or name.upper().replace(" ", "_")


def bench_balrog() -> None:
    if not BALROG.is_file():
        print(f"BALROG agreement: skipped, {BALROG} is absent")
        return
    rows = [json.loads(line) for line in BALROG.read_text(encoding="utf-8").splitlines()]
    valid = agree = recovered = 0
    failed = 0
    stages: Counter[str] = Counter()
    recovered_actions: Counter[str] = Counter()
    start = time.perf_counter()
    for row in rows:
        result = parse_action(row["output"], Variant.CLASSIC)
        stages[result.stage] += 1
        if row["balrog_action"]:
            valid += 1
            agree += result.name == crafter_to_ours(row["balrog_action"])
        else:
            failed += 1
            if result.name is not None:
                recovered += 1
                recovered_actions[result.name] += 1
    elapsed = time.perf_counter() - start
    print(f"BALROG outputs: {len(rows)} rows parsed in {elapsed:.2f} s")
    print(f"  agreement on the harness's valid rows: {agree}/{valid} = {agree / valid:.2%}")
    print(f"  harness failures we turn into an action: {recovered}/{failed}")
    print(f"    by action: {dict(recovered_actions.most_common())}")
    print(f"  stages: {dict(stages.most_common())}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="best of this many timings")
    args = parser.parse_args()
    bench_typical(args.repeats)
    bench_long(args.repeats)
    bench_reasoning_scaling(args.repeats)
    bench_balrog()


if __name__ == "__main__":
    main()
