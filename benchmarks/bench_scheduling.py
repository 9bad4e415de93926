"""Scheduling efficiency against a heavy-tailed server: lockstep vs continuous, side by side.

The episodes talk to a loopback OpenAI-compatible server (its own process) that records when
each answer started and ended. Efficiency = sum of answer times / (in flight x busy span),
measured at that server: 1.0 means every one of the `in flight` request slots was busy all the
time. Two spans are reported: the whole run (which ends with the last episodes draining, as any
finite run does), and the steady part, up to the first request of the last episode started.

Servers (`--server`):
- `lognormal`: answers after a lognormal time (median 0.2 s, sigma 1: reasoning models' answer
  lengths are heavy-tailed);
- `vllm`: a proxy in front of a real `vllm serve` of the embedded model on CPU (from the vLLM
  environment, `$VLLM_VENV`), which gives each request a lognormal `max_tokens` (median 12,
  sigma 1, at most 128) and `ignore_eos`, so answers really are of mixed lengths.

Schedulers:
- lockstep: the scheduling before continuous scheduling, reimplemented minimally here: every
  step sends all live episodes' prompts as one batch and waits for the slowest answer;
- continuous: `run_eval` as shipped (each episode steps when its own answer arrives).

    python benchmarks/bench_scheduling.py [--server lognormal|vllm] [--episodes 605]
        [--lockstep-episodes 32] [--max-steps 20] [--in-flight 32] [--variant full]
"""

from __future__ import annotations

import argparse
import contextlib
import math
import random
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

# The tests' loopback server and `vllm serve` launcher are the benchmark's too.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

MEDIAN_S = 0.2
SIGMA = 1.0
MEDIAN_TOKENS = 12
MAX_TOKENS = 128
ANSWERS = ["ACTION: LEFT", "ACTION: RIGHT", "ACTION: UP", "ACTION: DOWN", "ACTION: DO"]
#: Text of the step template when the episode has no history yet: marks an episode's start.
FIRST_STEP_MARK = "first step"


def serve(seed: int, upstream: str | None) -> None:
    """The server process: the tests' loopback server answering itself after a lognormal time,
    or through `upstream` with a drawn `max_tokens`; prints its URL."""
    import httpx
    from fault_server import FaultServer

    rng = random.Random(seed)
    lock = threading.Lock()
    client = httpx.Client(base_url=upstream, timeout=600) if upstream else None

    def answer(body: dict[str, Any]) -> dict[str, Any]:
        if client is None:
            with lock:
                delay = rng.lognormvariate(math.log(MEDIAN_S), SIGMA)
                text = rng.choice(ANSWERS)
            time.sleep(delay)
            return {"role": "assistant", "content": text}
        with lock:
            tokens = rng.lognormvariate(math.log(MEDIAN_TOKENS), SIGMA)
        body |= {"max_tokens": max(1, min(MAX_TOKENS, round(tokens))), "ignore_eos": True}
        [choice] = client.post("/chat/completions", json=body).json()["choices"]
        return {**choice["message"], "finish_reason": choice["finish_reason"]}

    server = FaultServer(answer=answer, max_requests=10**9).start()
    print(server.url, flush=True)
    threading.Event().wait()


SERVED_NAME = "smollm2"


def efficiency(answers: list[list[Any]], in_flight: int) -> dict[str, float]:
    """Whole-run and steady-state efficiency from the server's (start, end, first) records."""
    begin = min(a[0] for a in answers)
    end = max(a[1] for a in answers)
    steady_end = max(a[0] for a in answers if a[2])
    busy = sum(a[1] - a[0] for a in answers)
    steady_busy = sum(max(0.0, min(a[1], steady_end) - a[0]) for a in answers)
    steady = steady_end - begin
    return {
        "answers": len(answers),
        "span_s": end - begin,
        "efficiency": busy / (in_flight * (end - begin)),
        "steady_s": steady,
        # Undefined when every episode started at once (one round of lockstep).
        "steady_efficiency": steady_busy / (in_flight * steady) if steady > 1.0 else math.nan,
    }


def lockstep(config: Any, env: Any, model: Any) -> None:
    """The old runner loop, minus its records: one batched model call per step for all."""
    import numpy as np

    from env import VectorEnv, episode_key, goal_masks
    from env.dataset import load_dataset
    from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
    from llm_agents.agents.types import EpisodeStart
    from llm_agents.evaluation.schedule import build_schedule
    from textualizer import observe_batch

    instructions = load_dataset(config.dataset).instructions(config.categories)
    queue = list(reversed(build_schedule(config, instructions, None)))
    agent = ZeroShotAgent(config.variant, renderer=config.renderer, choice_rule=config.choice)
    batch = min(config.batch_size, len(queue))
    vector = VectorEnv(env, batch)

    def rows(specs: list[Any]) -> tuple[Any, Any, Any]:
        keys = np.stack(
            [episode_key(0, s.instruction.goal.id, s.instruction.variant, s.repeat) for s in specs]
        )
        return (keys, *goal_masks([s.instruction.goal for s in specs]))

    first = [queue.pop() for _ in range(batch)]
    host = vector.reset(*rows(first))
    live = set(range(batch))
    for slot, spec in enumerate(first):
        agent.start_episode(slot, EpisodeStart(spec.instruction.text))
    while live:
        slots = sorted(live)
        observations = observe_batch(host.game, config.variant, slots)
        prompts = [agent.prepare(slot, obs) for slot, obs in zip(slots, observations, strict=True)]
        outputs = model.generate([p.messages for p in prompts], choices=agent.choices)
        decisions = [agent.decide(p, out) for p, out in zip(prompts, outputs, strict=True)]
        actions = np.full(batch, agent.fallback_id, dtype=np.int32)
        for decision in decisions:
            actions[decision.slot] = decision.action
        host = vector.step(actions)
        ended = [slot for slot in slots if host.done[slot]]
        live -= set(ended)
        refill = [(slot, queue.pop()) for slot in ended if queue]
        if refill:
            host = vector.refill([s for s, _ in refill], *rows([spec for _, spec in refill]))
            for slot, spec in refill:
                agent.start_episode(slot, EpisodeStart(spec.instruction.text))
                live.add(slot)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    # A default run's schedule: at 32 in flight each slot plays about 19 episodes, so the drain
    # at the end (slots idling while the last episodes finish) weighs what it does at scale.
    parser.add_argument("--episodes", type=int, default=605, help="continuous run's episodes")
    parser.add_argument("--lockstep-episodes", type=int, default=32)
    parser.add_argument("--max-steps", type=int, default=20)
    parser.add_argument(
        "--in-flight", type=int, default=32, help="--batch-size and --max-concurrency"
    )
    parser.add_argument("--variant", default="full", choices=["full", "classic"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--server", default="lognormal", choices=["lognormal", "vllm"])
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--upstream", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.seed, args.upstream)
        return

    import httpx

    from env import CrafTextEnv, EnvConfig, Variant
    from llm_agents.backends import get_model
    from llm_agents.evaluation.config import build_config
    from llm_agents.evaluation.runner import run_eval

    with contextlib.ExitStack() as stack:
        upstream = None
        if args.server == "vllm":
            from vllm_serve import VLLM_VENV, ServerDidNotStart, vllm_serve

            from llm_agents.backends.embedded import embedded_model_dir

            if not (VLLM_VENV / "bin" / "vllm").exists():
                sys.exit(
                    f"no vLLM environment at {VLLM_VENV}: build it with scripts/setup_vllm_cpu.sh"
                )
            log = stack.enter_context(tempfile.TemporaryDirectory())
            try:
                upstream = stack.enter_context(
                    vllm_serve(
                        embedded_model_dir(), Path(log) / "vllm.log", served_name=SERVED_NAME,
                        max_model_len=4096, max_num_seqs=args.in_flight, kv_cache_gib=2,
                    )
                )  # fmt: skip
            except ServerDidNotStart as err:
                sys.exit(str(err))
        server = subprocess.Popen(
            [sys.executable, __file__, "--serve", "--seed", str(args.seed)]
            + (["--upstream", upstream] if upstream else []),
            stdout=subprocess.PIPE,
            text=True,
        )
        stack.callback(server.wait)
        stack.callback(server.terminate)
        assert server.stdout is not None
        url = server.stdout.readline().strip()
        model_name = SERVED_NAME if upstream else "bench"
        env = CrafTextEnv(EnvConfig(variant=Variant(args.variant), max_steps=args.max_steps))

        def settings(episodes: int, out: str) -> Any:
            return build_config(
                {
                    "model": f"openai:{model_name}@{url}",
                    "variant": args.variant,
                    "categories": ["one", "combo", "paraphrased", "new_objects"],
                    "max_steps": args.max_steps,
                    "batch_size": args.in_flight,
                    "limit": episodes,
                    "probe": False,
                    "generation": {"max_concurrency": args.in_flight},
                    "output_dir": out,
                }
            )

        def stats() -> dict[str, float]:
            answers = httpx.get(f"{url}/stats", timeout=30).json()
            timings = [[start, end, FIRST_STEP_MARK in key] for start, end, key in answers]
            return efficiency(timings, args.in_flight)

        with tempfile.TemporaryDirectory() as tmp:
            config = settings(args.lockstep_episodes, f"{tmp}/lockstep")
            model = get_model(config.backend_spec, config.generation)
            # Compiles (or loads from the cache) the env's functions before anything is timed.
            lockstep(settings(args.in_flight, f"{tmp}/warmup"), env, model)
            stats()
            lockstep(config, env, model)
            results = {"lockstep": (args.lockstep_episodes, stats())}
            config = settings(args.episodes, f"{tmp}/continuous")
            run_eval(config, model, env=env)
            results["continuous"] = (args.episodes, stats())

    answers = (
        f"vllm serve (embedded model, CPU), lognormal max_tokens (median {MEDIAN_TOKENS}, "
        f"sigma {SIGMA}, at most {MAX_TOKENS})"
        if args.server == "vllm"
        else f"lognormal answer time (median {MEDIAN_S} s, sigma {SIGMA})"
    )
    print(
        f"server: {answers}; "
        f"{args.in_flight} episodes and {args.in_flight} requests in flight; "
        f"{args.variant} Craftax, {args.max_steps} steps per episode"
    )
    print(
        f"{'scheduler':<11} {'episodes':>8} {'answers':>7} {'span s':>7} {'efficiency':>10} "
        f"{'steady s':>8} {'steady eff.':>11}"
    )
    for name, (episodes, figures) in results.items():
        print(
            f"{name:<11} {episodes:>8} {figures['answers']:>7.0f} {figures['span_s']:>7.1f} "
            f"{figures['efficiency']:>10.2f} {figures['steady_s']:>8.1f} "
            f"{figures['steady_efficiency']:>11.2f}"
        )
    ratio = results["continuous"][1]["efficiency"] / results["lockstep"][1]["efficiency"]
    print(f"continuous / lockstep efficiency: {ratio:.1f}x; target: continuous >= 0.85")


if __name__ == "__main__":
    main()
