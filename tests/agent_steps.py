"""Plays agent steps the way the runner does: each slot's prompt (`prepare`), the model's
answers to all of them in one call, and the decision read from each answer (`decide`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from llm_agents.agents import Agent
from llm_agents.agents.types import Decision
from llm_agents.backends.base import ModelAPI


def play_step(
    agent: Agent, model: ModelAPI, slots: Sequence[int], observations: Sequence[Any]
) -> list[Decision]:
    """One step of every slot in `slots`, with one `model.generate` call."""
    prompts = [agent.prepare(slot, obs) for slot, obs in zip(slots, observations, strict=True)]
    outputs = model.generate([prompt.messages for prompt in prompts], choices=agent.choices)
    return [agent.decide(prompt, output) for prompt, output in zip(prompts, outputs, strict=True)]
