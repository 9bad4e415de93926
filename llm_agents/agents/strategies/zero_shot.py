"""The zero-shot LLM agent (`zero-shot`): one object plays many episodes (slots) at once.

For each slot's observation it builds [system, user] messages from the templates (`prepare`),
and turns the model's answer into a decision (`decide`): parse, or fall back to a fixed action
on an unparseable answer. The runner sends the prompt and calls `decide` when its answer
arrives, so each episode moves on as soon as its own answer is in. It remembers, per slot, the
last actions and what they visibly did (moved or blocked, items gained or spent, achievements,
health lost), read off consecutive observations.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, Self

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY
from env.trusted import trusted
from env.variant import Variant, as_variant
from llm_agents.agents.answer_schemas import agent_schema, answered_action
from llm_agents.agents.answers.actions import (
    MOVE_HEADINGS,
    action_catalogue,
    action_id,
    action_names,
)
from llm_agents.agents.answers.lettered import LetteredOptions, label_choices, lettered
from llm_agents.agents.answers.parser import parse_action
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION
from llm_agents.agents.registry import ObservationMode
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt, messages_hash
from llm_agents.backends.base import (
    ChatMessage,
    ChoiceRule,
    ChoiceScoring,
    ChoiceSet,
    ModelOutput,
    OutputSchema,
)
from prompts import render_template, template_renderer

if TYPE_CHECKING:
    from env.goals import AnyGoal
    from llm_agents.agents.registry import AgentSettings

SYSTEM_TEMPLATE = "system"
STEP_TEMPLATE = "step"
#: What the frames attached to a step message show (`--observation image|both`).
FRAMES_TEMPLATE = "frames"
# The template check plays a step in a slot no run uses, with a stand-in observation text.
_CHECK_SLOT = -1
_PLACEHOLDER = "(observation)"


class _PositionLike(Protocol):
    @property
    def x(self) -> int: ...
    @property
    def y(self) -> int: ...


class _InventoryLike(Protocol):
    @property
    def materials(self) -> Mapping[str, int]: ...
    @property
    def tools(self) -> Collection[str]: ...


class _VitalsLike(Protocol):
    @property
    def health(self) -> float: ...


class ObservationLike(Protocol):
    """The fields of `textualizer.Observation` that outcomes are computed from."""

    @property
    def position(self) -> _PositionLike: ...
    @property
    def floor(self) -> object: ...
    @property
    def inventory(self) -> _InventoryLike: ...
    @property
    def achievements(self) -> Collection[str]: ...
    @property
    def vitals(self) -> _VitalsLike: ...


Renderer = Callable[[Any], str]


class HistoryEntry(BaseModel):
    """One past action of an episode and what it visibly did."""

    model_config = ConfigDict(frozen=True)

    step: int
    """The episode step (0-based) the action was taken at."""
    action: str
    """The action's name."""
    outcome: str
    """What changed between the observation before it and the one after it."""


class _Episode:
    def __init__(
        self, instruction: str, plan: str | None, goal: AnyGoal | None = None, name: str = ""
    ):
        self.instruction = instruction
        self.plan = plan
        self.goal = goal
        self.name = name
        """The episode's `episode_id` (what `--choice-scoring letters` draws its orders from)."""
        self.shown: LetteredOptions | None = None
        """`letters`: the order of the step message last built."""
        self.step = 0
        self.history: list[HistoryEntry] = []
        self.pending: tuple[str, Any] | None = None


def _items(observation: ObservationLike) -> dict[str, int]:
    inventory = observation.inventory
    return {**dict.fromkeys(inventory.tools, 1), **inventory.materials}


def describe_outcome(action: str, before: ObservationLike, after: ObservationLike) -> str:
    """What an action visibly did, from the observations before and after it."""
    effects: list[str] = []
    if before.floor != after.floor:
        effects.append("changed floor")
    elif action in MOVE_HEADINGS:
        heading = MOVE_HEADINGS[action]
        moved = (before.position.x, before.position.y) != (after.position.x, after.position.y)
        effects.append(f"moved {heading}" if moved else f"blocked, now facing {heading}")
    items_before, items_after = _items(before), _items(after)
    # Most steps change neither: one comparison each, not a sorted walk over every item.
    if items_before != items_after:
        for item in sorted(set(items_before) | set(items_after)):
            change = items_after.get(item, 0) - items_before.get(item, 0)
            if change:
                verb = "gained" if change > 0 else "spent"
                effects.append(f"{verb} {abs(change)} {item.replace('_', ' ')}")
    if after.achievements != before.achievements:
        for achievement in sorted(set(after.achievements) - set(before.achievements)):
            effects.append(f"achievement {achievement.lower().replace('_', ' ')}")
    lost = before.vitals.health - after.vitals.health
    if lost > 0:
        effects.append(f"lost {lost:g} health")
    return ", ".join(effects) if effects else "no visible effect"


def _textualizer_renderer(style: str) -> Renderer:
    # Looked up at run time: the agent depends only on the documented `render(obs, style)`.
    render = importlib.import_module("textualizer").render

    def render_style(observation: Any) -> str:
        return str(render(observation, style))

    return render_style


class ZeroShotAgent:
    """Plays many episodes (slots) at once: `prepare` a slot's prompt, `decide` on the answer."""

    protocol_version: ClassVar[int] = AGENT_PROTOCOL_VERSION
    needs_model: ClassVar[bool] = True
    step_template: ClassVar[str] = STEP_TEMPLATE
    """The template of the per-step user message (strategies built on this one swap it)."""
    templates: ClassVar[tuple[str, ...]] = (SYSTEM_TEMPLATE, STEP_TEMPLATE)
    agent_name: ClassVar[str] = "zero-shot"
    """The registry's name of the strategy: the one `--structured-output` asks its schema of."""

    def __init__(
        self,
        variant: Variant | str = Variant.FULL,
        renderer: str | Renderer = "objects",
        templates_dir: str | Path | None = None,
        history_length: int = 5,
        fallback_action: str = "NOOP",
        choice_rule: ChoiceRule | None = None,
        choice_scoring: ChoiceScoring = "sum",
        report_invalid: bool = False,
        observation: ObservationMode = "text",
        frame_history: int = 0,
        seed: int = 0,
        structured: bool = False,
    ):
        """`renderer`: a textualizer style name or a function observation -> text.

        `choice_rule` passes the action names as choices to the model, picked by that rule
        (`loglik` or `guided`); None lets the model write free text. `choice_scoring`: how
        `loglik` scores an option (`llm_agents.backends.base.choice_score`); under `letters`
        the step message letters the actions in an order drawn from (`seed`, the episode, the
        step) (`agents.lettered`), the backend picks a label, and the label's action is played.
        `report_invalid`
        tells the model, in the next step's history, that an answer named no valid action and the
        fallback was played in its place (BALROG's harness does; by default the history shows the
        fallback action alone). `observation`: `image` or `both` say, in the observation's
        place, what the frames the play loop attaches to the step message show (`frames.j2`;
        `both` after the text); `frame_history`: how many past frames come before the current.
        `structured`: every answer is held to the agent's JSON schema of an action
        (`answer_schemas.agent_schema`: `{"action": NAME}`, cot's with its reasoning first),
        the action read from its `action` field.
        """
        self.report_invalid = report_invalid
        self.observation_mode: ObservationMode = observation
        self.frame_history = frame_history
        self.variant = as_variant(variant)
        if history_length < 0:
            raise UserError(f"history_length must be >= 0, got {history_length}")
        self.history_length = history_length
        self.fallback_name = action_names(self.variant)[action_id(fallback_action, self.variant)]
        self.fallback_id = action_id(self.fallback_name, self.variant)
        self.choice_rule = choice_rule
        self.templates_dir = templates_dir
        self.render_observation = (
            _textualizer_renderer(renderer) if isinstance(renderer, str) else renderer
        )
        self.seed = seed
        #: Whether the step message letters the actions (`letters`; `loglik` only).
        self.lettered = choice_rule == "loglik" and choice_scoring == "letters"
        names = action_names(self.variant)
        self.choices = (
            label_choices(len(names))
            if self.lettered
            else ChoiceSet(options=tuple(names), rule=choice_rule, scoring=choice_scoring)
            if choice_rule is not None
            else None
        )
        #: The schema every answer is held to (`--structured-output`); None: free text.
        self.output_schema: OutputSchema | None = (
            agent_schema(self.agent_name, self.variant, DEFAULT_DIFFICULTY) if structured else None
        )
        self.system_message = ChatMessage(
            role="system",
            content=render_template(SYSTEM_TEMPLATE, self.system_context(), templates_dir),
        )
        self._render_step = template_renderer(self.step_template, templates_dir)
        self._episodes: dict[int, _Episode] = {}

    @classmethod
    def from_config(cls, config: AgentSettings) -> Self:
        """The agent an evaluation config describes."""
        return cls(
            config.variant,
            renderer=config.renderer,
            templates_dir=config.templates_dir,
            history_length=config.history_length,
            fallback_action=config.fallback_action,
            choice_rule=config.choice,
            choice_scoring=config.choice_scoring,
            report_invalid=config.report_invalid_answers,
            observation=config.observation,
            frame_history=config.frame_history,
            seed=config.seed,
            structured=config.structured_output,
            **cls.strategy_settings(config),
        )

    @classmethod
    def strategy_settings(cls, config: AgentSettings) -> dict[str, Any]:
        """Constructor keywords a strategy built on this agent reads from the config."""
        return {}

    def system_context(self) -> dict[str, Any]:
        """The variables `system.j2` is rendered with."""
        return {
            "variant": self.variant.value,
            "actions": [spec.model_dump() for spec in action_catalogue(self.variant)],
        }

    def step_context(
        self,
        observation_text: str,
        instruction: str,
        plan: str | None = None,
        history: Sequence[HistoryEntry] = (),
        shown: LetteredOptions | None = None,
    ) -> dict[str, Any]:
        """The variables `step.j2` is rendered with (`shown`: the lettered actions, `letters`)."""
        return {
            "variant": self.variant.value,
            "observation": observation_text,
            "instruction": instruction,
            "plan": plan,
            # The entries themselves, not dicts: Jinja reads `entry.step` as an attribute first
            # and a dict's item only once that lookup has raised, an exception per field that
            # made up half the render (`entry["step"]` still works on an entry).
            "history": list(history),
            "choice_mode": self.choice_rule is not None,
            "lettered": shown.lines() if shown is not None else None,
        }

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """Build the messages of an episode's second step (a placeholder observation after one
        answered step) the way a run builds them, so a broken template of any strategy (the step
        message, a kept reply's stand-in, the demonstrations) fails before any work."""
        slot = _CHECK_SLOT
        self.start_episode(slot, EpisodeStart(instruction, plan, goal))
        try:
            first = StepPrompt(slot=slot, observation=None, messages=[], text=_PLACEHOLDER)
            self.decide(first, ModelOutput(text=self.fallback_name))
            self._close_step(self._episode(slot), "no visible effect")
            self.messages_for(slot, _PLACEHOLDER)
            if self.observation_mode != "text":
                self.frames_text(self._episode(slot))
        finally:
            self.end_episode(slot)

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin a new episode in a slot, forgetting the slot's previous one."""
        self._episodes[slot] = _Episode(start.instruction, start.plan, start.goal, start.episode)

    def end_episode(self, slot: int) -> None:
        """Forget a slot's episode."""
        self._episodes.pop(slot, None)

    def history(self, slot: int) -> list[HistoryEntry]:
        """The slot's recorded actions and outcomes so far (all of them, oldest first)."""
        return list(self._episode(slot).history)

    def _episode(self, slot: int) -> _Episode:
        if slot not in self._episodes:
            raise UserError(f"slot {slot} has no episode; call start_episode({slot}, ...) first")
        return self._episodes[slot]

    def build_messages(self, slot: int, observation: Any) -> tuple[list[ChatMessage], str]:
        """The slot's messages for this observation, and the observation's text.

        Also closes the slot's previous step: its outcome is read off this observation.
        """
        episode = self._episode(slot)
        if episode.pending is not None:
            action, before = episode.pending
            self._close_step(episode, describe_outcome(action, before, observation))
        text = self.shown_observation(episode, observation)
        return self.messages_for(slot, text), text

    def shown_observation(self, episode: _Episode, observation: Any) -> str:
        """The observation's text in the step message: the renderer's, and for an image
        observation what the attached frames show (as many as the play loop sends now)."""
        if self.observation_mode == "text":
            return self.render_observation(observation)
        frames = self.frames_text(episode)
        if self.observation_mode == "image":
            return frames
        return f"{self.render_observation(observation)}\n\n{frames}"

    def frames_text(self, episode: _Episode) -> str:
        """`frames.j2` for the frames sent at the episode's current step."""
        context = {
            "variant": self.variant.value,
            "frames": min(episode.step, self.frame_history) + 1,
        }
        return render_template(FRAMES_TEMPLATE, context, self.templates_dir).strip()

    @staticmethod
    def _close_step(episode: _Episode, outcome: str) -> None:
        """Move the episode's pending action into its history with `outcome`."""
        assert episode.pending is not None
        action, _ = episode.pending
        episode.history.append(
            trusted(HistoryEntry, step=episode.step - 1, action=action, outcome=outcome)
        )
        episode.pending = None

    def messages_for(self, slot: int, observation_text: str) -> list[ChatMessage]:
        """The slot's messages for an observation rendered as `observation_text` (strategies
        built on this one add their turns here)."""
        episode = self._episode(slot)
        recent = episode.history[-self.history_length :] if self.history_length else []
        if self.lettered:
            episode.shown = lettered(
                action_names(self.variant), self.seed, episode.name, episode.step
            )
        context = self.step_context(
            observation_text, episode.instruction, episode.plan, recent, episode.shown
        )
        user = trusted(ChatMessage, role="user", content=self._render_step(context))
        return [self.system_message, user]

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        """The slot's prompt for this observation."""
        messages, text = self.build_messages(slot, observation)
        shown = self._episode(slot).shown
        return StepPrompt(
            slot=slot,
            observation=observation,
            messages=messages,
            text=text,
            options_shown=shown.order if shown is not None else None,
        )

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        """Turn the model's answer to `prompt` into the slot's decision."""
        slot, observation, messages, text = (
            prompt.slot,
            prompt.observation,
            prompt.messages,
            prompt.text,
        )
        answer = output.text
        if self.output_schema is not None:
            answer = answered_action(answer)
        if prompt.options_shown is not None:
            # A label stands for the action listed under it; anything else parses as nothing.
            answer = LetteredOptions(order=prompt.options_shown).option_of(output.text) or ""
        parsed = parse_action(answer, self.variant, prompt=[m.content for m in messages])
        fallback = parsed.action is None
        action = self.fallback_id if parsed.action is None else parsed.action
        name = self.fallback_name if parsed.name is None else parsed.name
        episode = self._episodes[slot]
        shown = f"{name} (your answer named no valid action; {name} was played)"
        episode.pending = (shown if fallback and self.report_invalid else name, observation)
        episode.step += 1
        return trusted(
            Decision,
            slot=slot,
            action=action,
            name=name,
            parse=parsed,
            output=output,
            observation_text=text,
            prompt_hash=messages_hash(messages),
            fallback_used=fallback,
            options_shown=prompt.options_shown,
        )
