"""What `plan-score` writes: each plan's steps as read into skills, and its score by execution."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from llm_agents.run_data.metrics import SuccessRate


class StepReading(BaseModel):
    """One plan step and the catalogue skills it was read as."""

    model_config = ConfigDict(frozen=True)

    number: int = Field(ge=1)
    """The step's place in the plan, from 1."""
    text: str
    """The step as the plan writes it (its number left off)."""
    skills: tuple[str, ...] = ()
    """The skills it reads as, in the catalogue's form, played in this order; empty: unread."""
    unread: str | None = None
    """Why the step, or a part of it ("Find cow, kill it": the first part), reads as no skill
    (it names nothing the catalogue knows); None when all of it was read."""
    notes: tuple[str, ...] = ()
    """How the plan around it shaped its reading: a count read from the later steps, a crafted
    table that a later step places."""


class FirstFailure(BaseModel):
    """Where the episodes of a plan that failed first went wrong, and how many did so."""

    model_config = ConfigDict(frozen=True)

    step: int | None
    """The plan step (from 1) whose skill failed; None: every step played and the goal was not
    met, or nothing was read."""
    skill: str | None
    """The skill that failed, in the catalogue's form."""
    reason: str
    """Why: the missing material, tool or station, the step budget spent, the game ending, or
    the goal not met after the last step."""
    episodes: int = Field(ge=1)
    """Episodes that failed here, for this reason."""


class PlanScore(BaseModel):
    """One candidate plan of one instruction text, played in `worlds` seeded worlds."""

    instruction: str
    """The instruction text, as the plans file keys it."""
    candidate: int = Field(ge=0)
    """The plan's index among the text's candidates (0 for an official plans file)."""
    plan: str
    """The plan as given."""
    steps: list[StepReading]
    """Every step, read or not."""
    goal_id: str
    """The dataset goal the text phrases."""
    split: str
    """The dataset split the goal belongs to."""
    success: SuccessRate
    """Episodes whose goal the checker saw met, with the 95% Wilson interval over the worlds."""
    env_steps: int = Field(ge=0)
    """Environment steps played over all its episodes."""
    failures: list[FirstFailure] = Field(default_factory=list)
    """The first failures of its failed episodes, commonest first."""
    goal_reached: float = 0.0
    """The share of the goal's required achievements its episodes reached, on average (a goal
    without required achievements: its success rate)."""
    played: float = 0.0
    """The share of its skills that finished before each episode ended, on average."""
    breaks: list[str] = Field(default_factory=list)
    """Its steps, played or not, that earn an achievement the instruction forbids
    (`verdict.breaking_steps`)."""
    met_without_acting: bool = False
    """The text's goal is met by doing nothing in at least one of do-nothing worlds: no plan of
    it says anything."""
    held_out: SuccessRate | None = None
    """Its success in the held-out worlds, where a text's first and best candidates are played
    after the choice; None for the others."""

    @property
    def empty(self) -> bool:
        """No step read as a skill."""
        return not any(step.skills for step in self.steps)

    @property
    def excluded(self) -> str | None:
        """Why no export may use it (as an answer to learn or to avoid), or None."""
        if self.met_without_acting:
            return "met_without_acting"
        if self.empty:
            return "empty"
        if self.breaks:
            return "breaks_instruction"
        return None

    @property
    def read(self) -> int:
        """Steps read: as at least one skill, or as none because a later step does their work."""
        return sum(1 for step in self.steps if step.skills or step.unread is None)

    @property
    def unread(self) -> int:
        """Steps that name nothing the catalogue knows."""
        return len(self.steps) - self.read
