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

import ast
import hashlib
import os
import re
import uuid
import zipfile
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, cast, get_args

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
        return _parse_tree(_DirectoryFiles(path), kind="directory", label=path)
    if not path.exists():
        raise UserError(f"dataset source {str(path)!r} does not exist")
    if path.suffix == ".json":
        return _load_user_json(path)
    if path.suffix == ".whl":
        return _parse_wheel(path)
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
    dataset = _parse_wheel(wheel)
    dataset.save_json(cached_json)
    return dataset


# --- parsing the official modules -----------------------------------------------------------


class _SourceFiles(Protocol):
    """Read access to the files of a directory or a wheel, by POSIX path relative to its root."""

    def read(self, relpath: str) -> bytes | None: ...

    def dist_info_metadata(self) -> bytes | None: ...

    def git_commit(self) -> str | None: ...


@dataclass
class _DirectoryFiles:
    root: Path

    def read(self, relpath: str) -> bytes | None:
        path = self.root / relpath
        return path.read_bytes() if path.is_file() else None

    def dist_info_metadata(self) -> bytes | None:
        found = sorted(self.root.glob("craftext-*.dist-info/METADATA"))
        return found[0].read_bytes() if found else None

    def git_commit(self) -> str | None:
        git = self.root / ".git"
        if git.is_file():  # a worktree or submodule: `.git` names the real git directory
            pointer = git.read_text().strip().removeprefix("gitdir:").strip()
            git = (self.root / pointer).resolve()
        if not (git / "HEAD").is_file():
            return None
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref:"):
            return head
        ref = head.removeprefix("ref:").strip()
        common = (
            git / (git / "commondir").read_text().strip() if (git / "commondir").is_file() else git
        )
        for base in (git, common):
            if (base / ref).is_file():
                return (base / ref).read_text().strip()
            packed = base / "packed-refs"
            if packed.is_file():
                for line in packed.read_text().splitlines():
                    commit, _, name = line.partition(" ")
                    if name == ref:
                        return commit
        return None


@dataclass
class _WheelFiles:
    archive: zipfile.ZipFile

    def read(self, relpath: str) -> bytes | None:
        try:
            return self.archive.read(relpath)
        except KeyError:
            return None

    def dist_info_metadata(self) -> bytes | None:
        names = sorted(
            name
            for name in self.archive.namelist()
            if re.fullmatch(r"craftext-[^/]+\.dist-info/METADATA", name)
        )
        return self.archive.read(names[0]) if names else None

    def git_commit(self) -> str | None:
        return None


# Where each split lives, relative to the `scenarious` package. The released wheel and the
# official repository spell the "new objects" split differently.
_SPLIT_BINDINGS: dict[Split, tuple[str, tuple[str, ...]]] = {
    "easy_train": ("SMALL.instructions", ("easy",)),
    "easy_test_paraphrased": ("SMALL.test", ("easy_test_paraphrased",)),
    "easy_test_other_params": (
        "SMALL.test",
        ("easy_test_other_params", "easy_test_other_paramets"),
    ),
}
_SCENARIOS_PACKAGE = "craftext.dataset.scenarious"
# Where the `scenarious` package may sit below the given root: repository clone or unpacked
# wheel, the `craftext` package itself, `craftext/dataset`, or `scenarious` itself.
_SCENARIOS_PREFIXES = ("craftext/dataset/scenarious", "dataset/scenarious", "scenarious", "")
_TARGET_STATE_FUNCTION = "create_target_state"
_ACHIEVEMENT_ENUM = "Achievement"


def _parse_wheel(wheel: Path) -> Dataset:
    try:
        with zipfile.ZipFile(wheel) as archive:
            dataset = _parse_tree(_WheelFiles(archive), kind="wheel", label=wheel)
    except zipfile.BadZipFile:
        raise UserError(f"{wheel} is not a valid wheel (zip) file") from None
    return Dataset(
        source=dataset.source.model_copy(update={"sha256": sha256_file(wheel)}),
        goals=dataset.goals,
    )


def _parse_tree(files: _SourceFiles, kind: SourceKind, label: Path) -> Dataset:
    prefix = next(
        (
            candidate
            for candidate in _SCENARIOS_PREFIXES
            if any(files.read(_join(candidate, name)) is not None for name in _SPLIT_MODULE_FILES)
        ),
        None,
    )
    if prefix is None:
        raise UserError(
            f"no CrafText dataset modules in {label}: expected "
            f"craftext/dataset/scenarious/SMALL/instructions.py (a clone of the official CrafText "
            "repository or an unpacked craftext wheel)"
        )
    tree = _SourceTree(files, prefix, label)
    goals: list[Goal] = []
    for split, (module_name, variables) in _SPLIT_BINDINGS.items():
        goals.extend(tree.split_goals(split, module_name, variables))
    metadata = files.dist_info_metadata()
    version_match = re.search(rb"^Version:\s*(\S+)", metadata or b"", flags=re.MULTILINE)
    version = version_match.group(1).decode() if version_match else files.git_commit()
    source = DatasetSource(kind=kind, path=str(label), version=version, sha256=tree.digest())
    return Dataset(source=source, goals=tuple(goals))


_SPLIT_MODULE_FILES = ("SMALL/instructions.py", "SMALL/instructions/__init__.py", "SMALL/test.py")


def _join(prefix: str, relpath: str) -> str:
    return f"{prefix}/{relpath}" if prefix else relpath


@dataclass(frozen=True)
class _ModuleRef:
    """A module, by dotted name (submodules resolve through attribute access)."""

    name: str


@dataclass(frozen=True)
class _ImportedName:
    """`from module import name`: a submodule or a binding in `module`, resolved on use."""

    module: str
    name: str


@dataclass(frozen=True)
class _AchievementRef:
    name: str
    where: str


@dataclass(frozen=True)
class _TargetState:
    required: list[Any]
    forbidden: list[Any]
    where: str


@dataclass(frozen=True)
class _Opaque:
    """A value the parser does not model (it only matters if a goal field needs it)."""

    text: str
    where: str


class _Table(dict[Any, Any]):
    """A dict value from the source, remembering where each entry was written."""

    def __init__(self) -> None:
        super().__init__()
        self.locations: dict[Any, str] = {}


class _Module:
    """One parsed source module: its top-level bindings, evaluated on demand."""

    def __init__(self, tree: _SourceTree, name: str, relpath: str, source: bytes, is_package: bool):
        self.tree = tree
        self.name = name
        self.display = f"{tree.label}/{relpath}"
        self.is_package = is_package
        try:
            syntax = ast.parse(source, filename=self.display)
        except (SyntaxError, ValueError) as error:
            line = getattr(error, "lineno", None)
            message = getattr(error, "msg", str(error))
            raise UserError(
                f"cannot parse {self.display}{f':{line}' if line else ''}: {message}"
            ) from None
        self.bindings: dict[str, ast.expr | _ModuleRef | _ImportedName] = {}
        for statement in syntax.body:
            self._bind(statement)
        self._values: dict[str, Any] = {}
        self._evaluating: set[str] = set()

    def _bind(self, statement: ast.stmt) -> None:
        if isinstance(statement, ast.Assign):
            for target in statement.targets:
                if isinstance(target, ast.Name):
                    self.bindings[target.id] = statement.value
        elif isinstance(statement, ast.AnnAssign) and statement.value is not None:
            if isinstance(statement.target, ast.Name):
                self.bindings[statement.target.id] = statement.value
        elif isinstance(statement, ast.Import):
            for alias in statement.names:
                if alias.asname:
                    self.bindings[alias.asname] = _ModuleRef(alias.name)
                else:
                    top = alias.name.split(".")[0]
                    self.bindings[top] = _ModuleRef(top)
        elif isinstance(statement, ast.ImportFrom):
            module = self._absolute(statement.module, statement.level)
            for alias in statement.names:
                self.bindings[alias.asname or alias.name] = _ImportedName(module, alias.name)

    def _absolute(self, module: str | None, level: int) -> str:
        if level == 0:
            return module or ""
        package = self.name.split(".") if self.is_package else self.name.split(".")[:-1]
        base = package[: len(package) - (level - 1)]
        return ".".join([*base, *([module] if module else [])])

    def where(self, node: ast.AST) -> str:
        return f"{self.display}:{getattr(node, 'lineno', '?')}"

    def lookup(self, name: str, wanted_at: str) -> Any:
        """The value of a top-level name, or of a submodule of this package."""
        if name in self._values:
            return self._values[name]
        binding = self.bindings.get(name)
        if binding is None:
            submodule = f"{self.name}.{name}"
            if self.tree.has_module(submodule):
                return _ModuleRef(submodule)
            return _Opaque(f"{self.name}.{name}", wanted_at)
        if name in self._evaluating:
            raise UserError(f"circular definition of {name!r} in {self.display}")
        self._evaluating.add(name)
        try:
            value = self._resolve(binding, wanted_at)
        finally:
            self._evaluating.discard(name)
        self._values[name] = value
        return value

    def _resolve(self, binding: ast.expr | _ModuleRef | _ImportedName, wanted_at: str) -> Any:
        if isinstance(binding, ast.expr):
            return self.evaluate(binding)
        if isinstance(binding, _ImportedName):
            return self.tree.resolve_import(binding, wanted_at)
        return binding

    def evaluate(self, node: ast.expr) -> Any:
        """The value of an expression, as far as the dataset needs it."""
        where = self.where(node)
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.List | ast.Tuple):
            if any(isinstance(item, ast.Starred) for item in node.elts):
                return _Opaque(ast.unparse(node), where)
            return [self.evaluate(item) for item in node.elts]
        if isinstance(node, ast.Dict):
            return self._dict(node)
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
            left, right = self.evaluate(node.left), self.evaluate(node.right)
            if isinstance(left, dict) and isinstance(right, dict):
                return _merge(_merge(_Table(), left, where), right, where)
            return _Opaque(ast.unparse(node), where)
        if isinstance(node, ast.Name):
            return self.lookup(node.id, where)
        if isinstance(node, ast.Attribute):
            return self._attribute(node, where)
        if isinstance(node, ast.Call):
            return self._call(node, where)
        return _Opaque(ast.unparse(node), where)

    def _dict(self, node: ast.Dict) -> _Table:
        table = _Table()
        for key_node, value_node in zip(node.keys, node.values, strict=True):
            if key_node is None:
                _merge(table, self.evaluate(value_node), self.where(value_node))
                continue
            key = self.evaluate(key_node)
            if isinstance(key, _Opaque):
                raise UserError(f"{key.where}: unsupported dict key {key.text!r}")
            # Like Python: a repeated key keeps its first position and takes the last value.
            table[key] = self.evaluate(value_node)
            table.locations[key] = self.where(key_node)
        return table

    def _attribute(self, node: ast.Attribute, where: str) -> Any:
        base = node.value
        if isinstance(base, ast.Name):
            binding = self.bindings.get(base.id)
            enum_name = binding.name if isinstance(binding, _ImportedName) else base.id
            if enum_name == _ACHIEVEMENT_ENUM and not isinstance(binding, ast.expr):
                return _AchievementRef(node.attr, where)
            if isinstance(binding, _ImportedName) and not self.tree.is_module(binding):
                # A class or constant from another module (e.g. `Scenarios.X`): not dataset data.
                return _Opaque(ast.unparse(node), where)
        owner = self.evaluate(base)
        if isinstance(owner, _ModuleRef):
            return self.tree.module(owner.name, where).lookup(node.attr, where)
        return _Opaque(ast.unparse(node), where)

    def _call(self, node: ast.Call, where: str) -> Any:
        function = node.func
        name = function.id if isinstance(function, ast.Name) else getattr(function, "attr", None)
        if name != _TARGET_STATE_FUNCTION:
            return _Opaque(ast.unparse(node), where)
        arguments: dict[str, Any] = {"required": [], "forbidden": []}
        for parameter, value in zip(("required", "forbidden"), node.args, strict=False):
            arguments[parameter] = self.evaluate(value)
        for keyword in node.keywords:
            if keyword.arg not in arguments:
                raise UserError(
                    f"{where}: unexpected argument {keyword.arg!r} to {_TARGET_STATE_FUNCTION}"
                )
            arguments[keyword.arg] = self.evaluate(keyword.value)
        return _TargetState(arguments["required"], arguments["forbidden"], where)


def _merge(table: _Table, other: Any, where: str) -> _Table:
    if not isinstance(other, dict):
        text = other.text if isinstance(other, _Opaque) else repr(other)
        raise UserError(f"{where}: cannot resolve {text!r} to a dict of goals")
    for key, value in other.items():
        table[key] = value
        table.locations[key] = other.locations[key] if isinstance(other, _Table) else where
    return table


class _SourceTree:
    """The dataset modules of one source, parsed on demand, with the bytes of each file read."""

    def __init__(self, files: _SourceFiles, prefix: str, label: Path):
        self.files = files
        self.prefix = prefix
        self.label = label
        self._modules: dict[str, _Module] = {}
        self._read: dict[str, bytes] = {}

    def _relpaths(self, dotted: str) -> Iterator[tuple[str, bool]]:
        parts = dotted.split(".")
        if "scenarious" in parts:
            base = self.prefix
            parts = parts[parts.index("scenarious") + 1 :]
        elif self.prefix.endswith("craftext/dataset/scenarious"):
            base = self.prefix.removesuffix("craftext/dataset/scenarious").rstrip("/")
        else:
            return
        stem = _join(base, "/".join(parts))
        yield f"{stem}.py", False
        yield _join(stem, "__init__.py"), True

    def _source(self, relpath: str) -> bytes | None:
        if relpath not in self._read:
            data = self.files.read(relpath)
            if data is None:
                return None
            self._read[relpath] = data
        return self._read[relpath]

    def has_module(self, dotted: str) -> bool:
        return any(self._source(relpath) is not None for relpath, _ in self._relpaths(dotted))

    def is_module(self, name: _ImportedName) -> bool:
        return self.has_module(f"{name.module}.{name.name}")

    def module(self, dotted: str, wanted_at: str) -> _Module:
        canonical = _canonical(dotted)
        if canonical not in self._modules:
            for relpath, is_package in self._relpaths(dotted):
                source = self._source(relpath)
                if source is not None:
                    self._modules[canonical] = _Module(self, canonical, relpath, source, is_package)
                    break
            else:
                raise UserError(f"{wanted_at}: module {dotted} not found in {self.label}")
        return self._modules[canonical]

    def resolve_import(self, name: _ImportedName, wanted_at: str) -> Any:
        if self.is_module(name):
            return _ModuleRef(f"{name.module}.{name.name}")
        if not self.has_module(name.module):
            return _Opaque(f"{name.module}.{name.name}", wanted_at)
        return self.module(name.module, wanted_at).lookup(name.name, wanted_at)

    def split_goals(self, split: Split, module_name: str, variables: tuple[str, ...]) -> list[Goal]:
        module = self.module(f"{_SCENARIOS_PACKAGE}.{module_name}", str(self.label))
        variable = next((name for name in variables if name in module.bindings), None)
        if variable is None:
            raise UserError(
                f"{module.display} defines none of {', '.join(variables)} (the {split} split)"
            )
        table = module.lookup(variable, module.display)
        if not isinstance(table, _Table):
            raise UserError(f"{module.display}: {variable} is not a dict of goals")
        return [_goal(split, key, entry, table.locations[key]) for key, entry in table.items()]

    def digest(self) -> str:
        digest = hashlib.sha256()
        for relpath in sorted(self._read):
            digest.update(relpath.encode() + b"\0" + self._read[relpath] + b"\0")
        return digest.hexdigest()


def _canonical(dotted: str) -> str:
    parts = dotted.split(".")
    if "scenarious" in parts:
        return ".".join([*_SCENARIOS_PACKAGE.split("."), *parts[parts.index("scenarious") + 1 :]])
    return dotted


def _goal(split: Split, key: Any, entry: Any, where: str) -> Goal:
    if not isinstance(key, str) or not isinstance(entry, dict):
        raise UserError(f"{where}: goal {key!r} is not a string key with a dict of fields")
    instruction = entry.get("instruction")
    paraphrases = entry.get("instruction_paraphrases", [])
    target = entry.get("arguments")
    if not isinstance(instruction, str):
        raise UserError(f"{where}: goal {key!r} has no literal 'instruction' string")
    if not isinstance(paraphrases, list) or not all(isinstance(text, str) for text in paraphrases):
        raise UserError(
            f"{where}: goal {key!r} has 'instruction_paraphrases' that are not literal strings"
        )
    if not isinstance(target, _TargetState):
        raise UserError(
            f"{where}: goal {key!r} has no {_TARGET_STATE_FUNCTION}(required=..., forbidden=...)"
        )
    required = _achievement_names(target.required, key, "required", target.where)
    forbidden = _achievement_names(target.forbidden, key, "forbidden", target.where)
    try:
        return Goal(
            id=key,
            split=split,
            category=category_of(split, required, forbidden),
            instruction=instruction,
            paraphrases=tuple(paraphrases),
            required=required,
            forbidden=forbidden,
        )
    except ValidationError as error:
        raise UserError(f"{where}: goal {key!r} is invalid: {error.errors()[0]['msg']}") from None


def _achievement_names(values: Any, goal: str, role: str, where: str) -> tuple[str, ...]:
    if not isinstance(values, list) or not all(
        isinstance(value, _AchievementRef) for value in values
    ):
        raise UserError(f"{where}: goal {goal!r}: {role} must be a list of Achievement.NAME")
    unknown = [value.name for value in values if value.name not in ACHIEVEMENT_IDS]
    if unknown:
        raise UserError(f"{where}: goal {goal!r}: unknown achievements {unknown} in {role}")
    return tuple(value.name for value in values)
