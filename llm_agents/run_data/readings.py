"""A model's reading of an instruction as a typed goal, and the outcome of asking for one.

A reading has the shape of the dataset's goal for its scenario, so it can be scored against the
record field by field. EASY goals are sets of required and forbidden achievements
(`EasyReading`). A scenario's reading exposes its fields as sets of atoms (`atoms()`), which is
all scoring needs: the typed goals of other scenarios join by adding a reading class with a
`scenario` literal of their own to `GoalReading` (then a union discriminated by `scenario`) and a
case to `reading_of`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, field_validator, model_validator

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS
from env.errors import UserError
from env.goals import AnyGoal, Goal

__all__ = ["EasyReading", "GoalReading", "Grounding", "reading_of"]


class EasyReading(BaseModel):
    """An EASY goal as read: achievements to reach and achievements to avoid."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    scenario: Literal["easy"] = "easy"
    """The CrafText scenario whose goal shape this is."""
    required: tuple[str, ...]
    """Achievement names that must all be reached, in achievement-id order."""
    forbidden: tuple[str, ...] = ()
    """Achievement names that must not be reached, in achievement-id order."""

    @field_validator("required", "forbidden")
    @classmethod
    def _known(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [name for name in names if name not in ACHIEVEMENT_IDS]
        if unknown:
            raise ValueError(f"unknown achievements {unknown}; known: {', '.join(ACHIEVEMENTS)}")
        # As in the dataset's goals: sets, kept in id order so equal readings compare equal.
        return tuple(sorted(set(names), key=ACHIEVEMENT_IDS.__getitem__))

    @model_validator(mode="after")
    def _consistent(self) -> EasyReading:
        if not self.required:
            raise ValueError("a goal requires at least one achievement")
        if overlap := set(self.required) & set(self.forbidden):
            raise ValueError(f"both required and forbidden: {', '.join(sorted(overlap))}")
        return self

    def atoms(self) -> dict[str, frozenset[str]]:
        """Each scored field as a set: what precision and recall are counted over."""
        return {"required": frozenset(self.required), "forbidden": frozenset(self.forbidden)}


GoalReading = EasyReading
"""Every scenario's reading; one class while only EASY goals are typed."""


def reading_of(goal: AnyGoal) -> GoalReading:
    """The dataset record's goal as a reading: the ground truth a model's reading is scored by."""
    if goal.scenario != "easy" or not isinstance(goal, Goal):
        raise UserError(
            f"goal {goal.id!r} is a {goal.scenario} goal, which has no typed reading yet "
            "(only EASY goals can be grounded)"
        )
    return EasyReading(required=goal.required, forbidden=goal.forbidden)


class Grounding(BaseModel):
    """What a model's answer to the grounding prompt was read as: a goal, or `invalid` and why.
    Nothing is guessed: an answer that is not a well-formed goal is invalid."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    outcome: Literal["valid", "invalid"]
    """`valid` when the answer held a well-formed goal."""
    stage: Literal["json", "fenced", "embedded", "none"]
    """Where the JSON object was found: the whole answer (`json`), a fenced code block
    (`fenced`), the first `{...}` inside other text (`embedded`), or nowhere (`none`)."""
    reading: GoalReading | None = None
    """The goal read; None when invalid."""
    reason: str | None = None
    """Why the answer is invalid (one line); None when valid."""
    raw: str
    """The model's answer as returned."""

    @model_validator(mode="after")
    def _reading_iff_valid(self) -> Grounding:
        if (self.outcome == "valid") != (self.reading is not None):
            raise ValueError("a valid grounding has a reading, an invalid one none")
        if (self.outcome == "invalid") != (self.reason is not None):
            raise ValueError("an invalid grounding says why, a valid one does not")
        return self

    def matches(self, truth: GoalReading) -> bool:
        """True when the reading is exactly the goal."""
        return self.reading == truth
