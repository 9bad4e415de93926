"""An evaluator for the subset of Python the official dataset modules are written in: top-level
bindings, imports between the modules, dict and list literals, `**` spreads and `|` merges, enum
members and `create_target_state(...)` calls, read with `ast` (the modules import JAX at module
level, so importing them is not an option). Its values (`Table`, `TargetState`, `StateRecord`,
...) are what `env.official_goals` turns into goals."""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from env.errors import UserError
from env.official_files import SourceFiles, join_path
from env.official_tables import (
    ACHIEVEMENT_ENUM,
    ENUMS,
    SCENARIOS_PACKAGE,
    STATE_FIELDS,
    TARGET_STATE_FUNCTION,
)


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
class AchievementRef:
    name: str
    where: str


@dataclass(frozen=True)
class EnumRef:
    """`Enum.MEMBER` of one of the official constant classes (`ENUMS`)."""

    enum: str
    member: str
    where: str


@dataclass(frozen=True)
class TargetState:
    required: list[Any]
    forbidden: list[Any]
    where: str


@dataclass(frozen=True)
class StateRecord:
    """A target-state record other than achievements: its class and its fields' values."""

    name: str
    fields: dict[str, Any]
    where: str


@dataclass(frozen=True)
class Opaque:
    """A value the parser does not model (it only matters if a goal field needs it)."""

    text: str
    where: str


class Table(dict[Any, Any]):
    """A dict value from the source, remembering where each entry was written."""

    def __init__(self) -> None:
        super().__init__()
        self.locations: dict[Any, str] = {}


class SourceModule:
    """One parsed source module: its top-level bindings, evaluated on demand."""

    def __init__(self, tree: SourceTree, name: str, relpath: str, source: bytes, is_package: bool):
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
            return Opaque(f"{self.name}.{name}", wanted_at)
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
                return Opaque(ast.unparse(node), where)
            return [self.evaluate(item) for item in node.elts]
        if isinstance(node, ast.Dict):
            return self._dict(node)
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
            left, right = self.evaluate(node.left), self.evaluate(node.right)
            if isinstance(left, dict) and isinstance(right, dict):
                return _merge(_merge(Table(), left, where), right, where, self.tree.notes)
            return Opaque(ast.unparse(node), where)
        if isinstance(node, ast.Name):
            return self.lookup(node.id, where)
        if isinstance(node, ast.Attribute):
            return self._attribute(node, where)
        if isinstance(node, ast.Call):
            return self._call(node, where)
        return Opaque(ast.unparse(node), where)

    def _dict(self, node: ast.Dict) -> Table:
        table = Table()
        for key_node, value_node in zip(node.keys, node.values, strict=True):
            if key_node is None:
                _merge(table, self.evaluate(value_node), self.where(value_node), self.tree.notes)
                continue
            key = self.evaluate(key_node)
            if isinstance(key, Opaque):
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
            if enum_name == ACHIEVEMENT_ENUM and not isinstance(binding, ast.expr):
                return AchievementRef(node.attr, where)
            if enum_name in ENUMS and not isinstance(binding, ast.expr):
                return EnumRef(enum_name, node.attr, where)
            if isinstance(binding, _ImportedName) and not self.tree.is_module(binding):
                # A class or constant from another module (e.g. `Scenarios.X`): not dataset data.
                return Opaque(ast.unparse(node), where)
        owner = self.evaluate(base)
        if isinstance(owner, _ModuleRef):
            return self.tree.module(owner.name, where).lookup(node.attr, where)
        return Opaque(ast.unparse(node), where)

    def _call(self, node: ast.Call, where: str) -> Any:
        function = node.func
        name = function.id if isinstance(function, ast.Name) else getattr(function, "attr", None)
        if name != TARGET_STATE_FUNCTION:
            return Opaque(ast.unparse(node), where)
        definition = self.functions.get(name)
        if definition is not None and (record := self._state_record(definition, node, where)):
            return record
        arguments: dict[str, Any] = {"required": [], "forbidden": []}
        for parameter, value in zip(("required", "forbidden"), node.args, strict=False):
            arguments[parameter] = self.evaluate(value)
        for keyword in node.keywords:
            if keyword.arg not in arguments:
                raise UserError(
                    f"{where}: unexpected argument {keyword.arg!r} to {TARGET_STATE_FUNCTION}"
                )
            arguments[keyword.arg] = self.evaluate(keyword.value)
        return TargetState(arguments["required"], arguments["forbidden"], where)

    def _state_record(
        self, definition: ast.FunctionDef, call: ast.Call, where: str
    ) -> StateRecord | None:
        """A module's own `create_target_state` applied to `call`'s arguments, when its body
        builds one of the records in `STATE_FIELDS` (EASY's builds an achievement mask, read
        by the caller)."""
        constructor = next(
            (
                node
                for node in ast.walk(definition)
                if isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and self._class_name(node.func.id) in STATE_FIELDS
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
            raise UserError(f"{where}: too many arguments to {TARGET_STATE_FUNCTION}")
        for parameter, value in zip(parameters, call.args, strict=False):
            bound[parameter] = self.evaluate(value)
        for keyword in call.keywords:
            if keyword.arg not in parameters:
                raise UserError(
                    f"{where}: unexpected argument {keyword.arg!r} to {TARGET_STATE_FUNCTION}"
                )
            bound[keyword.arg] = self.evaluate(keyword.value)

        def value_of(node: ast.expr) -> Any:
            if isinstance(node, ast.Name) and node.id in parameters:
                if node.id not in bound:
                    raise UserError(f"{where}: {TARGET_STATE_FUNCTION} needs {node.id!r}")
                return bound[node.id]
            return self.evaluate(node)

        class_name = self._class_name(constructor.func.id)
        fields = dict(STATE_FIELDS[class_name])
        names = list(fields)
        for index, value in enumerate(constructor.args):
            fields[names[index]] = value_of(value)
        for keyword in constructor.keywords:
            if keyword.arg in fields:
                fields[keyword.arg] = value_of(keyword.value)
        return StateRecord(class_name, fields, where)

    def _class_name(self, local: str) -> str:
        binding = self.bindings.get(local)
        return binding.name if isinstance(binding, _ImportedName) else local


def _merge(table: Table, other: Any, where: str, notes: list[str] | None = None) -> Table:
    if not isinstance(other, dict):
        text = other.text if isinstance(other, Opaque) else repr(other)
        raise UserError(f"{where}: cannot resolve {text!r} to a dict of goals")
    for key, value in other.items():
        if notes is not None and key in table:
            added = other.locations[key] if isinstance(other, Table) else where
            notes.append(f"key {key!r} from {added} replaces {table.locations[key]} at {where}")
        table[key] = value
        table.locations[key] = other.locations[key] if isinstance(other, Table) else where
    return table


class SourceTree:
    """The dataset modules of one source, parsed on demand, with the bytes of each file read."""

    def __init__(self, files: SourceFiles, prefix: str, label: str | Path):
        self.files = files
        self.prefix = prefix
        self.label = label
        self._modules: dict[str, SourceModule] = {}
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
        stem = join_path(base, "/".join(parts))
        yield f"{stem}.py", False
        yield join_path(stem, "__init__.py"), True

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

    def module(self, dotted: str, wanted_at: str) -> SourceModule:
        canonical = _canonical(dotted)
        if canonical not in self._modules:
            for relpath, is_package in self._relpaths(dotted):
                source = self._source(relpath)
                if source is not None:
                    self._modules[canonical] = SourceModule(
                        self, canonical, relpath, source, is_package
                    )
                    break
            else:
                raise UserError(f"{wanted_at}: module {dotted} not found in {self.label}")
        return self._modules[canonical]

    def resolve_import(self, name: _ImportedName, wanted_at: str) -> Any:
        if self.is_module(name):
            return _ModuleRef(f"{name.module}.{name.name}")
        if not self.has_module(name.module):
            return Opaque(f"{name.module}.{name.name}", wanted_at)
        return self.module(name.module, wanted_at).lookup(name.name, wanted_at)

    def digest(self) -> str:
        digest = hashlib.sha256()
        for relpath in sorted(self._read):
            digest.update(relpath.encode() + b"\0" + self._read[relpath] + b"\0")
        return digest.hexdigest()


def _canonical(dotted: str) -> str:
    parts = dotted.split(".")
    if "scenarious" in parts:
        return ".".join([*SCENARIOS_PACKAGE.split("."), *parts[parts.index("scenarious") + 1 :]])
    return dotted
