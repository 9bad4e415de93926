"""The guided agent (`guided`): the model reads the instruction, the scripted expert acts on it.

At the start of each episode the model grounds the instruction once (`ground.j2` offering the
run's difficulty's goal kinds, parsed by `parse_grounding`, cached per text, so the paraphrase
played again in another world costs no request, and a text several slots start at once is asked
by one of them while the others wait on its answer, their prompts `deferred`); then the expert
(`expert.py`) plays the goal as the model read it, never the dataset record's: the achievements
it read, or on Medium and Hard the placing goal with the block, side, distance, size and counts
it read. This separates understanding from acting: its success is what a model that plays
perfectly-scripted moves would reach with its own reading of the goals. `grounding_shots` shows
the request worked examples from the training goals first, as `craftext-llm ground` does (the
episode's goal is read for that alone: no example answered with it is shown). An invalid
grounding is an episode the agent could not start: its first decision carries the invalid
grounding and the runner ends it there, unscored as play but counted as a failure.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from env.dataset import load_dataset
from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY
from env.variant import Variant, as_variant
from llm_agents.agents.answer_schemas import reading_schema
from llm_agents.agents.answers.parser import ParseResult
from llm_agents.agents.grounding import (
    GROUND_TEMPLATE,
    GroundingExample,
    grounding_messages,
    parse_grounding,
    training_examples,
)
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION
from llm_agents.agents.strategies.expert import ExpertAgent
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt, messages_hash
from llm_agents.backends.base import ChatMessage, ModelOutput
from llm_agents.run_data.readings import Grounding, reading_of

if TYPE_CHECKING:
    from env.goals import AnyGoal, Difficulty
    from llm_agents.agents.registry import AgentSettings


class GuidedAgent:
    """Grounds each episode's instruction with the model, then plays the expert on that goal."""

    protocol_version: ClassVar[int] = AGENT_PROTOCOL_VERSION
    needs_model: ClassVar[bool] = True
    templates: ClassVar[tuple[str, ...]] = (GROUND_TEMPLATE,)
    # Grounding answers are JSON, free or held to the reading schema (`output_schema`):
    # action-name choices do not apply to them.
    choices: ClassVar[None] = None

    def __init__(
        self,
        variant: Variant | str = Variant.FULL,
        renderer: str = "objects",
        fallback_action: str = "NOOP",
        templates_dir: str | Path | None = None,
        difficulty: Difficulty = DEFAULT_DIFFICULTY,
        examples: Sequence[GroundingExample] = (),
        shots: int = 0,
        structured: bool = False,
    ):
        self.variant = as_variant(variant)
        self.templates_dir = templates_dir
        self.difficulty = difficulty
        self.examples = tuple(examples)
        self.shots = shots
        #: `--structured-output`: each reading is held to the schema of a goal of the
        #: difficulty over the variant's names (`answer_schemas.reading_schema`).
        self.output_schema = reading_schema(self.variant, difficulty) if structured else None
        self.expert = ExpertAgent(self.variant, renderer=renderer, fallback_action=fallback_action)
        self.fallback_id = self.expert.fallback_id
        self._groundings: dict[str, Grounding] = {}
        self._texts: dict[int, str] = {}
        self._goals: dict[int, AnyGoal | None] = {}
        self._asking: dict[str, int] = {}
        """Text -> the slot whose grounding request for it is out."""
        self._waiting: set[int] = set()
        """Slots deferred while another slot's request for their text is out."""
        self._unreported: dict[int, Grounding] = {}

    @classmethod
    def from_config(cls, config: AgentSettings) -> GuidedAgent:
        if config.choice is not None:
            raise UserError(
                "the guided agent reads goals in free text: --choice picks action names, "
                "which it never asks for (leave --choice out)"
            )
        shots = config.grounding_shots
        return cls(
            config.variant,
            renderer=config.renderer,
            fallback_action=config.fallback_action,
            templates_dir=config.templates_dir,
            difficulty=config.difficulty,
            examples=training_examples(load_dataset(config.dataset), config.difficulty)
            if shots
            else (),
            shots=shots,
            structured=config.structured_output,
        )

    @property
    def groundings(self) -> dict[str, Grounding]:
        """Instruction text -> its grounding, for every text grounded so far."""
        return dict(self._groundings)

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin an episode; `goal` (the dataset record) is never played, the model's reading
        is: it only keeps its own answer out of the worked examples."""
        self._texts[slot] = start.instruction
        self._goals[slot] = start.goal
        self._unreported.pop(slot, None)
        if start.instruction in self._groundings:
            self._begin(slot, self._groundings[start.instruction])

    def _begin(self, slot: int, grounding: Grounding) -> None:
        self._unreported[slot] = grounding
        if grounding.reading is not None:
            self.expert.start_goal(slot, grounding.reading)

    def end_episode(self, slot: int) -> None:
        text = self._texts.pop(slot, None)
        self._goals.pop(slot, None)
        self._waiting.discard(slot)
        if text is not None and self._asking.get(text) == slot:
            del self._asking[text]
        self._unreported.pop(slot, None)
        self.expert.end_episode(slot)

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """Render the grounding request the run will send (the expert renders nothing)."""
        self._request(instruction, goal)

    def _request(self, text: str, goal: AnyGoal | None) -> list[ChatMessage]:
        return grounding_messages(
            text,
            self.variant,
            self.templates_dir,
            self.difficulty,
            self.examples,
            self.shots,
            answer=None if goal is None else reading_of(goal),
        )

    def _text(self, slot: int) -> str:
        if slot not in self._texts:
            raise UserError(f"slot {slot} has no episode; call start_episode({slot}, ...) first")
        return self._texts[slot]

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        """The grounding request while the slot's text is not grounded (deferred while another
        slot's request for it is out); then the expert's step, which sends nothing."""
        text = self._text(slot)
        if slot in self._waiting and text in self._groundings:
            # The answer it waited on arrived: the episode begins as if it had been cached.
            self._waiting.discard(slot)
            self._begin(slot, self._groundings[text])
        step = self.expert.prepare(slot, observation)
        if text in self._groundings:
            return step
        if self._asking.setdefault(text, slot) != slot:
            self._waiting.add(slot)
            return StepPrompt(
                slot=slot, observation=observation, messages=[], text=step.text, deferred=True
            )
        # It asks itself now (the slot it waited on failed to get an answer).
        self._waiting.discard(slot)
        messages = self._request(text, self._goals.get(slot))
        return StepPrompt(slot=slot, observation=observation, messages=messages, text=step.text)

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        """Read the grounding from the answer to a grounding request, then the expert acts; an
        invalid grounding is a decision that the episode cannot start."""
        slot, text = prompt.slot, self._text(prompt.slot)
        if prompt.messages:
            if self._asking.get(text) == slot:
                del self._asking[text]
            if output.finish_reason == "error":
                # The backend failed, not the model: nothing is cached, the runner aborts it.
                return self._fallback(prompt, output)
            if text not in self._groundings:
                self._groundings[text] = parse_grounding(output.text, self.variant, self.difficulty)
            self._begin(slot, self._groundings[text])
        grounding = self._unreported.pop(slot, None)
        if grounding is not None and grounding.reading is None:
            return self._fallback(prompt, output, grounding)
        decision = self.expert.decide(prompt, output)
        if not prompt.messages and grounding is None:
            return decision
        return decision.model_copy(
            update={
                "output": output if prompt.messages else decision.output,
                "prompt_hash": messages_hash(prompt.messages),
                "grounding": grounding,
            }
        )

    def _fallback(
        self,
        prompt: StepPrompt,
        output: ModelOutput,
        grounding: Grounding | None = None,
    ) -> Decision:
        name = self.expert.variant.action_names[self.fallback_id]
        return Decision(
            slot=prompt.slot,
            action=self.fallback_id,
            name=name,
            parse=ParseResult(action=self.fallback_id, name=name, stage="invalid", raw=output.text),
            output=output,
            observation_text=prompt.text,
            prompt_hash=messages_hash(prompt.messages),
            # An unstarted episode takes no action at all; a failed request takes the fallback.
            fallback_used=grounding is None,
            grounding=grounding,
        )
