"""The reference pages of the documentation site, generated from the code when the site builds.

mkdocs loads this file as a hook (mkdocs.yml `hooks:`): `on_config` adds a page per command to
the nav's Reference section, and `on_files` adds every generated page to the site, so the
reference cannot drift from the code. The pages:

- `reference/cli/COMMAND.md`: every flag of the command, read from the CLI parser (its help,
  default and choices); a command or flag added to the parser appears with no edit here.
- `reference/backends.md`: each backend's options (its options class: docstring, default), the
  choice rules it supports and whether it takes images.
- `reference/records.md`: the files a run writes (`results.json`, `episodes.jsonl`,
  `steps.jsonl`, `card.json`) from their pydantic models, with their schema versions.
- `reference/agent-api.md`: the agent protocol from its docstrings.

tests/test_docs.py imports it to check that every parser flag has a row here.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses
import enum
import importlib
import importlib.abc
import importlib.machinery
import inspect
import itertools
import re
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Iterator, Sequence
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

ROOT = Path(__file__).resolve().parent.parent
if TYPE_CHECKING:
    from llm_agents.backends.base import ModelAPI

REFERENCE = "reference"
#: The nav section (a title of mkdocs.yml's `nav`) the command pages are added to.
NAV_SECTION = "Reference"
#: The title of the subsection that lists the command pages.
NAV_COMMANDS = "Command-line flags"


# ------------------------------------------------------------------------------ docstrings


def _text(doc: str | None) -> str:
    """A docstring as one Markdown paragraph (line breaks inside a paragraph dropped)."""
    return " ".join(inspect.cleandoc(doc).split()) if doc else ""


def _paragraphs(doc: str | None) -> str:
    """A docstring's paragraphs, each on one line, blank lines between; a `- ` list stays a
    list, an item per line."""
    if not doc:
        return ""
    out: list[str] = []
    for block in inspect.cleandoc(doc).split("\n\n"):
        lines: list[str] = []
        for line in block.splitlines():
            line = line.strip()
            if line.startswith("- ") or not lines:
                lines.append(line)
            else:
                lines[-1] += " " + line
        if len(lines) > 1 and not lines[0].startswith("- "):
            lines[1:1] = [""]  # a list needs a blank line after the paragraph before it
        out.append("\n".join(lines))
    return "\n\n".join(out)


@cache
def attribute_docs(cls: type) -> dict[str, str]:
    """The docstrings written under the attributes of `cls` and its bases (`x: int` then
    `\"\"\"...\"\"\"`), a subclass's winning: pydantic reads them only where a model asks it to,
    dataclasses and protocols never."""
    found: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or klass.__module__ in ("builtins", "typing", "pydantic.main"):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body
        if not body or not isinstance(body[0], ast.ClassDef):
            continue
        statements = body[0].body
        for statement, after in itertools.pairwise(statements):
            name = _assigned_name(statement)
            if (
                name
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                found[name] = _text(after.value.value)
    return found


def _assigned_name(statement: ast.stmt) -> str | None:
    if isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name):
        return statement.target.id
    if isinstance(statement, ast.FunctionDef):  # a protocol's property
        return statement.name
    return None


# ------------------------------------------------------------------------------ Markdown


def _cell(text: object) -> str:
    """A table cell: one line, and no `|` that would end the cell. Python-Markdown's tables keep
    a `|` inside a code span (and would show a backslash there), so only the others are escaped."""
    parts = re.split(r"(`[^`]*`)", " ".join(str(text).split()))
    return "".join(part if part.startswith("`") else part.replace("|", "\\|") for part in parts)


def _code(text: object) -> str:
    """A code span in a table cell. Python-Markdown's tables keep a `|` inside a code span."""
    value = " ".join(str(text).split())
    return f"`{value}`" if value else ""


def _table(header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _type_name(annotation: Any) -> str:
    """A type as a reader writes it: `int | None`, `list[str]`, `Literal['a', 'b']`."""
    if annotation is type(None):
        return "None"
    if isinstance(annotation, type) and not typing.get_args(annotation):
        return annotation.__name__
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(arg) for arg in typing.get_args(annotation))
    if origin is typing.Literal:
        return " | ".join(repr(arg) for arg in typing.get_args(annotation))
    if origin is typing.Annotated:
        return _type_name(typing.get_args(annotation)[0])
    if origin is not None:
        arguments = ", ".join(
            "..." if arg is Ellipsis else _type_name(arg) for arg in typing.get_args(annotation)
        )
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{arguments}]"
    return str(annotation).replace("typing.", "")


def _default(value: Any) -> str:
    """A default as it is typed: a string bare, anything else as Python writes it."""
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, BaseModel):
        return ""
    if isinstance(value, str):
        return value if value.strip() == value and value else repr(value)
    return repr(value)


# ------------------------------------------------------------------------------ commands


def _parser() -> argparse.ArgumentParser:
    from llm_agents.cli import build_parser

    return build_parser()


def subcommands(parser: argparse.ArgumentParser | None = None) -> dict[str, Any]:
    """Each command's name -> its parser."""
    parser = parser or _parser()
    found = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(found.choices)


def _command_help(parser: argparse.ArgumentParser, name: str) -> str:
    found = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for choice in found._choices_actions:
        if choice.dest == name:
            return choice.help or ""
    return ""


def _settings_defaults(command: argparse.ArgumentParser) -> dict[str, Any]:
    """dest -> the settings class's default, for a command whose flags come from one
    (`cli_flags.add_settings_flags`: the flags themselves default to None, "not given")."""
    settings = command.get_default("settings_class")
    targets = command.get_default("flag_targets") or []
    defaults: dict[str, Any] = {}
    for target in targets:
        model: Any = settings
        field = None
        for key in target.path:
            field = model.model_fields[key]
            model = _model_of(field.annotation)
        if field is None or field.is_required():
            continue
        value = field.get_default(call_default_factory=True)
        if value is not None and value != {} and value != []:
            defaults[target.dest] = value
    return defaults


def _model_of(annotation: Any) -> Any:
    for candidate in (annotation, *typing.get_args(annotation)):
        if isinstance(candidate, type) and issubclass(candidate, BaseModel):
            return candidate
    return None


def _help(action: argparse.Action, prog: str) -> str:
    text = action.help or ""
    if "%" in text:
        with contextlib.suppress(KeyError, ValueError, TypeError):
            text = text % {**vars(action), "prog": prog}
    return " ".join(text.split())


def _spelling(action: argparse.Action) -> str:
    """The flag as typed: its spellings, then what it takes (`--max-steps MAX_STEPS`)."""
    spellings = ", ".join(f"`{option}`" for option in action.option_strings)
    if action.nargs == 0 or isinstance(action, argparse.BooleanOptionalAction):
        return spellings
    metavar = action.metavar or (None if action.choices else action.dest.upper())
    if metavar is None:
        return spellings
    if action.nargs in ("+", "*"):
        metavar = f"{metavar} [{metavar} ...]"
    return f"{spellings} {metavar}"


def flag_rows(command: argparse.ArgumentParser) -> list[tuple[str, list[argparse.Action]]]:
    """The command's options by argparse group (title, actions), `--help` left out."""
    groups = []
    for group in command._action_groups:
        actions = [
            action
            for action in group._group_actions
            if action.option_strings and not isinstance(action, argparse._HelpAction)
        ]
        if actions:
            groups.append((group.title or "options", actions))
    return groups


def command_page(name: str, command: argparse.ArgumentParser, summary: str) -> str:
    """The reference page of `craftext-llm NAME`: usage, arguments, every flag."""
    prog = command.prog
    lines = [
        f"# {prog}",
        "",
        "Generated from the command-line parser when the site builds: every argument and flag "
        f"of `{prog}`, as `{prog} --help` gives them. The [guide to `{name}`]"
        f"(../../commands/{name}.md) explains when to use which.",
        "",
    ]
    if summary:
        lines += [f"{summary[0].upper()}{summary[1:]}.", ""]
    if command.description:
        lines += [" ".join(command.description.split()), ""]
    usage = command.format_usage().removeprefix("usage: ").strip()
    lines += ["```text", usage, "```", ""]
    positionals = [
        action
        for action in command._actions
        if not action.option_strings and not isinstance(action, argparse._HelpAction)
    ]
    if positionals:
        rows = [
            (
                _code(action.metavar or action.dest),
                _cell(_help(action, prog)) + (" (optional)" if action.nargs == "?" else ""),
                ", ".join(_code(choice) for choice in action.choices or ()),
            )
            for action in positionals
        ]
        lines += ["## Arguments", "", _table(("argument", "meaning", "choices"), rows), ""]
    defaults = _settings_defaults(command)
    for title, actions in flag_rows(command):
        heading = "Options" if title in ("options", "optional arguments") else f"`{title}` options"
        table_rows: list[tuple[str, ...]] = []
        for action in actions:
            help_text = _help(action, prog)
            if action.dest in defaults:
                default = _default(defaults[action.dest])
                help_text = re.sub(r"\s*\(default: [^()]*\)$", "", help_text)
            elif action.default not in (None, False, argparse.SUPPRESS):
                default = _default(action.default)
            else:
                default = ""
            if isinstance(default, str) and len(default) > 60:
                default = default[:57] + "..."
            table_rows.append(
                (
                    _cell(_spelling(action)),
                    _cell(help_text),
                    _code(default),
                    ", ".join(_code(choice) for choice in action.choices or ()),
                )
            )
        lines += [
            f"## {heading}",
            "",
            _table(("flag", "meaning", "default", "choices"), table_rows),
            "",
        ]
    return "\n".join(lines)


# ------------------------------------------------------------------------------ importing


class _StubFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports modules of `roots` as empty stand-ins whose every attribute is a class, so a
    backend's options class can be read without its optional dependency (what Sphinx's
    `autodoc_mock_imports` does)."""

    def __init__(self, roots: set[str]) -> None:
        self.roots = roots

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname.partition(".")[0] in self.roots:
            return importlib.machinery.ModuleSpec(fullname, self, is_package=True)
        return None

    def create_module(self, spec: Any) -> types.ModuleType:
        module = types.ModuleType(spec.name)
        module.__path__ = []
        module.__getattr__ = lambda attribute: type(attribute, (Exception,), {})  # type: ignore[method-assign]
        return module

    def exec_module(self, module: types.ModuleType) -> None:
        return None


@contextlib.contextmanager
def _missing_modules_stubbed(roots: set[str]) -> Iterator[None]:
    """Within the block, the modules of `roots` that are not installed import as stand-ins.
    Every module first imported within it is forgotten afterwards, so that nothing imported
    later in the process (a test, say) meets a module built on a stand-in."""
    missing = {root for root in roots if importlib.util.find_spec(root) is None}
    before = set(sys.modules)
    finder = _StubFinder(missing)
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)
        for name in set(sys.modules) - before:
            del sys.modules[name]


#: What a backend's module imports that its extra installs (the docs need only its classes).
OPTIONAL_IMPORTS = {"vllm", "torch", "transformers", "httpx", "anyio", "accelerate", "gguf"}


def backends() -> Iterator[tuple[str, type[ModelAPI]]]:
    """Each backend's name and class, imported even where its extra is not installed: such a
    backend's module is read under stand-ins, which last while the caller holds it."""
    from llm_agents.backends import BACKENDS

    for name, target in BACKENDS.items():
        module, _, attribute = target.partition(":")
        try:
            cls = getattr(importlib.import_module(module), attribute)
        except ImportError:
            with _missing_modules_stubbed(OPTIONAL_IMPORTS):
                yield name, getattr(importlib.import_module(module), attribute)
            continue
        yield name, cls


# ------------------------------------------------------------------------------ models


def model_table(
    model: type[BaseModel], link: Callable[[type[BaseModel]], str], first: str = "field"
) -> str:
    """A row per field of a pydantic model: name (headed `first`), type, default, meaning."""
    docs = attribute_docs(model)
    rows: list[tuple[str, ...]] = []
    for name, field in model.model_fields.items():
        nested = _nested_models(field.annotation)
        kind = _code(_type_name(field.annotation))
        if nested:
            kind += " (" + ", ".join(link(item) for item in nested) + ")"
        if field.is_required():
            default = "required"
        elif field.default is PydanticUndefined:
            default = _code(_default(field.get_default(call_default_factory=True)))
        else:
            default = _code(_default(field.default))
        rows.append((f"`{name}`", kind, default, _cell(field.description or docs.get(name, ""))))
    for name, computed in model.model_computed_fields.items():
        doc = computed.description or _text(getattr(computed.wrapped_property, "__doc__", ""))
        kind = _code(_type_name(computed.return_type))
        rows.append((f"`{name}`", kind, "computed", _cell(doc)))
    return _table((first, "type", "default", "meaning"), rows)


def _nested_models(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models a field's type holds (`X`, `X | None`, `list[X]`, `dict[str, X]`)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    found: list[type[BaseModel]] = []
    for argument in typing.get_args(annotation):
        for model in _nested_models(argument):
            if model not in found:
                found.append(model)
    return found


def models_reachable(root: type[BaseModel]) -> list[type[BaseModel]]:
    """`root` and every model its fields hold, depth first, each once."""
    seen: list[type[BaseModel]] = []

    def visit(model: type[BaseModel]) -> None:
        if model in seen:
            return
        seen.append(model)
        for field in model.model_fields.values():
            for nested in _nested_models(field.annotation):
                visit(nested)

    visit(root)
    return seen


def _anchor(model: type) -> str:
    return model.__name__.lower()


def _model_sections(roots: list[type[BaseModel]], done: set[type], level: str) -> list[str]:
    lines: list[str] = []
    for root in roots:
        for model in models_reachable(root):
            if model in done:
                continue
            done.add(model)
            lines += [f"{level} {model.__name__}", ""]
            if model.__doc__ and model.__doc__ != BaseModel.__doc__:
                lines += [_paragraphs(model.__doc__), ""]
            lines += [model_table(model, lambda m: f"[{m.__name__}](#{_anchor(m)})"), ""]
    return lines


def records_page() -> str:
    from llm_agents.judging.card import CARD_FILE, CARD_SCHEMA_VERSION, Card
    from llm_agents.run_data.records import EpisodeRecord, StepRecord
    from llm_agents.run_data.store import EPISODES_FILE, RESULTS_FILE, STEPS_FILE, RunResults

    files: list[tuple[str, type[BaseModel], str, str]] = [
        (
            RESULTS_FILE,
            RunResults,
            "One JSON object, rewritten whole (atomically) as the run goes: what the run is and "
            "how far it got.",
            "none: fields are only ever added, each with a default, so a results file written "
            "by an earlier version still reads (its `versions` say which code wrote it).",
        ),
        (
            EPISODES_FILE,
            EpisodeRecord,
            "One JSON object per line, a line per finished episode, appended as episodes end.",
            "none, as `results.json`; each line's `code` names the code version that played it.",
        ),
        (
            STEPS_FILE,
            StepRecord,
            "One JSON object per line, a line per agent step, appended as steps are taken.",
            "none, as `results.json`.",
        ),
        (
            CARD_FILE,
            Card,
            "One JSON object written by `craftext-llm card`: what the run was and every figure "
            "its records give.",
            f"`schema_version` {CARD_SCHEMA_VERSION}; a reader refuses a card of any other "
            "version (write it again with `craftext-llm card RUN_DIR`).",
        ),
    ]
    lines = [
        "# Record formats",
        "",
        "Generated from the pydantic models when the site builds: every field of the files a "
        "run directory holds, its type, its default (a field with a default may be absent from "
        "records written before it existed) and what it means. [Architecture]"
        "(../architecture.md) says which module writes which file; [the changelog]"
        "(../changelog.md) lists the format changes.",
        "",
    ]
    lines += ["| file | model | layout | schema version |", "|---|---|---|---|"]
    for name, model, layout, version in files:
        lines.append(
            f"| `{name}` | [{model.__name__}](#{_anchor(model)}) | {_cell(layout)} | "
            f"{_cell(version)} |"
        )
    lines.append("")
    done: set[type] = set()
    for name, model, _, _ in files:
        lines += [f"## {name}", ""]
        lines += _model_sections([model], done, "###")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ backends


def _backend_section(name: str, cls: type[ModelAPI]) -> list[str]:
    """A backend's section: its module's docstring, choice rules, images, options."""
    from llm_agents.backends.base import ModelAPI

    lines = [f"## {name}", "", _paragraphs(sys.modules[cls.__module__].__doc__ or cls.__doc__), ""]
    rules = ", ".join(f"`{rule}`" for rule in sorted(cls.choice_rules)) or "none"
    lines += [f"**Choice rules**: {rules}."]
    for rule, why in cls.choice_rule_gaps.items():
        lines += [f"Not `{rule}`: {_text(why)}"]
    lines.append("")
    if cls.check_images is ModelAPI.check_images:
        lines += ["**Images** (`--observation image` or `both`): not taken.", ""]
    else:
        taken = _text(cls.check_images.__doc__ or "taken")
        lines += [f"**Images** (`--observation image` or `both`): {taken}", ""]
    honoured = ", ".join(f"`{field}`" for field in sorted(cls.honoured_config))
    lines += [f"**Generation settings it reads**: {honoured or 'none'}.", ""]
    if cls.options_model is not None:
        lines += [
            f"### {name} options",
            "",
            model_table(cls.options_model, lambda m: m.__name__, "option"),
        ]
    else:
        accepted = cls.accepted_options()
        text = ", ".join(f"`{option}`" for option in accepted) if accepted else "none"
        lines += [f"**Options**: {text}."]
    return [*lines, ""]


def backends_page() -> str:
    from llm_agents.backends.base import GenerateConfig, ModelAPI

    lines = [
        "# Backend options",
        "",
        "Generated from the backends' classes when the site builds. A backend's options are "
        "given with `--backend-option KEY=VALUE` (repeatable; the value is read as JSON when it "
        "parses, else as text) or under `backend_options` in a `--config` file; an option the "
        "backend lacks is refused with the ones it accepts. [Model specs](../backends/index.md) "
        "explains how to choose a backend.",
        "",
    ]
    rows: list[tuple[str, ...]] = []
    sections: list[str] = []
    for name, cls in backends():
        rules = ", ".join(f"`{rule}`" for rule in sorted(cls.choice_rules)) or "none"
        images = "yes" if cls.check_images is not ModelAPI.check_images else "no"
        rows.append((f"[{name}](#{name})", rules, images))
        sections += _backend_section(name, cls)
    lines += [_table(("backend", "choice rules (`--choice`)", "images"), rows), ""]
    lines += sections
    lines += [
        "## Generation settings",
        "",
        "The `GenerateConfig` every backend is handed (flags of `eval` under "
        "[generation](cli/eval.md)); a backend refuses one it does not read when it would "
        "change answers.",
        "",
        model_table(GenerateConfig, lambda m: m.__name__),
        "",
    ]
    return "\n".join(lines)


# ------------------------------------------------------------------------------ agent API


def _signature(function: Any) -> str:
    try:
        signature = str(inspect.signature(function))
    except (TypeError, ValueError):
        return "(...)"
    # Postponed annotations come back as strings: show them as written.
    return signature.replace("'", "")


def _class_members(cls: type, names: tuple[str, ...]) -> list[tuple[str, str, str]]:
    """(name, what, doc) for each member: an attribute's annotation, a method's signature."""
    docs = attribute_docs(cls)
    hints = getattr(cls, "__annotations__", {})
    rows: list[tuple[str, str, str]] = []
    for name in names:
        member = inspect.getattr_static(cls, name, None)
        if isinstance(member, classmethod | staticmethod):
            function = member.__func__
            rows.append((name, f"{name}{_signature(function)}", _text(function.__doc__)))
        elif inspect.isfunction(member):
            rows.append((name, f"{name}{_signature(member)}", _text(member.__doc__)))
        else:
            rows.append((name, f"{name}: {hints.get(name, '')}", docs.get(name, "")))
    return rows


def _dataclass_table(cls: type) -> str:
    docs = attribute_docs(cls)
    hints = typing.get_type_hints(cls, include_extras=False, localns=_agent_namespace())
    rows: list[tuple[str, ...]] = []
    for field in dataclasses.fields(cls):
        if field.default is not dataclasses.MISSING:
            default = _code(_default(field.default))
        elif field.default_factory is not dataclasses.MISSING:
            default = _code(_default(field.default_factory()))
        else:
            default = "required"
        kind = _code(_type_name(hints.get(field.name, field.type)))
        rows.append((f"`{field.name}`", kind, default, _cell(docs.get(field.name, ""))))
    return _table(("field", "type", "default", "meaning"), rows)


def _agent_namespace() -> dict[str, Any]:
    from env.goals import AnyGoal

    return {"AnyGoal": AnyGoal}


def agent_api_page() -> str:
    from llm_agents.agents import protocol
    from llm_agents.agents.registry import AgentSettings
    from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt
    from llm_agents.backends.base import ChatMessage, ChoiceSet, ModelOutput
    from llm_agents.evaluation.config import EvalConfig
    from textualizer.observation import Observation

    lines = [
        "# Agent API",
        "",
        "Generated from the docstrings of `llm_agents.agents.protocol` when the site builds. "
        "[Writing an agent](../writing-an-agent.md) walks through writing one.",
        "",
        _paragraphs(protocol.__doc__),
        "",
        f"The protocol's version: `AGENT_PROTOCOL_VERSION = {protocol.AGENT_PROTOCOL_VERSION}`. "
        "Import what an agent needs from `llm_agents.agents.protocol`: "
        + ", ".join(f"`{name}`" for name in protocol.__all__)
        + ".",
        "",
        "## Agent",
        "",
        _paragraphs(protocol.Agent.__doc__),
        "",
    ]
    members = _class_members(protocol.Agent, (*protocol.CLASS_MEMBERS, *protocol.INSTANCE_MEMBERS))
    lines += [
        _table(
            ("member", "signature", "meaning"),
            [(f"`{n}`", _code(s), _cell(d)) for n, s, d in members],
        ),
        "",
    ]
    for cls in (EpisodeStart, StepPrompt):
        lines += [f"## {cls.__name__}", "", _paragraphs(cls.__doc__), "", _dataclass_table(cls), ""]
    done: set[type] = set()
    lines += _model_sections([Decision, ChoiceSet, ChatMessage, ModelOutput], done, "##")
    lines += [
        "## AgentSettings",
        "",
        _paragraphs(AgentSettings.__doc__),
        "",
        "Each setting is a flag of `eval` ([its reference](cli/eval.md)):",
        "",
    ]
    settings = [
        name
        for name, member in vars(AgentSettings).items()
        if isinstance(member, property) and not name.startswith("_")
    ]
    hints = typing.get_type_hints(AgentSettings)
    rows: list[tuple[str, ...]] = []
    for name in settings:
        field = EvalConfig.model_fields.get(name)
        kind = _code(
            _type_name(
                typing.get_type_hints(vars(AgentSettings)[name].fget).get("return", hints.get(name))
            )
        )
        flag = f"`--{name.replace('_', '-')}`" if field is not None else ""
        rows.append((f"`{name}`", kind, flag, _cell(field.description if field else "")))
    lines += [_table(("setting", "type", "flag", "meaning"), rows), ""]
    lines += [
        "## Observation",
        "",
        "What `prepare` is handed at each step (`textualizer.observation.Observation`); "
        "[Observation](../observation.md) explains how it is rendered.",
        "",
    ]
    lines += _model_sections([Observation], done, "###")[2:]
    return "\n".join(lines)


# ------------------------------------------------------------------------------ the pages


def pages() -> dict[str, str]:
    """Every generated page: its path under docs/ -> its Markdown."""
    parser = _parser()
    generated = {
        f"{REFERENCE}/cli/{name}.md": command_page(name, command, _command_help(parser, name))
        for name, command in subcommands(parser).items()
    }
    generated[f"{REFERENCE}/backends.md"] = backends_page()
    generated[f"{REFERENCE}/records.md"] = records_page()
    generated[f"{REFERENCE}/agent-api.md"] = agent_api_page()
    # The changelog lives at the repository's root, where a reader of the code looks for it.
    generated["changelog.md"] = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    return generated


def on_config(config: Any) -> Any:
    """Add a page per command to the nav's Reference section."""
    entries = [{name: f"{REFERENCE}/cli/{name}.md"} for name in subcommands()]
    for section in config["nav"] or []:
        if isinstance(section, dict) and NAV_SECTION in section:
            section[NAV_SECTION].append({NAV_COMMANDS: entries})
            return config
    raise ValueError(f"mkdocs.yml's nav has no {NAV_SECTION!r} section for the command pages")


def on_files(files: Any, config: Any) -> Any:
    """Add the generated pages to the site."""
    from mkdocs.structure.files import File

    for path, text in pages().items():
        files.append(File.generated(config, path, content=text))
    return files
