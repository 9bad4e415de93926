"""The CrafText instruction sets (EASY, Medium, Hard): typed goals, read from the official dataset
sources.

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

import logging
import os
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

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

# The records are re-exported: `env.dataset` is where callers get goals from.
from env.goals import CATEGORIES as CATEGORIES
from env.goals import CATEGORY_SPLIT as CATEGORY_SPLIT
from env.goals import DIFFICULTIES as DIFFICULTIES
from env.goals import GOAL_KINDS as GOAL_KINDS
from env.goals import PAPER_CATEGORIES as PAPER_CATEGORIES
from env.goals import SPLITS as SPLITS
from env.goals import AnyGoal as AnyGoal
from env.goals import Category as Category
from env.goals import Dataset as Dataset
from env.goals import DatasetSource as DatasetSource
from env.goals import Goal as Goal
from env.goals import Instruction as Instruction
from env.goals import SourceKind as SourceKind
from env.goals import Split as Split
from env.goals import category_of as category_of
from env.goals import check_split as check_split
from env.goals import goal_masks as goal_masks
from env.goals import parse_categories as parse_categories
from env.goals import split_digest as split_digest
from env.official_source import parse_archive, parse_directory, parse_wheel

logger = logging.getLogger(__name__)

WHEEL_REQUIREMENT = "craftext==0.2.2"
WHEEL_FILENAME = "craftext-0.2.2-py3-none-any.whl"
WHEEL_SHA256 = "a7d13bc8c6af94496d187a702e50cf621ff9940ac45ed2ac6e8ef6c5474e52cc"
# Bump when parsing changes what a cached JSON would contain, so stale caches are not reused.
_CACHE_FORMAT = 2

OFFICIAL_REPOSITORY = "AIRI-Institute/CrafText"
OFFICIAL_COMMIT = "1c518aeaaf729d0e04b768d907593fb9980efe4e"
#: The code host's zip archive of a repository at a commit; `{base}` is `code_host()`.
OFFICIAL_ARCHIVE_URL = "{base}/{repository}/archive/{commit}.zip"
#: `Dataset.split_sha256` of the official splits at `OFFICIAL_COMMIT`, as a clone parses. The
#: Hard test splits are absent: `SMALL/test.py` defines none, so the official loader yields none.
OFFICIAL_SPLIT_SHA256: dict[Split, str] = {
    "easy_train": "7db0c11d0b363d52baa9467e936e511d12cdc259476e0707a11baa0f0d3fe77e",
    "easy_test_paraphrased": "500deecdffe39bc82edd45c7eda470408509041674397eb222bade14ea5c2c4f",
    "easy_test_other_params": "c677decd7de1223f1a2bbaad1e72f4ff1c4538b237e18e31051a9f6f9bf38fc6",
    "medium_train": "1bf30d556a1f52d3245e191cc0036afd2fec2ab63790a1889369691efd41c56a",
    "medium_test_paraphrased": "0e12aa073a39f521bd5f28c82e3fa811e19f2a8a88159456203f9d6cf6d39346",
    "medium_test_other_params": "7058da123729637e008573302f0903e2ac2a6b0a39f37467192599f2a3f099e1",
    "hard_train": "ef1b95fdbbec8d145defe01717329bdc02e34ac329407e941ab53b29939d9981",
}
#: Goals per category in the official EASY splits at `OFFICIAL_COMMIT`.
OFFICIAL_GOALS: dict[Category, int] = {"one": 20, "combo": 37, "paraphrased": 41, "new_objects": 44}
# The repository archive is a few MB (mostly GIFs); anything far larger is not it.
_ARCHIVE_MAX_BYTES = 64 << 20


def official_splits(dataset: Dataset) -> list[str]:
    """The splits of `dataset` whose content equals the official data at `OFFICIAL_COMMIT`."""
    digests = dataset.split_sha256()
    return [
        split
        for split in SPLITS
        if split in digests and digests[split] == OFFICIAL_SPLIT_SHA256.get(split)
    ]


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
        return parse_directory(path)
    if not path.exists():
        raise UserError(f"dataset source {str(path)!r} does not exist")
    if path.suffix == ".json":
        return _load_user_json(path)
    if path.suffix == ".whl":
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


# --- JSON sources ---------------------------------------------------------------------------


def _read_dataset_json(path: Path) -> Dataset:
    try:
        return Dataset.model_validate_json(path.read_bytes())
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "the dataset"
        message = first["msg"].removeprefix("Value error, ")
        raise UserError(
            f"{path} is not a valid dataset JSON ({error.error_count()} errors; first at {where}: {message})"
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
    matching = official_splits(dataset)
    differing = [split for split in OFFICIAL_SPLIT_SHA256 if split not in matching]
    if not differing:
        return "which equals the official data"
    missing_splits = [split for split in differing if not dataset.has_split(split)]
    differing = [split for split in differing if split not in missing_splits]
    absent = f"; it has no {', '.join(missing_splits)} goals" if missing_splits else ""
    if not differing:
        return f"which equals the official data where present{absent}"
    counts = dataset.category_goals()
    missing = [
        f"{counts[category]} of {OFFICIAL_GOALS[category]} `{category}` goals"
        for category in CATEGORIES
        if CATEGORY_SPLIT[category] in differing and counts[category] != OFFICIAL_GOALS[category]
    ]
    has = f" (it has {', '.join(missing)})" if missing else ""
    verb = "s differ" if len(differing) > 1 else " differs"
    return f"whose {', '.join(differing)} split{verb} from the official one{has}{absent}"


# --- the official data ------------------------------------------------------------------------


def official_archive_url() -> str:
    """The URL of the official repository's archive at the pinned commit."""
    return OFFICIAL_ARCHIVE_URL.format(
        base=code_host(), repository=OFFICIAL_REPOSITORY, commit=OFFICIAL_COMMIT
    )


def official_cache_file(cache: Path | None = None) -> Path:
    """Where the parsed official data is cached."""
    root = cache_root() if cache is None else cache
    return root / f"CrafText-{OFFICIAL_COMMIT[:12]}.v{_CACHE_FORMAT}.json"


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
    differing = [
        split for split in differing if split in OFFICIAL_SPLIT_SHA256 or dataset.has_split(split)
    ]
    missing = [split for split in differing if not dataset.has_split(split)]
    changed = [split for split in differing if split not in missing]
    if differing:
        reasons = [f"its {', '.join(changed)} content digest differs from the pinned one"] * bool(
            changed
        ) + [f"it has no {', '.join(missing)} goals"] * bool(missing)
        raise UserError(
            f"the data from {origin} is not the official CrafText data at commit "
            f"{OFFICIAL_COMMIT[:7]}: {'; '.join(reasons)}"
        )


# --- the craftext 0.2.2 wheel -----------------------------------------------------------------


def wheel_cache_file(cache: Path | None = None) -> Path:
    """Where the parsed `craftext==0.2.2` wheel data is cached."""
    root = cache_root() if cache is None else cache
    return root / f"{WHEEL_FILENAME.removesuffix('.whl')}.v{_CACHE_FORMAT}.json"


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
    dataset = parse_wheel(wheel)
    dataset.save_json(cached_json)
    return dataset
