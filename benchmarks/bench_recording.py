"""What recording a step costs, and what the run-integrity fields (finish reason, backend error,
cache flag, follow-ups) add to it: per-step time to build and serialise a `StepRecord` and to
append a batch of them to `steps.jsonl`, with and without those fields, and with and without an
fsync per write (the runner syncs steps only when an episode ends).

    python benchmarks/bench_recording.py [--steps 20000] [--batch 32]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from llm_agents.run_data.records import StepRecord
from llm_agents.run_data.store import append_lines

INTEGRITY_FIELDS = {"finish_reason", "error", "cached", "followups"}
OBSERVATION = "\n".join(f"tree at ({i}, {-i}), 3 steps away" for i in range(20))


def record(step: int) -> StepRecord:
    return StepRecord(
        episode_id="combo/place_table/0/0",
        step=step,
        observation=OBSERVATION,
        prompt_hash="0" * 64,
        raw_output="The tree is north of me.\nACTION: UP",
        action_name="UP",
        action_id=3,
        parse_stage="action_line",
        fallback_used=False,
        reward=0.0,
        done=False,
        prompt_tokens=1650,
        completion_tokens=12,
        latency_s=0.2,
        finish_reason="stop",
    )


def per_step_us(
    steps: int, batch: int, exclude: set[str], directory: Path, sync: bool = False
) -> float:
    path = directory / f"steps-{len(exclude)}-{sync}.jsonl"
    started = time.perf_counter()
    for first in range(0, steps, batch):
        lines = [
            record(step).model_dump_json(exclude=exclude)
            for step in range(first, min(first + batch, steps))
        ]
        append_lines(path, lines, durable=sync)
    return (time.perf_counter() - started) / steps * 1e6


def serialise_us(steps: int, exclude: set[str]) -> float:
    started = time.perf_counter()
    for step in range(steps):
        record(step).model_dump_json(exclude=exclude)
    return (time.perf_counter() - started) / steps * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--batch", type=int, default=32, help="steps appended per write")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        directory = Path(folder)
        per_step_us(args.batch * 4, args.batch, set(), directory)  # warm up pydantic
        rounds = [
            (
                per_step_us(args.steps, args.batch, INTEGRITY_FIELDS, directory),
                per_step_us(args.steps, args.batch, set(), directory),
            )
            for _ in range(3)
        ]
        synced = min(
            per_step_us(args.steps, args.batch, set(), directory, sync=True) for _ in range(3)
        )
        serialised = [
            (serialise_us(args.steps, INTEGRITY_FIELDS), serialise_us(args.steps, set()))
            for _ in range(3)
        ]
    print(
        "build + serialise only: "
        f"{min(r[0] for r in serialised):.1f} us without, {min(r[1] for r in serialised):.1f} us "
        "with the integrity fields"
    )
    without = min(r[0] for r in rounds)
    with_fields = min(r[1] for r in rounds)
    print(f"steps: {args.steps}, appended {args.batch} per write (no fsync)")
    print(f"per step without the integrity fields: {without:.1f} us")
    print(f"per step with them:                    {with_fields:.1f} us")
    print(
        f"added by the integrity fields: {with_fields - without:+.1f} us per step "
        f"({with_fields / without:.3f}x)"
    )
    print(f"per step with an fsync after every write: {synced:.1f} us")


if __name__ == "__main__":
    main()
