"""CrafText's goals as typed records: splits, categories, goals, instructions and the dataset.

`env.dataset` loads a `Dataset` from its sources; `env.official_source` parses the official
modules into one. Both build on the records here.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Annotated, Literal, cast, get_args

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    field_validator,
    model_validator,
)

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS, NUM_ACHIEVEMENTS
from env.downloads import atomic_write_bytes
from env.errors import UserError

Split = Literal[
    "easy_train",
    "easy_test_paraphrased",
    "easy_test_other_params",
    "medium_train",
    "medium_test_paraphrased",
    "medium_test_other_params",
    "hard_train",
    "hard_test_paraphrased",
    "hard_test_other_params",
]
"""`<difficulty>_<part>`: the official `SMALL` subsets (EASY, Medium on Craftax-Classic, Hard on
full Craftax), each a train split and two test splits (paraphrased instructions, other
parameters)."""
Difficulty = Literal["easy", "medium", "hard"]
Category = Literal["one", "combo", "paraphrased", "new_objects", "train"]
"""CrafText goal sets: single achievements, combinations, paraphrased instructions, unseen objects,
and (Medium and Hard, whose train goals are not all achievements) a whole train split."""
SourceKind = Literal["archive", "directory", "wheel", "json"]
GoalKind = Literal[
    "achievements",
    "conditional_placing",
    "localization_placing",
    "build_line",
    "build_square",
    "build_star",
]
"""What a goal asks, one per official checker that the data uses (`Scenarios.X`)."""
ScenarioClass = Literal["Achievements", "Conditional", "Localization", "Build"]
"""The paper's grouping of scenarios (its Table 2)."""
Side = Literal["right", "left", "up", "down"]
"""Where the placed block is from the target block (the official side codes 0-3, in order)."""
CrossType = Literal["straight", "diagonal", "combined"]
"""The official `CrossType` codes 0-2, in order."""

#: The difficulty a run, a grounding run and every function that takes one play unless told
#: otherwise.
DEFAULT_DIFFICULTY: Difficulty = "easy"
SPLITS: tuple[Split, ...] = get_args(Split)
DIFFICULTIES: tuple[Difficulty, ...] = get_args(Difficulty)
GOAL_KINDS: tuple[GoalKind, ...] = get_args(GoalKind)
SIDES: tuple[Side, ...] = get_args(Side)
CROSS_TYPES: tuple[CrossType, ...] = get_args(CrossType)
SCENARIO_CLASSES: tuple[ScenarioClass, ...] = get_args(ScenarioClass)
ALL_CATEGORIES: tuple[Category, ...] = get_args(Category)
#: EASY's goal sets (the other difficulties' are in `DIFFICULTY_CATEGORIES`).
CATEGORIES: tuple[Category, ...] = ("one", "combo", "paraphrased", "new_objects")
#: The goal sets of the paper's zero-shot table (Achievements one / combo, New objects): what a
#: run plays unless told otherwise, and the columns published numbers exist for.
PAPER_CATEGORIES: tuple[Category, ...] = ("one", "combo", "new_objects")
#: The goal sets a run of each difficulty can select: EASY's are the paper's zero-shot table's,
#: Medium's and Hard's its Table 2 columns (Train / Paraphrased / New objects).
DIFFICULTY_CATEGORIES: dict[Difficulty, tuple[Category, ...]] = {
    "easy": ("one", "combo", "paraphrased", "new_objects"),
    "medium": ("train", "paraphrased", "new_objects"),
    "hard": ("train", "paraphrased", "new_objects"),
}
#: The goal kinds each difficulty's official splits hold (Medium: achievements and the Classic
#: placing goals, no star; Hard: placing goals only): what a model grounding them is offered.
DIFFICULTY_KINDS: dict[Difficulty, tuple[GoalKind, ...]] = {
    "easy": ("achievements",),
    "medium": (
        "achievements",
        "conditional_placing",
        "localization_placing",
        "build_line",
        "build_square",
    ),
    "hard": (
        "conditional_placing",
        "localization_placing",
        "build_line",
        "build_square",
        "build_star",
    ),
}
_SPLIT_PART: dict[Category, str] = {
    "one": "train",
    "combo": "train",
    "train": "train",
    "paraphrased": "test_paraphrased",
    "new_objects": "test_other_params",
}
CATEGORY_SPLIT: dict[Category, Split] = {
    "one": "easy_train",
    "combo": "easy_train",
    "paraphrased": "easy_test_paraphrased",
    "new_objects": "easy_test_other_params",
}


def category_of(split: Split, required: Sequence[str], forbidden: Sequence[str]) -> Category:
    """The category of an achievements goal: in a train split, `one` (exactly one required
    achievement and no forbidden one) or `combo` (any other); in the test splits, the split's own
    category."""
    if split.endswith("_train"):
        return "one" if len(required) == 1 and not forbidden else "combo"
    return "paraphrased" if split.endswith("_test_paraphrased") else "new_objects"


def difficulty_of(split: Split) -> Difficulty:
    """The difficulty a split belongs to (its name's first part)."""
    return cast(Difficulty, split.split("_", 1)[0])


def check_difficulty(name: str) -> Difficulty:
    """`name` as a `Difficulty`, or a `UserError` listing the known ones."""
    if name not in DIFFICULTIES:
        raise UserError(f"unknown difficulty {name!r}; known: {', '.join(DIFFICULTIES)}")
    return cast(Difficulty, name)


def check_categories(categories: Iterable[str], difficulty: Difficulty) -> tuple[Category, ...]:
    """`categories` checked against what a run of `difficulty` can select."""
    selected = parse_categories(categories)
    allowed = DIFFICULTY_CATEGORIES[difficulty]
    wrong = [category for category in selected if category not in allowed]
    if wrong:
        raise UserError(
            f"category {wrong[0]!r} is not one of {difficulty}'s; choose from {', '.join(allowed)}"
        )
    return selected


def category_split(category: Category, difficulty: Difficulty) -> Split:
    """The split a category's goals come from in `difficulty`."""
    return cast(Split, f"{difficulty}_{_SPLIT_PART[category]}")


def split_categories(split: Split) -> tuple[Difficulty, tuple[Category, ...]]:
    """The difficulty and categories whose goals are `split`'s (`category_split` the other way):
    EASY's train split holds `one` and `combo`, every other split one category."""
    difficulty = difficulty_of(split)
    part = split.split("_", 1)[1]
    if difficulty == "easy" and part == "train":
        return difficulty, ("one", "combo")
    categories = [
        category for category in DIFFICULTY_CATEGORIES[difficulty] if _SPLIT_PART[category] == part
    ]
    return difficulty, tuple(categories)


def run_category(goal: AnyGoal) -> Category:
    """The goal set a run counts `goal` in: an EASY goal's own category; a Medium or Hard goal's
    split (`train`, `paraphrased`, `new_objects`), as the paper's Table 2 groups them."""
    if goal.difficulty == "easy" and isinstance(goal, Goal):
        return goal.category
    if goal.split.endswith("_train"):
        return "train"
    return "paraphrased" if goal.split.endswith("_test_paraphrased") else "new_objects"


def parse_categories(spec: str | Iterable[str]) -> tuple[Category, ...]:
    """Category names from a comma-separated string or an iterable, checked and deduplicated."""
    # "one,combo" and ["one", "combo"] alike, also as one flag value among several.
    names = [
        part for item in ([spec] if isinstance(spec, str) else spec) for part in item.split(",")
    ]
    selected: list[Category] = []
    for raw in filter(str.strip, names):
        name = raw.strip().lower()
        if name not in ALL_CATEGORIES:
            raise UserError(f"unknown category {raw!r}; known: {', '.join(ALL_CATEGORIES)}")
        category = cast(Category, name)
        if category not in selected:
            selected.append(category)
    if not selected:
        raise UserError(f"no category selected; known: {', '.join(ALL_CATEGORIES)}")
    return tuple(selected)


def check_split(name: str) -> Split:
    """`name` as a `Split`, or a `UserError` listing the known splits."""
    if name not in SPLITS:
        raise UserError(f"unknown split {name!r}; known: {', '.join(SPLITS)}")
    return cast(Split, name)


class _GoalText(BaseModel):
    """What every goal has: where it is in the dataset and its instruction texts."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    id: str
    """The goal's key in the official dataset, e.g. `EAT_PLANT_NO_EAT_COW` (unique in its split)."""
    scenario: str = "easy"
    """The CrafText difficulty the goal belongs to (`easy`, `medium`, `hard`)."""
    split: Split
    """The dataset split, e.g. `easy_train` or `medium_test_other_params`."""
    instruction: str
    """The original instruction text."""
    paraphrases: tuple[str, ...]
    """The official paraphrases of the instruction, as many as the data gives (the official data:
    5 for nearly every goal, 4 for a few, 10 for Medium's `INSTRUCTION_STONE_3`)."""

    @model_validator(mode="after")
    def _scenario_is_the_splits(self) -> _GoalText:
        if self.scenario != difficulty_of(self.split):
            raise ValueError(f"goal {self.id!r} in {self.split} has scenario {self.scenario!r}")
        return self

    @property
    def texts(self) -> tuple[str, ...]:
        """The instruction followed by its paraphrases: index = variant."""
        return (self.instruction, *self.paraphrases)

    @property
    def difficulty(self) -> Difficulty:
        return difficulty_of(self.split)

    def parameters(self) -> list[object]:
        """The goal's own parameters, in field order (what the split digest covers)."""
        common = set(_GoalText.model_fields) | {"kind", "category"}
        return [getattr(self, name) for name in type(self).model_fields if name not in common]


# Each goal kind's parameters, declared once: the dataset's goals below add where they are in
# the dataset and their texts; the readings of `llm_agents.run_data.readings` add nothing but
# how they are scored.


class _Parameters(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class AchievementsParameters(_Parameters):
    """An achievements goal's parameters: achievements to reach and to avoid."""

    kind: Literal["achievements"] = "achievements"
    required: tuple[str, ...]
    """Achievement names that must all be reached, in achievement-id order."""
    forbidden: tuple[str, ...] = ()
    """Achievement names that must not be reached, in achievement-id order."""

    @field_validator("required", "forbidden")
    @classmethod
    def _known_achievements(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [name for name in names if name not in ACHIEVEMENT_IDS]
        if unknown:
            raise ValueError(f"unknown achievements {unknown}; known: {', '.join(ACHIEVEMENTS)}")
        # The official goals are masks, so order and repetition carry no meaning: keep id order.
        return tuple(sorted(set(names), key=ACHIEVEMENT_IDS.__getitem__))


class ConditionalPlacingParameters(_Parameters):
    """Collect an item, then have blocks of a kind on the map (official `conditional_placing`)."""

    kind: Literal["conditional_placing"] = "conditional_placing"
    collect: str
    """The inventory field the official checker counts (e.g. `iron`; its enum codes 6-11, 14 and
    15 all count `diamond`)."""
    collect_count: int = Field(ge=0)
    place: str
    """The block that must stand on the map (Craftax block name)."""
    place_count: int = Field(ge=0)


class LocalizationParameters(_Parameters):
    """Place a block at a side and distance from another (official `localization_placing`)."""

    kind: Literal["localization_placing"] = "localization_placing"
    place: str
    """The block to place (Craftax block name)."""
    target: str
    """The block it is placed relative to."""
    side: Side
    distance: int = Field(ge=0)


class BuildLineParameters(_Parameters):
    """A straight or diagonal line of blocks (official `build_line`)."""

    kind: Literal["build_line"] = "build_line"
    block: str
    size: int = Field(ge=1)
    diagonal: bool


class BuildSquareParameters(_Parameters):
    """A filled square of blocks (official `build_square`)."""

    kind: Literal["build_square"] = "build_square"
    block: str
    size: int = Field(ge=1)


class BuildStarParameters(_Parameters):
    """A cross of blocks (official `build_star`)."""

    kind: Literal["build_star"] = "build_star"
    block: str
    size: int = Field(ge=1)
    cross: CrossType


class _CategorizedText(_GoalText):
    # `kind` again only so that an achievements goal's fields (and its JSON) keep their order:
    # kind, category, required, forbidden.
    kind: Literal["achievements"] = "achievements"
    category: Category
    """`one` or `combo` (train), `paraphrased` or `new_objects` (test); see `category_of`."""


class Goal(AchievementsParameters, _CategorizedText):
    """A conditional-achievements goal: achievements to reach and to avoid (all of EASY, and part
    of Medium)."""

    @model_validator(mode="after")
    def _consistent(self) -> Goal:
        if not self.required:
            raise ValueError(f"goal {self.id!r} requires no achievement")
        if overlap := set(self.required) & set(self.forbidden):
            raise ValueError(f"goal {self.id!r} both requires and forbids {sorted(overlap)}")
        expected = category_of(self.split, self.required, self.forbidden)
        if self.category != expected:
            raise ValueError(
                f"goal {self.id!r} in {self.split} has category {self.category!r}, expected {expected!r}"
            )
        return self

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Achievements"

    def required_mask(self) -> np.ndarray:
        """Boolean mask over the 22 achievement ids, True where the achievement is required."""
        return _mask(self.required)

    def forbidden_mask(self) -> np.ndarray:
        """Boolean mask over the 22 achievement ids, True where the achievement is forbidden."""
        return _mask(self.forbidden)


class ConditionalPlacingGoal(ConditionalPlacingParameters, _GoalText):
    __doc__ = ConditionalPlacingParameters.__doc__

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Conditional"


class LocalizationGoal(LocalizationParameters, _GoalText):
    __doc__ = LocalizationParameters.__doc__

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Localization"


class BuildLineGoal(BuildLineParameters, _GoalText):
    __doc__ = BuildLineParameters.__doc__

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Build"


class BuildSquareGoal(BuildSquareParameters, _GoalText):
    __doc__ = BuildSquareParameters.__doc__

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Build"


class BuildStarGoal(BuildStarParameters, _GoalText):
    __doc__ = BuildStarParameters.__doc__

    @property
    def scenario_class(self) -> ScenarioClass:
        return "Build"


def kind_of(value: object) -> str:
    """The `kind` of a goal (or a goal as read), as a record or as its JSON; records saved
    before Medium and Hard existed carry none: they are achievements goals."""
    if isinstance(value, dict):
        return str(value.get("kind", "achievements"))
    return str(getattr(value, "kind", "achievements"))


AnyGoal = Annotated[
    Annotated[Goal, Tag("achievements")]
    | Annotated[ConditionalPlacingGoal, Tag("conditional_placing")]
    | Annotated[LocalizationGoal, Tag("localization_placing")]
    | Annotated[BuildLineGoal, Tag("build_line")]
    | Annotated[BuildSquareGoal, Tag("build_square")]
    | Annotated[BuildStarGoal, Tag("build_star")],
    Discriminator(kind_of),
]
"""Any CrafText goal, told apart by its `kind`."""


def _mask(names: Iterable[str]) -> np.ndarray:
    mask = np.zeros(NUM_ACHIEVEMENTS, dtype=bool)
    mask[[ACHIEVEMENT_IDS[name] for name in names]] = True
    return mask


def goal_masks(goals: Sequence[Goal]) -> tuple[np.ndarray, np.ndarray]:
    """Required and forbidden masks of a batch of goals, each bool of shape (len(goals), 22)."""
    required = np.zeros((len(goals), NUM_ACHIEVEMENTS), dtype=bool)
    forbidden = np.zeros((len(goals), NUM_ACHIEVEMENTS), dtype=bool)
    for row, goal in enumerate(goals):
        required[row] = goal.required_mask()
        forbidden[row] = goal.forbidden_mask()
    return required, forbidden


class Instruction(BaseModel):
    """One instruction text an agent is given: a goal and which of its phrasings."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    goal: AnyGoal
    """The goal the text describes."""
    variant: int
    """0 for the original instruction, 1..n for the goal's n paraphrases."""
    text: str
    """The instruction text itself."""

    @model_validator(mode="after")
    def _text_matches_variant(self) -> Instruction:
        texts = self.goal.texts
        if not 0 <= self.variant < len(texts):
            raise ValueError(f"variant {self.variant} out of range 0..{len(texts) - 1}")
        if texts[self.variant] != self.text:
            raise ValueError(f"text is not variant {self.variant} of goal {self.goal.id!r}")
        return self

    @property
    def key(self) -> str:
        """A stable name for results: `split/goal_id/variant`."""
        return f"{self.goal.split}/{self.goal.id}/{self.variant}"


class DatasetSource(BaseModel):
    """Where a dataset was read from, recorded with every result."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: SourceKind
    """`archive` (the official repository's zip from the code host), `directory` (official
    repository clone or unpacked wheel), `wheel` or `json`."""
    path: str
    """The URL, directory, wheel file or JSON file read."""
    version: str | None = None
    """The craftext package version or the repository's git commit, where known."""
    sha256: str | None = None
    """SHA-256 of the wheel or JSON file; for an archive or a directory, of the parsed modules
    (paths and bytes)."""
    built_from: DatasetSource | None = None
    """For a JSON file: the source its goals were parsed from."""


class Dataset(BaseModel):
    """The goals of every split, and the source they came from."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    source: DatasetSource
    """Where the goals were read from."""
    goals: tuple[AnyGoal, ...]
    """All goals, split by split, in the official order."""

    # What the rest of the project assumes of the data, checked here, once, as it is loaded;
    # nothing else is (paraphrase counts, ids repeated across splits are the data's own).
    @model_validator(mode="after")
    def _what_runs_assume(self) -> Dataset:
        seen: set[tuple[str, str]] = set()
        for goal in self.goals:
            # A run names a goal by its category and id (episode ids, replays, per-goal rates).
            if (goal.split, goal.id) in seen:
                raise ValueError(f"goal {goal.id!r} appears twice in {goal.split}")
            seen.add((goal.split, goal.id))
            # Grounding offers a difficulty's kinds only: a goal of another could never be read.
            kinds = DIFFICULTY_KINDS[goal.difficulty]
            if goal.kind not in kinds:
                raise ValueError(
                    f"goal {goal.id!r} in {goal.split} is a {goal.kind} goal; "
                    f"{goal.difficulty} goals are {', '.join(kinds)}"
                )
        return self

    def split(self, name: str) -> list[AnyGoal]:
        """The goals of one split; a `UserError` when this dataset has none."""
        wanted = check_split(name)
        goals = [goal for goal in self.goals if goal.split == wanted]
        if not goals:
            present = ", ".join(split for split in SPLITS if self.has_split(split))
            raise UserError(f"this dataset has no {wanted} goals; it has: {present}")
        return goals

    def has_split(self, name: Split) -> bool:
        return any(goal.split == name for goal in self.goals)

    def select(self, categories: str | Iterable[str]) -> list[Goal]:
        """The EASY goals of the given categories (names or a comma-separated string), in
        dataset order."""
        wanted = set(parse_categories(categories))
        return [
            goal
            for goal in self.goals
            if isinstance(goal, Goal) and goal.difficulty == "easy" and goal.category in wanted
        ]

    def select_goals(
        self, categories: str | Iterable[str], difficulty: Difficulty = DEFAULT_DIFFICULTY
    ) -> list[AnyGoal]:
        """The goals of `difficulty` in the given categories (see `run_category`), in dataset
        order; a `UserError` for a category the difficulty has not or a selected split this
        dataset lacks."""
        wanted = check_categories(
            categories.split(",") if isinstance(categories, str) else categories, difficulty
        )
        if difficulty != "easy":
            for category in wanted:
                self.split(category_split(category, difficulty))
        return [
            goal
            for goal in self.goals
            if goal.difficulty == difficulty and run_category(goal) in wanted
        ]

    def instructions(
        self,
        categories: str | Iterable[str],
        include_paraphrases: bool = True,
        difficulty: Difficulty = DEFAULT_DIFFICULTY,
    ) -> list[Instruction]:
        """Every instruction text of the selected goals: the original, then the paraphrases."""
        return [
            Instruction(goal=goal, variant=variant, text=text)
            for goal in self.select_goals(categories, difficulty)
            for variant, text in enumerate(goal.texts if include_paraphrases else goal.texts[:1])
        ]

    def split_sha256(self) -> dict[str, str]:
        """A content digest of each split present: its goals' ids, texts and achievements in
        order, whatever file or format they were read from."""
        return {
            split: split_digest([goal for goal in self.goals if goal.split == split])
            for split in SPLITS
            if self.has_split(split)
        }

    def scenario_goals(self) -> dict[str, dict[str, int]]:
        """Goals per split and goal kind, for the splits present."""
        counts: dict[str, dict[str, int]] = {}
        for goal in self.goals:
            per_kind = counts.setdefault(goal.split, {})
            per_kind[goal.kind] = per_kind.get(goal.kind, 0) + 1
        return counts

    def category_goals(self) -> dict[str, int]:
        """Goals per EASY category, zeros included."""
        return {category: len(self.select(category)) for category in CATEGORIES}

    def save_json(self, path: str | Path) -> Path:
        """Write the dataset as JSON (atomically: a reader never sees a partial file)."""
        target = Path(path)
        atomic_write_bytes(target, self.model_dump_json(indent=1).encode())
        return target


def checked_dataset(source: DatasetSource, goals: Iterable[AnyGoal]) -> Dataset:
    """The dataset of `goals` read from `source`, a goal that breaks what runs assume of the
    data (see `Dataset`) as one line naming the source."""
    try:
        return Dataset(source=source, goals=tuple(goals))
    except ValidationError as error:
        message = error.errors()[0]["msg"].removeprefix("Value error, ")
        raise UserError(f"{source.path}: {message}") from None


def split_digest(goals: Sequence[AnyGoal]) -> str:
    """SHA-256 of goals' ids, instruction texts and parameters, in order (see `split_sha256`)."""
    content = [
        [goal.id, goal.instruction, list(goal.paraphrases), *_digested(goal)] for goal in goals
    ]
    text = json.dumps(content, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _digested(goal: AnyGoal) -> list[object]:
    if isinstance(goal, Goal):
        # As before other kinds existed, so EASY digests stay what they were.
        return [list(goal.required), list(goal.forbidden)]
    return [goal.kind, *goal.parameters()]


# --- files: writing ------------------------------------------------------------------------
