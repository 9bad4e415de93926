"""The chain-of-thought agent (`cot`): the zero-shot agent asked to reason before answering,
with its own replies of the last k steps kept in the conversation.

The conversation of a step is [system, (short stand-in, earlier reply) x up to k, step message]:
earlier observations are not repeated (the history lines already give what the actions did),
only the model's reasoning is, newest kept first until `max_tokens` (estimated as 4 characters a
token, whatever the backend's tokenizer) is spent; a reply that does not fit whole keeps its end,
where the answer is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from env.errors import UserError
from llm_agents.agents.strategies.zero_shot import SYSTEM_TEMPLATE, ZeroShotAgent
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt
from llm_agents.backends.base import ChatMessage, ModelOutput
from prompts import render_template

if TYPE_CHECKING:
    from llm_agents.agents.registry import AgentSettings

CHARS_PER_TOKEN = 4
TURN_TEMPLATE = "cot_turn"


def estimate_tokens(text: str) -> int:
    """A tokenizer-free size estimate, so the cap means the same for every backend."""
    return -(-len(text) // CHARS_PER_TOKEN)


class ChainOfThoughtAgent(ZeroShotAgent):
    """Zero-shot with step-by-step reasoning that stays in the conversation for k steps."""

    step_template: ClassVar[str] = "step_cot"
    agent_name: ClassVar[str] = "cot"
    templates: ClassVar[tuple[str, ...]] = (SYSTEM_TEMPLATE, step_template, TURN_TEMPLATE)

    def __init__(self, *args: Any, steps: int = 3, max_tokens: int = 384, **kwargs: Any):
        if steps < 1 or max_tokens < 1:
            raise UserError(f"cot needs steps >= 1 and max_tokens >= 1, got {steps}, {max_tokens}")
        super().__init__(*args, **kwargs)
        self.keep_steps = steps
        self.max_tokens = max_tokens
        self._replies: dict[int, list[tuple[int, str]]] = {}

    @classmethod
    def strategy_settings(cls, config: AgentSettings) -> dict[str, Any]:
        return {"steps": config.cot_steps, "max_tokens": config.cot_max_tokens}

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        super().start_episode(slot, start)
        self._replies[slot] = []

    def end_episode(self, slot: int) -> None:
        super().end_episode(slot)
        self._replies.pop(slot, None)

    def kept_replies(self, slot: int) -> list[tuple[int, str]]:
        """The (step, reply) pairs the next prompt carries, oldest first, within the caps."""
        kept: list[tuple[int, str]] = []
        budget = self.max_tokens
        for step, reply in reversed(self._replies.get(slot, [])[-self.keep_steps :]):
            size = estimate_tokens(reply)
            if size > budget:
                if budget > 0:
                    kept.append((step, "..." + reply[-budget * CHARS_PER_TOKEN :]))
                break
            kept.append((step, reply))
            budget -= size
        return kept[::-1]

    def messages_for(self, slot: int, observation_text: str) -> list[ChatMessage]:
        messages = super().messages_for(slot, observation_text)
        turns: list[ChatMessage] = []
        for step, reply in self.kept_replies(slot):
            stand_in = render_template(TURN_TEMPLATE, {"step": step}, self.templates_dir)
            turns += [
                ChatMessage(role="user", content=stand_in),
                ChatMessage(role="assistant", content=reply),
            ]
        return [messages[0], *turns, *messages[1:]]

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        decision = super().decide(prompt, output)
        step = self._episode(decision.slot).step - 1
        self._replies[decision.slot].append((step, decision.output.text.strip()))
        return decision
