"""What an image observation costs: frame render time per step and bytes per request, `text`
vs `image` vs `both`, side by side in one run, at batch 1 and 64.

States come from random-action rollouts of a `VectorEnv` (the play loop's env). Per mode, a
step's observation is made as the play loop makes it: `text` pulls the states to numpy and
renders the textualizer's text into the zero-shot agent's messages; `image` draws the batch's
frames (`VectorEnv.frames`: craftax's renderer at the Pixels env's block size, in JAX) and
encodes each as PNG (`ImagePart.from_frame`); `both` does the two. The time is CPU time of the
process (every thread, JAX's included) per episode step; the bytes are the JSON body of the
OpenAI chat request the step sends (`openai_message`), with `--frame-history` past frames.

    python benchmarks/bench_observation.py [--variant classic full] [--batch 1 64]
        [--rounds 6] [--frame-history 0]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import deque
from typing import Any

import numpy as np

from env import CrafTextEnv, EnvConfig, Variant, VectorEnv, episode_key
from env.frames import AGENT_BLOCK_SIZES, frame_shape
from env.open_ended import OPEN_ENDED_GOAL
from env.scenario_tasks import encode_goals
from llm_agents.agents.registry import ObservationMode
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.backends.base import ImagePart, openai_message
from textualizer import observe_batch

MODES: tuple[ObservationMode, ...] = ("text", "image", "both")


def measure(
    variant: Variant, batch: int, rounds: int, frame_history: int
) -> dict[str, tuple[float, float]]:
    """Per mode: (CPU ms per episode step, mean request bytes)."""
    env = CrafTextEnv(EnvConfig(variant=variant, max_steps=10_000))
    vector = VectorEnv(env, batch)
    tasks = encode_goals([OPEN_ENDED_GOAL] * batch, variant)
    keys = np.stack([episode_key(0, "bench", 0, i) for i in range(batch)])
    vector.reset(keys, tasks.required, tasks.forbidden, tasks.kind, tasks.params)
    agents = {
        mode: ZeroShotAgent(variant, observation=mode, frame_history=frame_history)
        for mode in MODES
    }
    for agent in agents.values():
        for slot in range(batch):
            agent.start_episode(slot, EpisodeStart(OPEN_ENDED_GOAL.instruction))
    history: dict[str, list[deque[ImagePart]]] = {
        mode: [deque(maxlen=frame_history + 1) for _ in range(batch)] for mode in MODES
    }
    rng = np.random.default_rng(0)
    slots = list(range(batch))
    cpu: dict[str, list[float]] = {mode: [] for mode in MODES}
    sizes: dict[str, list[int]] = {mode: [] for mode in MODES}
    # Round 0 compiles the renderer and is not counted.
    for round_ in range(rounds + 1):
        host = vector.step(rng.integers(0, variant.num_actions, batch))
        for mode in MODES:
            agent = agents[mode]
            start = time.process_time()
            observations = observe_batch(host.game, variant)
            frames = (
                [ImagePart.from_frame(frame) for frame in vector.frames(slots)]
                if mode != "text"
                else []
            )
            bodies = []
            for slot in slots:
                prompt = agent.prepare(slot, observations[slot])
                messages = prompt.messages
                if frames:
                    history[mode][slot].append(frames[slot])
                    messages = [
                        *messages[:-1],
                        messages[-1].model_copy(update={"images": tuple(history[mode][slot])}),
                    ]
                body = {"model": "m", "messages": [openai_message(m) for m in messages]}
                bodies.append(json.dumps(body))
                agent.decide(prompt, _answer())
            elapsed = time.process_time() - start
            if round_:
                cpu[mode].append(1000 * elapsed / batch)
                sizes[mode].extend(len(body.encode()) for body in bodies)
    return {mode: (statistics.median(cpu[mode]), statistics.mean(sizes[mode])) for mode in MODES}


def _answer() -> Any:
    from llm_agents.backends.base import ModelOutput

    return ModelOutput(text="ACTION: NOOP")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variant", nargs="+", default=["classic", "full"])
    parser.add_argument("--batch", nargs="+", type=int, default=[1, 64])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--frame-history", type=int, default=0)
    args = parser.parse_args()
    print(
        f"CPU ms per episode step (median of {args.rounds} rounds; observation, text, frames, "
        f"PNG, messages, JSON body) and mean request body bytes; frame history "
        f"{args.frame_history}"
    )
    print(
        f"{'variant':8} {'frame':>12} {'batch':>5} | "
        + " | ".join(f"{mode + ' ms':>9} {mode + ' B':>9}" for mode in MODES)
    )
    for name in args.variant:
        variant = Variant(name)
        height, width, _ = frame_shape(variant)
        for batch in args.batch:
            result = measure(variant, batch, args.rounds, args.frame_history)
            cells = " | ".join(f"{ms:9.2f} {size:9.0f}" for ms, size in result.values())
            frame = f"{width}x{height}@{AGENT_BLOCK_SIZES[variant]}"
            print(f"{name:8} {frame:>12} {batch:5d} | {cells}", flush=True)


if __name__ == "__main__":
    main()
