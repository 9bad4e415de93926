"""A model's reading of an instruction as a typed goal, and the outcome of asking for one.

A reading is the dataset's goal of its kind without the dataset's bookkeeping (id, split,
texts): both build on the kind's parameters, declared once in `env.goals`
(`AchievementsParameters`, ...), so a reading is scored against the record field by field.
Achievements goals (all of EASY, part of Medium) are sets of required and forbidden achievements
(`AchievementsReading`); the placing goals of Medium and Hard are their typed parameters (block,
side, distance, size, counts, ...). `GoalReading` is their union, told apart by `kind` as the
goals are; `reading_of` turns a dataset goal into the reading it should be read as.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Tag,
    model_validator,
)

from env.goals import (
    AchievementsParameters,
    AnyGoal,
    BuildLineParameters,
    BuildSquareParameters,
    BuildStarParameters,
    ConditionalPlacingParameters,
    GoalKind,
    LocalizationParameters,
    kind_of,
)

__all__ = [
    "AchievementsReading",
    "BuildLineReading",
    "BuildSquareReading",
    "BuildStarReading",
    "ConditionalPlacingReading",
    "EasyReading",
    "GoalReading",
    "Grounding",
    "LocalizationReading",
    "PlacingReading",
    "reading_of",
]


class _Reading(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    def parameters(self) -> dict[str, object]:
        """The typed parameters, each scored on its own (not `kind`; for achievements goals
        none: their fields are sets, scored by `atoms`)."""
        return {name: getattr(self, name) for name in type(self).model_fields if name != "kind"}


class AchievementsReading(AchievementsParameters, _Reading):
    """An achievements goal as read: achievements to reach and achievements to avoid."""

    @model_validator(mode="before")
    @classmethod
    def _legacy_scenario(cls, value: Any) -> Any:
        # Runs written while only EASY goals were typed marked readings `scenario: easy`.
        if isinstance(value, dict) and value.get("scenario") == "easy":
            return {key: item for key, item in value.items() if key != "scenario"}
        return value

    @model_validator(mode="after")
    def _consistent(self) -> AchievementsReading:
        if not self.required:
            raise ValueError("a goal requires at least one achievement")
        if overlap := set(self.required) & set(self.forbidden):
            raise ValueError(f"both required and forbidden: {', '.join(sorted(overlap))}")
        return self

    def parameters(self) -> dict[str, object]:
        return {}

    def atoms(self) -> dict[str, frozenset[str]]:
        """Each scored field as a set: what precision and recall are counted over."""
        return {"required": frozenset(self.required), "forbidden": frozenset(self.forbidden)}


EasyReading = AchievementsReading
"""The name of `AchievementsReading` while EASY's were the only goals typed."""


class ConditionalPlacingReading(ConditionalPlacingParameters, _Reading):
    __doc__ = ConditionalPlacingParameters.__doc__


class LocalizationReading(LocalizationParameters, _Reading):
    __doc__ = LocalizationParameters.__doc__


class BuildLineReading(BuildLineParameters, _Reading):
    __doc__ = BuildLineParameters.__doc__


class BuildSquareReading(BuildSquareParameters, _Reading):
    __doc__ = BuildSquareParameters.__doc__


class BuildStarReading(BuildStarParameters, _Reading):
    __doc__ = BuildStarParameters.__doc__


PlacingReading = (
    ConditionalPlacingReading
    | LocalizationReading
    | BuildLineReading
    | BuildSquareReading
    | BuildStarReading
)
"""The readings of the goals that are not achievements goals."""

#: Each goal kind's reading class (its fields are the goal's parameters, same names), keyed by
#: the kind its parameters declare.
READING_CLASSES: dict[GoalKind, type[_Reading]] = {
    reading.model_fields["kind"].default: reading
    for reading in (
        AchievementsReading,
        ConditionalPlacingReading,
        LocalizationReading,
        BuildLineReading,
        BuildSquareReading,
        BuildStarReading,
    )
}


GoalReading = Annotated[
    Annotated[AchievementsReading, Tag("achievements")]
    | Annotated[ConditionalPlacingReading, Tag("conditional_placing")]
    | Annotated[LocalizationReading, Tag("localization_placing")]
    | Annotated[BuildLineReading, Tag("build_line")]
    | Annotated[BuildSquareReading, Tag("build_square")]
    | Annotated[BuildStarReading, Tag("build_star")],
    Discriminator(kind_of),
]
"""Any goal as read, told apart by its `kind`."""


def reading_of(goal: AnyGoal) -> GoalReading:
    """The dataset record's goal as a reading: the ground truth a model's reading is scored by."""
    reading = READING_CLASSES[goal.kind]
    fields = {name: getattr(goal, name) for name in reading.model_fields if name != "kind"}
    return reading(**fields)  # type: ignore[return-value]


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
