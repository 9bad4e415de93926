"""A model's reading of an instruction as a typed goal, and the outcome of asking for one.

A reading has the shape of the dataset's goal of its kind (`env.goals`), without the dataset's
bookkeeping (id, split, texts), so it can be scored against the record field by field.
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
    Field,
    Tag,
    field_validator,
    model_validator,
)

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS
from env.goals import AnyGoal, CrossType, GoalKind, Side, kind_of

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


class AchievementsReading(_Reading):
    """An achievements goal as read: achievements to reach and achievements to avoid."""

    kind: Literal["achievements"] = "achievements"
    required: tuple[str, ...]
    """Achievement names that must all be reached, in achievement-id order."""
    forbidden: tuple[str, ...] = ()
    """Achievement names that must not be reached, in achievement-id order."""

    @model_validator(mode="before")
    @classmethod
    def _legacy_scenario(cls, value: Any) -> Any:
        # Runs written while only EASY goals were typed marked readings `scenario: easy`.
        if isinstance(value, dict) and value.get("scenario") == "easy":
            return {key: item for key, item in value.items() if key != "scenario"}
        return value

    @field_validator("required", "forbidden")
    @classmethod
    def _known(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [name for name in names if name not in ACHIEVEMENT_IDS]
        if unknown:
            raise ValueError(f"unknown achievements {unknown}; known: {', '.join(ACHIEVEMENTS)}")
        # As in the dataset's goals: sets, kept in id order so equal readings compare equal.
        return tuple(sorted(set(names), key=ACHIEVEMENT_IDS.__getitem__))

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


class ConditionalPlacingReading(_Reading):
    """Collect an item, then have blocks of a kind on the map."""

    kind: Literal["conditional_placing"] = "conditional_placing"
    collect: str
    """The inventory item counted (lower case, e.g. `iron`)."""
    collect_count: int = Field(ge=0)
    place: str
    """The block that must stand on the map (Craftax block name)."""
    place_count: int = Field(ge=0)


class LocalizationReading(_Reading):
    """Place a block at a side and distance from another."""

    kind: Literal["localization_placing"] = "localization_placing"
    place: str
    target: str
    side: Side
    distance: int = Field(ge=0)


class BuildLineReading(_Reading):
    """A straight or diagonal line of blocks."""

    kind: Literal["build_line"] = "build_line"
    block: str
    size: int = Field(ge=1)
    diagonal: bool


class BuildSquareReading(_Reading):
    """A filled square of blocks."""

    kind: Literal["build_square"] = "build_square"
    block: str
    size: int = Field(ge=1)


class BuildStarReading(_Reading):
    """A cross of blocks."""

    kind: Literal["build_star"] = "build_star"
    block: str
    size: int = Field(ge=1)
    cross: CrossType


PlacingReading = (
    ConditionalPlacingReading
    | LocalizationReading
    | BuildLineReading
    | BuildSquareReading
    | BuildStarReading
)
"""The readings of the goals that are not achievements goals."""

#: Each goal kind's reading class (its fields are the goal's parameters, same names).
READING_CLASSES: dict[GoalKind, type[_Reading]] = {
    "achievements": AchievementsReading,
    "conditional_placing": ConditionalPlacingReading,
    "localization_placing": LocalizationReading,
    "build_line": BuildLineReading,
    "build_square": BuildSquareReading,
    "build_star": BuildStarReading,
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
