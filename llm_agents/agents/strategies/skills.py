"""The skills agent (`skills`): the model chooses the next subgoal, the expert's controllers carry
it out.

At each decision the model sees the instruction, the rendered observation (inventory included)
and the outcomes of its last skills (`skills.j2`), and names one skill of the catalogue
(`skill_catalogue`). With `--choice loglik` the backend picks among the skills valid now; with
`--choice guided` the model's own answer is held to the catalogue's grammar (every skill and
parameter it offers, `SkillOffer.grammar`) by constrained decoding: it may still name a skill
that cannot start, and is told why, but never one the catalogue lacks. With `--skill-demos K`
each request first shows K worked skill sequences of other goals (`skill_demos`). The skill
then runs (`skill_runner`), sending nothing to the model, until it succeeds, fails with a reason,
is interrupted by an attack or spends its `skill_steps` budget; then the model chooses again.
An answer that names no skill of the catalogue, or a skill that cannot start (a missing
material, tool or station: prerequisites are not solved for the model), is a decision that
plays one NOOP step, and the model is told why at the next. The agent stops asking after
`GIVE_UP` invalid answers in a row, or once the model has chosen the same skill `stuck_after`
times, each ending before its first step, with no step taken by any skill in between (a model
stuck on a skill it cannot start, as Qwen2.5-Coder-0.5B's `place stone` with no stone, or on
one with nothing to do, as Qwen2.5-Coder-1.5B's `go to stone` beside stone, would otherwise pay
a call per step for the rest of the episode): the episode plays NOOP to its end, a failure whose reason is in its last
decision's record. Every decision is recorded (`run_data.records.SkillRecord`) on its step and,
in full, on the episode.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from env.dataset import load_dataset
from env.errors import UserError
from env.variant import Variant, as_variant
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.answers.parser import ParseResult
from llm_agents.agents.expert.navigation import ExpertEpisode
from llm_agents.agents.grounding import training_examples
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION
from llm_agents.agents.skills.catalogue import SkillOffer, parse_skill, skill_offer
from llm_agents.agents.skills.demos import SkillDemo, demos_for, skill_demos
from llm_agents.agents.skills.runner import Finished, SkillRun, valid_now
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt, messages_hash
from llm_agents.backends.base import ChatMessage, ChoiceRule, ChoiceScoring, ChoiceSet, ModelOutput
from llm_agents.run_data.records import SKILL_STAGE, SkillRecord
from prompts import render_blocks

if TYPE_CHECKING:
    from env.goals import AnyGoal, Difficulty
    from llm_agents.agents.registry import AgentSettings

SKILLS_TEMPLATE = "skills.j2"
#: Invalid answers in a row after which an episode's model is asked nothing more.
GIVE_UP = 3
#: The end of a reason after which the agent asked nothing more (`skill_errors` reads it).
STOPPED = "no more skills are asked"
_CHECK_SLOT = -1


@dataclass
class _Episode:
    instruction: str
    demos: tuple[SkillDemo, ...] = ()
    """The worked skill sequences this episode's requests show (none of its own goal)."""
    expert: ExpertEpisode = field(default_factory=lambda: ExpertEpisode((), ()))
    """The controllers' memory of the map (no goal: the model's skills are theirs)."""
    run: SkillRun | None = None
    record: SkillRecord | None = None
    """The decision in progress."""
    history: list[SkillRecord] = field(default_factory=list)
    closed: SkillRecord | None = None
    """A decision closed by this step's observation, not yet handed to the runner."""
    pending: str = "NOOP"
    """The action a running skill chose for this step."""
    invalid_in_a_row: int = 0
    stopped: bool = False


class SkillsAgent:
    """Asks the model for a skill whenever none is running; the controllers play it."""

    protocol_version: ClassVar[int] = AGENT_PROTOCOL_VERSION
    needs_model: ClassVar[bool] = True
    templates: ClassVar[tuple[str, ...]] = (SKILLS_TEMPLATE,)
    # With --choice each request carries the skills valid now (`StepPrompt.choices`).
    choices: ClassVar[None] = None

    def __init__(
        self,
        variant: Variant | str = Variant.FULL,
        difficulty: Difficulty = "easy",
        renderer: str = "objects",
        templates_dir: str | Path | None = None,
        history_length: int = 5,
        skill_steps: int = 60,
        stuck_after: int = 3,
        choice_rule: ChoiceRule | None = None,
        choice_scoring: ChoiceScoring = "sum",
        demos: tuple[SkillDemo, ...] = (),
        shown_demos: int = 0,
    ):
        self.variant = as_variant(variant)
        self.offer: SkillOffer = skill_offer(self.variant, difficulty)
        self.renderer = renderer
        self.templates_dir = templates_dir
        self.history_length = history_length
        self.skill_steps = skill_steps
        self.stuck_after = stuck_after
        self.choice_rule = choice_rule
        self.choice_scoring = choice_scoring
        self.demos = demos
        self.shown_demos = shown_demos
        #: `--choice guided`: the catalogue's grammar, the same at every request.
        self.grammar = (
            ChoiceSet(options=self.offer.grammar(), rule="guided")
            if choice_rule == "guided"
            else None
        )
        self.fallback_id = action_id("NOOP", self.variant)
        self._render = importlib.import_module("textualizer").render
        self._episodes: dict[int, _Episode] = {}

    @classmethod
    def from_config(cls, config: AgentSettings) -> SkillsAgent:
        return cls(
            config.variant,
            difficulty=config.difficulty,
            renderer=config.renderer,
            templates_dir=config.templates_dir,
            history_length=config.history_length,
            skill_steps=config.skill_steps,
            stuck_after=config.stuck_after,
            choice_rule=config.choice,
            choice_scoring=config.choice_scoring,
            demos=training_demos(config.dataset, config.variant, config.difficulty)
            if config.skill_demos
            else (),
            shown_demos=config.skill_demos,
        )

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin an episode; the instruction text is the model's to read. The goal record is
        read only to keep its own demonstrations out of the worked sequences shown."""
        self._episodes[slot] = _Episode(
            start.instruction, self._demos(start.instruction, start.goal)
        )

    def _demos(self, text: str, goal: AnyGoal | None) -> tuple[SkillDemo, ...]:
        if not self.shown_demos:
            return ()
        if goal is None:
            raise ValueError("skill demonstrations are chosen knowing the text's goal: pass it")
        return demos_for(text, goal, self.demos, self.shown_demos)

    def end_episode(self, slot: int) -> None:
        self._episodes.pop(slot, None)

    def _episode(self, slot: int) -> _Episode:
        if slot not in self._episodes:
            raise UserError(f"slot {slot} has no episode; call start_episode({slot}, ...) first")
        return self._episodes[slot]

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: AnyGoal | None = None
    ) -> None:
        """Render a decision's request after one recorded decision, as a run builds it."""
        episode = _Episode(instruction, self._demos(instruction, goal))
        episode.history.append(
            SkillRecord(
                index=0,
                step=0,
                skill="noop",
                label="noop",
                outcome="succeeded",
                steps=1,
                parse_stage="exact",
                prompt="",
                answer="noop",
            )
        )
        self._messages(episode, "(observation)", ["noop"])

    def _messages(self, episode: _Episode, text: str, options: list[str]) -> list[ChatMessage]:
        recent = episode.history[-self.history_length :] if self.history_length else []
        context = {
            "variant": self.variant.value,
            "skills": self.offer.forms(),
            "instruction": episode.instruction,
            "observation": text,
            "history": [
                {
                    "skill": r.skill or f"(invalid answer: {r.answer.strip()[:80]!r})",
                    "outcome": r.outcome,
                    "reason": r.reason,
                    "steps": r.steps,
                }
                for r in recent
            ],
            "choice_mode": self.choice_rule == "loglik",
            "grammar_mode": self.choice_rule == "guided",
            "options": options,
            "demos": [{"instruction": d.instruction, "skills": d.skills} for d in episode.demos],
        }
        blocks = render_blocks(SKILLS_TEMPLATE, context, self.templates_dir)
        return [ChatMessage(role=role, content=content) for role, content in blocks]

    # ------------------------------------------------------------------ one step of one slot

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        """The running skill's step (sent nowhere), or once none runs, the model's request."""
        episode = self._episode(slot)
        episode.expert.world.update(observation)
        text = str(self._render(observation, self.renderer))
        silent = StepPrompt(slot=slot, observation=observation, messages=[], text=text)
        if episode.stopped:
            episode.pending = "NOOP"
            return silent
        if episode.run is not None:
            result = episode.run.advance(observation)
            if isinstance(result, str):
                episode.pending = result
                return silent
            self._close(episode, result)
        options = (
            valid_now(self.offer, episode.expert, observation)
            if self.choice_rule == "loglik"
            else []
        )
        choices = (
            ChoiceSet(options=tuple(options), rule="loglik", scoring=self.choice_scoring)
            if self.choice_rule == "loglik"
            else self.grammar
        )
        messages = self._messages(episode, text, options)
        return StepPrompt(
            slot=slot, observation=observation, messages=messages, text=text, choices=choices
        )

    def _close(self, episode: _Episode, finished: Finished) -> None:
        assert episode.record is not None and episode.run is not None
        record = episode.record.model_copy(
            update={
                "outcome": finished.outcome,
                "reason": finished.reason,
                "steps": episode.run.steps,
            }
        )
        episode.history.append(record)
        episode.closed, episode.record, episode.run = record, None, None

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        """The running skill's action, or the skill read from the model's answer started."""
        episode = self._episode(prompt.slot)
        closed, episode.closed = episode.closed, None
        if not prompt.messages:
            touched: tuple[SkillRecord, ...] = ()
            if episode.record is not None and episode.run is not None:
                episode.record = episode.record.model_copy(update={"steps": episode.run.steps})
                touched = (episode.record,)
            return self._decision(prompt, output, episode.pending, SKILL_STAGE, touched)
        if output.finish_reason == "error":
            # The backend failed, not the model: the runner aborts the episode.
            return self._decision(prompt, output, "NOOP", "invalid", (), fallback=True)
        user = prompt.messages[-1].content
        parsed = parse_skill(output.text, self.offer, prompt=[m.content for m in prompt.messages])
        base = SkillRecord(
            index=len(episode.history),
            step=prompt.observation.step,
            skill=None if parsed.skill is None else parsed.skill.text,
            label="invalid" if parsed.skill is None else parsed.skill.label,
            outcome="running",
            parse_stage=parsed.stage,
            prompt=user,
            answer=output.text,
        )
        earlier = () if closed is None else (closed,)
        if parsed.skill is None:
            episode.invalid_in_a_row += 1
            reason = f"not a skill of the catalogue: {parsed.reason}"
            if episode.invalid_in_a_row >= GIVE_UP:
                episode.stopped = True
                reason += f"; {GIVE_UP} invalid answers in a row: {STOPPED}"
            record = base.model_copy(update={"outcome": "invalid", "reason": reason})
            episode.history.append(record)
            return self._decision(
                prompt, output, "NOOP", "invalid", (*earlier, record), fallback=True
            )
        episode.invalid_in_a_row = 0
        run = SkillRun(parsed.skill, episode.expert, prompt.observation, self.skill_steps)
        why = run.why_not()
        result: str | Finished = Finished("failed", why) if why else run.advance(prompt.observation)
        if isinstance(result, Finished):
            record = base.model_copy(
                update={
                    "outcome": result.outcome,
                    "reason": result.reason,
                    "prerequisite": bool(why),
                }
            )
            if self._stuck(episode.history, record):
                episode.stopped = True
                stop = f"chosen {self.stuck_after} times with no step taken since: {STOPPED}"
                reason = stop if result.reason is None else f"{result.reason}; {stop}"
                record = record.model_copy(update={"reason": reason})
            episode.history.append(record)
            return self._decision(prompt, output, "NOOP", parsed.stage, (*earlier, record))
        episode.run = run
        episode.record = base.model_copy(update={"steps": run.steps})
        return self._decision(prompt, output, result, parsed.stage, (*earlier, episode.record))

    def _stuck(self, history: list[SkillRecord], record: SkillRecord) -> bool:
        """Whether `record`, a skill that ended before its first step (it failed, or had
        nothing to do: `go to stone` beside stone), is the `stuck_after`-th such end of that
        skill since a skill last took a step. Other decisions in between, that took no step
        either, change nothing (Qwen-1.5B alternated `craft wood_pickaxe` and `collect iron`,
        both failing, for as long as it was asked)."""
        if not self.stuck_after or record.outcome not in ("failed", "succeeded"):
            return False
        repeats = 1
        for earlier in reversed(history):
            if earlier.steps:
                break
            repeats += earlier.skill == record.skill and earlier.outcome in ("failed", "succeeded")
        return repeats >= self.stuck_after

    def _decision(
        self,
        prompt: StepPrompt,
        output: ModelOutput,
        name: str,
        stage: str,
        skills: tuple[SkillRecord, ...],
        fallback: bool = False,
    ) -> Decision:
        action = action_id(name, self.variant)
        return Decision(
            slot=prompt.slot,
            action=action,
            name=name,
            parse=ParseResult(action=action, name=name, stage=stage, raw=output.text),
            output=output,
            observation_text=prompt.text,
            prompt_hash=messages_hash(prompt.messages),
            fallback_used=fallback,
            skills=skills,
        )


def training_demos(
    dataset: str | None, variant: Variant, difficulty: Difficulty
) -> tuple[SkillDemo, ...]:
    """The worked skill sequences of `difficulty`'s training goals in `dataset` (the list a run
    offers; its digest is part of the run's identity)."""
    return skill_demos(training_examples(load_dataset(dataset), difficulty), variant, difficulty)
