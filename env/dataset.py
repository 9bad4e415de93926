"""The CrafText EASY instruction sets: typed goals, read from the official dataset sources.

`load_dataset(source)` dispatches on what `source` is:

- `None` (the default): the `craftext==0.2.2` wheel. It is fetched once with
  `python -m pip download --no-deps` into the cache directory (`$CRAFTEXT_LLM_CACHE`, else the
  platform's user cache directory for `craftext-llm`), checked against its published sha256,
  parsed, and the result cached as JSON there; later calls read that JSON and run no pip. The
  wheel is never installed: its pins conflict with our JAX stack.
- a directory: a clone of the official repository AIRI-Institute/CrafText (any commit) or an
  unpacked `craftext` wheel. The commit (clone) or version (wheel) is recorded when found.
- a `.whl` file: a `craftext` wheel of any version, parsed in place.
- a `.json` file written by `Dataset.save_json`.

The official dataset modules are parsed with `ast`, never imported or executed (they import JAX
at module level). A split is a module-level dict such as `SMALL/instructions.py: easy`, built from
dict literals and `**other_module.name` spreads; each goal is a dict with the instruction, its
paraphrases, and `create_target_state(required=[Achievement.X, ...], forbidden=[...])`, from which
the required and forbidden achievements are read.

Which train split: the wheel's EASY train split is an older 12-goal version with no single-
achievement goals. The official repository's current EASY train split has 57 goals (20 `one`,
37 `combo`), but we may not redistribute it, so the default source stays the wheel. To evaluate on
the 57-goal split, clone the official repository and pass the clone as the dataset source
(`--dataset /path/to/CrafText` on the command line, `load_dataset("/path/to/CrafText")` in code).
The two test splits are the same in both sources. Every `Dataset` records its source (kind, path,
version or commit, sha256), so results always say which data they used.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal, cast, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator, model_validator

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS, NUM_ACHIEVEMENTS

# CACHE_ENV_VAR is re-exported: callers and tests read it from here.
from env.downloads import CACHE_ENV_VAR as CACHE_ENV_VAR
from env.downloads import cache_root, fetch_pinned_wheel, sha256_file, verify_sha256
from env.errors import UserError

Split = Literal["easy_train", "easy_test_paraphrased", "easy_test_other_params"]
Category = Literal["one", "combo", "paraphrased", "new_objects"]
SourceKind = Literal["directory", "wheel", "json"]

SPLITS: tuple[Split, ...] = get_args(Split)
CATEGORIES: tuple[Category, ...] = get_args(Category)
CATEGORY_SPLIT: dict[Category, Split] = {
    "one": "easy_train",
    "combo": "easy_train",
    "paraphrased": "easy_test_paraphrased",
    "new_objects": "easy_test_other_params",
}

WHEEL_REQUIREMENT = "craftext==0.2.2"
WHEEL_FILENAME = "craftext-0.2.2-py3-none-any.whl"
WHEEL_SHA256 = "a7d13bc8c6af94496d187a702e50cf621ff9940ac45ed2ac6e8ef6c5474e52cc"
# Bump when parsing changes what a cached JSON would contain, so stale caches are not reused.
_CACHE_FORMAT = 1


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
    """`directory` (official repository clone or unpacked wheel), `wheel` or `json`."""
    path: str
    """The directory, wheel file or JSON file read."""
    version: str | None = None
    """The craftext package version or the repository's git commit, where known."""
    sha256: str | None = None
    """SHA-256 of the wheel or JSON file; for a directory, of the parsed modules (paths and bytes)."""
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

    def save_json(self, path: str | Path) -> Path:
        """Write the dataset as JSON (atomically: a reader never sees a partial file)."""
        target = Path(path)
        _atomic_write(target, self.model_dump_json(indent=1).encode())
        return target


def load_dataset(source: str | Path | None = None) -> Dataset:
    """The EASY dataset from `source`: None (the cached `craftext==0.2.2` wheel), a directory
    (official repository clone or unpacked wheel), a `.whl` file, or a `.json` file."""
    if source is None:
        return _load_default_wheel(cache_root())
    path = Path(source).expanduser().resolve()
    if path.is_dir():
        from env.official_source import parse_directory

        return parse_directory(path)
    if not path.exists():
        raise UserError(f"dataset source {str(path)!r} does not exist")
    if path.suffix == ".json":
        return _load_user_json(path)
    if path.suffix == ".whl":
        from env.official_source import parse_wheel

        return parse_wheel(path)
    raise UserError(
        f"dataset source {str(path)!r} is not a directory, a .whl or a .json file; "
        "pass a clone of the official CrafText repository, a craftext wheel or a saved dataset JSON"
    )


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


# --- JSON sources ---------------------------------------------------------------------------


def _read_dataset_json(path: Path) -> Dataset:
    try:
        return Dataset.model_validate_json(path.read_bytes())
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise UserError(
            f"{path} is not a valid dataset JSON ({error.error_count()} errors; first at {where}: {first['msg']})"
        ) from None
    except OSError as error:
        raise UserError(f"cannot read dataset JSON {path}: {error.strerror}") from None


def _load_user_json(path: Path) -> Dataset:
    saved = _read_dataset_json(path)
    origin = saved.source.built_from if saved.source.kind == "json" else saved.source
    return Dataset(
        source=DatasetSource(
            kind="json",
            path=str(path),
            version=saved.source.version,
            sha256=sha256_file(path),
            built_from=origin,
        ),
        goals=saved.goals,
    )


# --- the default wheel ----------------------------------------------------------------------


def _load_default_wheel(cache: Path) -> Dataset:
    cached_json = cache / f"{WHEEL_FILENAME.removesuffix('.whl')}.easy.v{_CACHE_FORMAT}.json"
    if cached_json.is_file():
        try:
            return _read_dataset_json(cached_json)
        except UserError as error:
            raise UserError(f"{error}; delete it to rebuild the cache") from None
    wheel = cache / WHEEL_FILENAME
    if wheel.is_file():
        verify_sha256(wheel, WHEEL_SHA256, WHEEL_REQUIREMENT)
    else:
        fetch_pinned_wheel(
            WHEEL_REQUIREMENT,
            WHEEL_FILENAME,
            WHEEL_SHA256,
            cache,
            offline_hint="check the network, or pass a local clone of the official CrafText "
            "repository or a craftext wheel as the dataset source",
        )
    from env.official_source import parse_wheel

    dataset = parse_wheel(wheel)
    dataset.save_json(cached_json)
    return dataset
