"""CrafText's goals as typed records: splits, categories, goals, instructions and the dataset.

`env.dataset` loads a `Dataset` from its sources; `env.official_source` parses the official
modules into one. Both build on the records here.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal, cast, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, field_validator, model_validator

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS, NUM_ACHIEVEMENTS
from env.errors import UserError

Split = Literal["easy_train", "easy_test_paraphrased", "easy_test_other_params"]
Category = Literal["one", "combo", "paraphrased", "new_objects"]
"""CrafText goal sets: single achievements, combinations, paraphrased instructions, unseen objects."""
SourceKind = Literal["archive", "directory", "wheel", "json"]

SPLITS: tuple[Split, ...] = get_args(Split)
CATEGORIES: tuple[Category, ...] = get_args(Category)
#: The goal sets of the paper's zero-shot table (Achievements one / combo, New objects): what a
#: run plays unless told otherwise, and the columns published numbers exist for.
PAPER_CATEGORIES: tuple[Category, ...] = ("one", "combo", "new_objects")
CATEGORY_SPLIT: dict[Category, Split] = {
    "one": "easy_train",
    "combo": "easy_train",
    "paraphrased": "easy_test_paraphrased",
    "new_objects": "easy_test_other_params",
}


def category_of(split: Split, required: Sequence[str], forbidden: Sequence[str]) -> Category:
    """The category of a goal: in EASY train, `one` (exactly one required achievement and no
    forbidden one) or `combo` (any other); in the test splits, the split's own category."""
    if split == "easy_train":
        return "one" if len(required) == 1 and not forbidden else "combo"
    return "paraphrased" if split == "easy_test_paraphrased" else "new_objects"


def parse_categories(spec: str | Iterable[str]) -> tuple[Category, ...]:
    """Category names from a comma-separated string or an iterable, checked and deduplicated."""
    names = spec.split(",") if isinstance(spec, str) else list(spec)
    selected: list[Category] = []
    for raw in filter(str.strip, names):
        name = raw.strip().lower()
        if name not in CATEGORIES:
            raise UserError(f"unknown category {raw!r}; known: {', '.join(CATEGORIES)}")
        category = cast(Category, name)
        if category not in selected:
            selected.append(category)
    if not selected:
        raise UserError(f"no category selected; known: {', '.join(CATEGORIES)}")
    return tuple(selected)


def check_split(name: str) -> Split:
    """`name` as a `Split`, or a `UserError` listing the known splits."""
    if name not in SPLITS:
        raise UserError(f"unknown split {name!r}; known: {', '.join(SPLITS)}")
    return cast(Split, name)


class Goal(BaseModel):
    """One CrafText goal: achievements to reach and to avoid, described by an instruction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    id: str
    """The goal's key in the official dataset, e.g. `EAT_PLANT_NO_EAT_COW` (unique in its split)."""
    scenario: str = "easy"
    """The CrafText difficulty scenario the goal belongs to."""
    split: Split
    """The dataset split: `easy_train`, `easy_test_paraphrased` or `easy_test_other_params`."""
    category: Category
    """`one` or `combo` (train), `paraphrased` or `new_objects` (test); see `category_of`."""
    instruction: str
    """The original instruction text."""
    paraphrases: tuple[str, ...]
    """The official paraphrases of the instruction (5 for nearly every goal; a few have fewer)."""
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
    def texts(self) -> tuple[str, ...]:
        """The instruction followed by its paraphrases: index = variant."""
        return (self.instruction, *self.paraphrases)

    def required_mask(self) -> np.ndarray:
        """Boolean mask over the 22 achievement ids, True where the achievement is required."""
        return _mask(self.required)

    def forbidden_mask(self) -> np.ndarray:
        """Boolean mask over the 22 achievement ids, True where the achievement is forbidden."""
        return _mask(self.forbidden)


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

    goal: Goal
    """The goal the text describes."""
    variant: int
    """0 for the original instruction, 1..n for the goal's paraphrases (n is usually 5)."""
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
    """The EASY goals of all three splits, and the source they came from."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    source: DatasetSource
    """Where the goals were read from."""
    goals: tuple[Goal, ...]
    """All goals, split by split, in the official order."""

    @model_validator(mode="after")
    def _unique_ids(self) -> Dataset:
        seen: set[tuple[str, str]] = set()
        for goal in self.goals:
            if (goal.split, goal.id) in seen:
                raise ValueError(f"goal {goal.id!r} appears twice in {goal.split}")
            seen.add((goal.split, goal.id))
        return self

    def split(self, name: str) -> list[Goal]:
        """The goals of one split."""
        wanted = check_split(name)
        return [goal for goal in self.goals if goal.split == wanted]

    def select(self, categories: str | Iterable[str]) -> list[Goal]:
        """The goals of the given categories (names or a comma-separated string), in dataset order."""
        wanted = set(parse_categories(categories))
        return [goal for goal in self.goals if goal.category in wanted]

    def instructions(
        self, categories: str | Iterable[str], include_paraphrases: bool = True
    ) -> list[Instruction]:
        """Every instruction text of the selected goals: the original, then the paraphrases."""
        return [
            Instruction(goal=goal, variant=variant, text=text)
            for goal in self.select(categories)
            for variant, text in enumerate(goal.texts if include_paraphrases else goal.texts[:1])
        ]

    def split_sha256(self) -> dict[str, str]:
        """A content digest of each split present: its goals' ids, texts and achievements in
        order, whatever file or format they were read from."""
        return {split: split_digest(goals) for split in SPLITS if (goals := self.split(split))}

    def category_goals(self) -> dict[str, int]:
        """Goals per category, zeros included."""
        return {category: len(self.select(category)) for category in CATEGORIES}

    def save_json(self, path: str | Path) -> Path:
        """Write the dataset as JSON (atomically: a reader never sees a partial file)."""
        target = Path(path)
        _atomic_write(target, self.model_dump_json(indent=1).encode())
        return target


def split_digest(goals: Sequence[Goal]) -> str:
    """SHA-256 of goals' ids, instruction texts and achievements, in order (see `split_sha256`)."""
    content = [
        [
            goal.id,
            goal.instruction,
            list(goal.paraphrases),
            list(goal.required),
            list(goal.forbidden),
        ]
        for goal in goals
    ]
    text = json.dumps(content, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# --- files: writing ------------------------------------------------------------------------


def _atomic_write(target: Path, data: bytes) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    # A unique sibling file, renamed over the target once complete; "xb" keeps umask permissions.
    temp = target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")
    try:
        with temp.open("xb") as out:
            out.write(data)
        os.replace(temp, target)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
