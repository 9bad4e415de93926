"""Command-line flags generated from typed settings, so a setting is declared exactly once.

Every field of a pydantic settings class becomes `--field-name`, with the field's docstring as
its help; fields of nested models (`generation`) become flags of their own, read back into the
nested table. Flags default to None, meaning "not given": only given flags override a config
file, and the model's own defaults apply last.
"""

from __future__ import annotations

import argparse
import enum
import json
import sys
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from pydantic.fields import FieldInfo

#: Extra spellings kept so that a flag reads naturally when repeated.
ALIASES: dict[str, tuple[str, ...]] = {"backend_options": ("--backend-option",)}

#: Old spellings of renamed settings: still accepted, so scripts keep working, with a notice
#: naming the current flag so that they get updated.
DEPRECATED: dict[str, tuple[str, ...]] = {"categories": ("--splits",)}


class _StoreNoticingDeprecated(argparse.Action):
    """Store the value like a plain flag; given by a deprecated spelling, say which to use."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        current = self.option_strings[0]
        if option_string is not None and option_string != current:
            print(
                f"{parser.prog}: warning: {option_string} is deprecated; use {current}",
                file=sys.stderr,
            )
        setattr(namespace, self.dest, values)


@dataclass(frozen=True)
class FlagTarget:
    """Where a parsed flag's value goes in the settings dict."""

    dest: str
    """The argparse destination."""
    path: tuple[str, ...]
    """Keys into the settings dict, e.g. ("generation", "temperature")."""


def _key_value(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        parsed = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    return key.strip(), parsed


def _unwrap_optional(annotation: Any) -> Any:
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        members = [arg for arg in typing.get_args(annotation) if arg is not type(None)]
        if len(members) == 1:
            return members[0]
    return annotation


def _help(field: FieldInfo) -> str:
    text = " ".join((field.description or "").split())
    default = field.get_default(call_default_factory=True)
    if isinstance(default, enum.Enum):
        default = default.value
    if isinstance(default, BaseModel | dict) or default is None or field.is_required():
        return text.replace("%", "%%")
    if isinstance(default, tuple | list):
        default = " ".join(str(item) for item in default)
    return f"{text} (default: {default})".replace("%", "%%")


def _singular(name: str) -> str:
    return name[:-3] + "y" if name.endswith("ies") else name.rstrip("s")


def add_settings_flags(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    model: type[BaseModel],
    *,
    skip: Sequence[str] = (),
    path: tuple[str, ...] = (),
) -> list[FlagTarget]:
    """Add a flag for every field of `model` (recursing into nested models)."""
    targets: list[FlagTarget] = []
    for name, field in model.model_fields.items():
        extra = field.json_schema_extra
        if name in skip or (isinstance(extra, dict) and extra.get("flag") is False):
            continue
        annotation = _unwrap_optional(field.annotation)
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            group = parser.add_argument_group(name) if path == () else parser
            targets += add_settings_flags(group, annotation, path=(*path, name))
            continue
        dest = "_".join((*path, name))
        deprecated = DEPRECATED.get(name, ())
        flags = (f"--{name.replace('_', '-')}", *ALIASES.get(name, ()), *deprecated)
        options: dict[str, Any] = {"dest": dest, "default": None, "help": _help(field)}
        origin = typing.get_origin(annotation)
        if annotation is bool:
            options["action"] = argparse.BooleanOptionalAction
        elif origin is dict:
            options.update(action="append", type=_key_value, metavar="KEY=VALUE")
        elif origin in (tuple, list):
            options.update(nargs="+", metavar=_singular(name).upper())
        elif origin is typing.Literal:
            options["choices"] = [str(value) for value in typing.get_args(annotation)]
        elif isinstance(annotation, type) and issubclass(annotation, enum.Enum):
            options["choices"] = [member.value for member in annotation]
        elif annotation in (int, float):
            options.update(type=annotation, metavar=name.upper())
        elif annotation in (str, Path):
            options.update(type=str, metavar=name.upper())
        else:
            raise TypeError(f"no flag type for {model.__name__}.{name}: {field.annotation!r}")
        if deprecated:
            if "action" in options:
                raise TypeError(f"deprecated spellings of {name} need a flag that stores a value")
            options["action"] = _StoreNoticingDeprecated
            options["help"] += f" ({', '.join(deprecated)}: deprecated spelling)"
        parser.add_argument(*flags, **options)
        targets.append(FlagTarget(dest=dest, path=(*path, name)))
    return targets


def given_settings(args: argparse.Namespace, targets: Sequence[FlagTarget]) -> dict[str, Any]:
    """The settings dict of the flags that were given (nested paths become nested dicts)."""
    settings: dict[str, Any] = {}
    for target in targets:
        value = getattr(args, target.dest)
        if value is None:
            continue
        if isinstance(value, list) and value and isinstance(value[0], tuple):
            value = dict(value)
        table = settings
        for key in target.path[:-1]:
            table = table.setdefault(key, {})
        table[target.path[-1]] = value
    return settings
