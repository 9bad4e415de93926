"""How long checking a run by replay takes (`card --verify`'s replay: the episodes derived from
the protocol, each re-simulated from its world key and actions, the answers parsed again).

    craftext-llm eval --agent expert --protocol paper --output-dir runs/paper-expert
    python benchmarks/bench_replay_check.py runs/paper-expert

Prints the seconds of the first check in a fresh process (compiling the replay included) and of
a second one, what was checked, and the process's peak memory (the step log is read line by
line, so it stays far below the log's size). Goals on a 2-core CPU: a complete paper-protocol
EASY run (605 episodes) in at most 2 minutes, a Medium one (81,400 episodes) in at most 20; give
a Medium run `--repeats 1`, its check is long enough that compiling is noise.
"""

from __future__ import annotations

import argparse
import resource
import time

from llm_agents.evaluation.run_view import read_run
from llm_agents.judging.replay_check import check_run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", help="a complete run's output directory")
    parser.add_argument("--repeats", type=int, default=2, help="checks in this process")
    args = parser.parse_args()
    for repeat in range(args.repeats):
        started = time.perf_counter()
        check = check_run(read_run(args.run_dir))
        seconds = time.perf_counter() - started
        steps = sum(episode.steps for episode in check.replayed)
        print(
            f"check {repeat + 1}: {seconds:.1f} s for {check.episodes} episodes ({steps} steps, "
            f"{check.answers} answers parsed again), {len(check.differences)} differences"
        )
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
