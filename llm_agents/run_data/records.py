"""Typed records of an evaluation run: one `StepRecord` per agent step, one `EpisodeRecord` per
finished episode (with a `SkillRecord` per decision of the `skills` agent). `llm_agents.run_data.store` owns the files they live in.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, Field, computed_field, model_validator

from env.goals import Category, ScenarioClass
from env.termination import TERMINATIONS
from llm_agents.run_data.readings import Grounding

__all__ = [
    "EPISODE_ENDS",
    "NOT_STARTED",
    "SKILL_STAGE",
    "EpisodeRecord",
    "SkillOutcome",
    "SkillRecord",
    "StepRecord",
]

NOT_STARTED = "not_started"
"""How an episode ends that the agent could not start (it read no goal from the instruction):
never played, counted as a failure."""
EPISODE_ENDS: tuple[str, ...] = (*TERMINATIONS, NOT_STARTED)
"""Every way a recorded episode ends."""


SKILL_STAGE = "skill"
"""The `parse_stage` of a step whose action a running skill's controller chose (`skills`): no
answer was read at that step."""
SkillOutcome = Literal[
    "running", "succeeded", "failed", "out_of_steps", "interrupted", "invalid", "unfinished"
]
"""How a decision of the `skills` agent ended: still `running`; its skill did what it says;
`failed` (could not start or go on, the reason says why); `out_of_steps` (its step budget ran
out); `interrupted` (a creature attacked); `invalid` (the answer named no skill of the
catalogue, the reason says why); `unfinished` (the episode ended while it ran)."""


def _finished(label: str) -> str:
    if label not in EPISODE_ENDS:
        raise ValueError(f"termination must be one of {', '.join(EPISODE_ENDS)}, not {label!r}")
    return label


FinishedTermination = Annotated[str, AfterValidator(_finished)]
"""The label of `env.termination.Termination` a finished episode ended with, or `NOT_STARTED`."""


class StepRecord(BaseModel):
    """One agent step of one episode: what the model saw, said and did, and what followed."""

    episode_id: str
    """The episode this step belongs to (matches `EpisodeRecord.episode_id`)."""
    step: int = Field(ge=0)
    """Index of the step within its episode, from 0."""
    observation: str
    """The observation text the agent was shown."""
    frame_png: str | None = None
    """`--observation image|both`: the frame the model was sent at this step, the PNG file
    exactly as sent, base64-encoded; the message carried it after the frames of up to
    `frame_history` steps before (theirs, recorded on those steps)."""
    prompt_hash: str
    """Hash of the full prompt, to spot identical prompts without storing each one."""
    raw_output: str
    """The model's answer text exactly as returned (reasoning removed)."""
    reasoning: str | None = None
    """The model's reasoning text, when the backend returns one."""
    action_name: str
    """Name of the action taken, as in the variant's craftax `Action` enum (`MAKE_WOOD_PICKAXE`)."""
    action_id: int = Field(ge=0)
    """Id of the action taken in the variant's craftax `Action` enum."""
    parse_stage: str
    """Which parser stage produced the action (the parser names its stages)."""
    fallback_used: bool
    """True when no action could be parsed and the fallback action was taken instead."""
    reward: float
    """Environment reward for this step."""
    done: bool
    """True when the episode ended on this step."""
    new_achievements: list[str] = Field(default_factory=list)
    """Achievement names first unlocked on this step."""
    prompt_tokens: int = Field(0, ge=0)
    """Tokens in the prompt."""
    computed_prompt_tokens: int | None = Field(None, ge=0)
    """Prompt tokens the backend computed for this answer, the rest reused from its prefix
    cache (hf's prefix store, vLLM's prefix caching); None where the backend does not say."""
    completion_tokens: int = Field(0, ge=0)
    """Tokens generated, reasoning included."""
    latency_s: float = Field(0.0, ge=0.0)
    """Wall time of the model call (for a call carrying many conversations: the call's time)."""
    finish_reason: str = "stop"
    """How the answer ended: `stop`, `length` (hit max_tokens), `choice` or `error`."""
    error: str | None = None
    """Why the backend failed, after its retries; the step's action is then the fallback and the
    episode does not count (it is re-run on resume)."""
    cached: bool = False
    """True when the answer came from the response cache."""
    followups: int = Field(0, ge=0)
    """Extra requests made for this answer (e.g. an answer-only follow-up after long reasoning)."""
    options_shown: list[str] | None = None
    """`--choice-scoring letters`: the options in the order the prompt lettered them, the first
    under `A` (`raw_output` is the label the model chose); None under other rules."""
    skill: str | None = None
    """`skills`: the skill chosen at this step, without counts and places (`collect wood`,
    `invalid`); None on the steps a chosen skill carries on (`parse_stage` `skill`) and for
    other agents."""


class SkillRecord(BaseModel):
    """One decision of the `skills` agent: the skill the model chose, what became of it, and
    the model's input and output."""

    index: int = Field(ge=0)
    """The decision's place in its episode, from 0."""
    step: int = Field(ge=0)
    """The episode step it was made at."""
    skill: str | None
    """The skill as the catalogue writes it (`collect wood 3`); None when the answer named none."""
    label: str
    """The skill without its counts and places (`collect wood`), `invalid` when none."""
    outcome: SkillOutcome
    reason: str | None = None
    """Why it failed, was invalid, ran out of steps or was interrupted (what the model is told)."""
    prerequisite: bool = False
    """It failed before its first step: a material, tool or station it needs was missing."""
    steps: int = Field(0, ge=0)
    """Environment steps the skill took."""
    parse_stage: str
    """The skill parser's stage (`field`, `exact`, `invalid`)."""
    prompt: str
    """The model's input: the decision's user message."""
    answer: str
    """The model's output as returned."""


class EpisodeRecord(BaseModel):
    """The outcome of one episode: which goal, under which seed, and how it ended."""

    episode_id: str
    """Unique id of the episode within the run."""
    goal_id: str
    """Id of the CrafText goal the instruction states."""
    instruction: str
    """The instruction text the agent was given."""
    instruction_variant: int = Field(ge=0)
    """Which wording of the goal: 0 the original, 1..n one of its n paraphrases (as many as the
    dataset gives it: 4, 5 or 10 in the official data)."""
    category: Category
    """The goal set the episode counts towards."""
    scenario_class: ScenarioClass = "Achievements"
    """The goal's scenario class (the paper's Table 2 rows: Achievements, Conditional,
    Localization, Build); records written before Medium had only achievements goals."""
    seed: int
    """Environment seed of the episode."""
    episode_index: int = Field(ge=0)
    """Position of the episode in the run's schedule, from 0."""
    success: bool
    """True when the goal was met."""
    steps: int = Field(ge=0)
    """Agent steps taken."""
    termination: FinishedTermination
    """Why the episode ended."""
    episode_return: float
    """Sum of environment rewards."""
    invalid_actions: int = Field(0, ge=0)
    """Steps on which no action could be parsed and the fallback action was taken."""
    prompt_tokens: int = Field(0, ge=0)
    """Prompt tokens over all steps."""
    computed_prompt_tokens: int | None = Field(None, ge=0)
    """Prompt tokens the backend computed over all steps (the rest reused from its prefix
    cache); None when some step's backend did not say."""
    completion_tokens: int = Field(0, ge=0)
    """Generated tokens over all steps, reasoning included."""
    achievements: list[str] = Field(default_factory=list)
    """Achievement names unlocked during the episode, in order."""
    plan_given: bool = False
    """True when the agent was given a plan for the goal."""
    goal_at_game_over: Literal["death", "timeout"] | None = None
    """Set when the goal was completed on the step the game ended (the episode's last step): how
    the game ended (`timeout`: Craftax's own time limit). Recorded under either success rule, so
    `report --success-rule` can re-score the episode both ways without replaying it."""
    goal_in_new_world: Literal["death", "timeout"] | None = None
    """Set when, on the step the game ended, the goal was met in the world Craftax's automatic
    reset starts (what the official wrapper checks there, a success under `official`): how the
    game ended. Recorded under either rule, like `goal_at_game_over`; records written before it
    existed leave it unset (their runs scored that step as no success under `official`)."""
    grounding: Grounding | None = None
    """The goal the agent read from the instruction before playing (`guided`); None for agents
    that read none."""
    grounding_correct: bool | None = None
    """Whether `grounding` is exactly the dataset's goal; None without a grounding."""
    reset_key: list[int] | None = Field(None, min_length=2, max_length=2)
    """The raw PRNG key (two uint32 words) the episode's world was reset with; None in records
    written before it was stored (replays then derive it the way the runner did)."""
    code: str | None = None
    """The version of the code that played the episode (`code_version`); None in records
    written before it was stored."""
    model_calls: int | None = Field(None, ge=0)
    """Steps whose prompt was sent to the model (zero-shot: every step; skills: one per
    decision; the expert: none); None in records written before it was counted."""
    skills: list[SkillRecord] | None = None
    """`skills`: every decision of the episode, in order; None for other agents."""

    # A computed field is written to JSON but ignored on reading, so the rate can never
    # disagree with the count it comes from.
    @computed_field  # type: ignore[prop-decorator]
    @property
    def invalid_action_rate(self) -> float:
        """Share of steps whose action was the fallback (0 for an episode without steps)."""
        return self.invalid_actions / self.steps if self.steps else 0.0

    @model_validator(mode="after")
    def _consistent(self) -> EpisodeRecord:
        if self.success != (self.termination == "success"):
            raise ValueError(f"success={self.success} contradicts termination={self.termination!r}")
        for name, ending in (
            ("goal_at_game_over", self.goal_at_game_over),
            ("goal_in_new_world", self.goal_in_new_world),
        ):
            if ending is not None and self.termination not in ("success", ending):
                raise ValueError(f"{name}={ending!r} contradicts termination={self.termination!r}")
        if None not in (self.goal_at_game_over, self.goal_in_new_world) and (
            self.goal_at_game_over != self.goal_in_new_world
        ):
            raise ValueError("goal_at_game_over and goal_in_new_world name one game end")
        if (self.grounding is None) != (self.grounding_correct is None):
            raise ValueError("grounding_correct is set exactly when there is a grounding")
        if self.termination == NOT_STARTED and (
            self.steps or self.grounding is None or self.grounding.reading is not None
        ):
            raise ValueError(
                "only an episode whose grounding was invalid ends unstarted, at 0 steps"
            )
        if self.invalid_actions > self.steps:
            raise ValueError(f"invalid_actions={self.invalid_actions} exceeds steps={self.steps}")
        return self
