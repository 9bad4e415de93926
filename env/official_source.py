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
from env.downloads import sha256_file
from env.errors import UserError
from env.goals import (
    Dataset,
    DatasetSource,
    Goal,
    SourceKind,
    Split,
    category_of,
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


def parse_wheel(wheel: Path) -> Dataset:
    try:
        with zipfile.ZipFile(wheel) as archive:
            dataset = _parse_tree(_ZipFiles(archive), kind="wheel", label=wheel)
    except zipfile.BadZipFile:
        raise UserError(f"{wheel} is not a valid wheel (zip) file") from None
    return Dataset(
        source=dataset.source.model_copy(update={"sha256": sha256_file(wheel)}),
        goals=dataset.goals,
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
    return Dataset(
        source=dataset.source.model_copy(update={"path": url, "version": commit}),
        goals=dataset.goals,
    )


def _parse_tree(files: _SourceFiles, kind: SourceKind, label: str | Path) -> Dataset:
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

    def __init__(self, files: _SourceFiles, prefix: str, label: str | Path):
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


def parse_directory(path: Path) -> Dataset:
    """Parse a clone of the official repository or an unpacked `craftext` wheel."""
    return _parse_tree(_DirectoryFiles(path), kind="directory", label=path)
