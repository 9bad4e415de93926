"""The agent a run names, found and checked: a built-in's name (`registry.AGENTS`), a name an
installed package registers under the `craftext_llm.agents` entry-point group, or a
`package.module:Class` path; the class checked against the agent protocol (its version
included) before anything is written; and the identity (import path and version) of an agent
from outside this package, which a run records and a resume must match.

One lazy table, name -> `"module:Class"`: the built-ins and the entry points' names, read from
the installed distributions' metadata without importing any agent. A name both a built-in and
an entry point claim, or two entry points, is an error naming both.
"""

from __future__ import annotations

import difflib
import hashlib
import importlib
import importlib.metadata
import inspect
import re
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from env.errors import UserError
from llm_agents.agents.protocol import (
    AGENT_PROTOCOL_VERSION,
    CLASS_MEMBERS,
    INSTANCE_MEMBERS,
    Agent,
)
from llm_agents.agents.registry import AGENTS, ENTRY_POINT_GROUP
from llm_agents.run_data.store import AgentIdentity

if TYPE_CHECKING:
    from llm_agents.agents.registry import AgentSettings

__all__ = [
    "agent_class",
    "agent_identity",
    "agent_shipment",
    "build_agent",
    "check_agent_name",
    "registered_agents",
]

#: `package.module:Class`: dotted identifiers, a colon, an identifier.
_PATH = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$")
_GUIDE = "docs/writing-an-agent.md"


@dataclass(frozen=True)
class Registration:
    """Where a registered name points, and who registered it."""

    target: str
    """`"module:Class"`."""
    origin: str
    """`built-in`, or the entry point and its distribution, as an error names it."""
    distribution: importlib.metadata.Distribution | None = None
    """The distribution an entry point came from."""


def is_agent_path(spec: str) -> bool:
    """True when `spec` names a class by path (`package.module:Class`), not by a short name."""
    return ":" in spec


@lru_cache(maxsize=8)
def _entry_points(path: tuple[str, ...]) -> tuple[importlib.metadata.EntryPoint, ...]:
    # Keyed by sys.path: a directory put on it later (a test, a notebook) is seen.
    return tuple(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))


def registered_agents() -> dict[str, Registration]:
    """Every agent name: the built-ins, then the entry points' (see the module)."""
    found = {name: Registration(target, "built-in") for name, target in AGENTS.items()}
    for entry in _entry_points(tuple(sys.path)):
        dist = entry.dist
        origin = (
            f"entry point {entry.name} = {entry.value} of distribution "
            f"{dist.name if dist else '(unknown)'} (group {ENTRY_POINT_GROUP})"
        )
        if entry.name in found:
            other = found[entry.name]
            claimed = (
                f"the built-in agent {entry.name} ({other.target})"
                if other.origin == "built-in"
                else other.origin
            )
            raise UserError(f"agent name {entry.name!r} is claimed twice: {origin}, and {claimed}")
        if not _PATH.match(entry.value):
            raise UserError(f"{origin} does not name a class as package.module:Class")
        found[entry.name] = Registration(entry.value, origin, dist)
    return found


def check_agent_name(spec: str) -> None:
    """Refuse (`ValueError`, for the config's validation) a spec that is neither a registered
    name nor a well-formed `package.module:Class`; imports nothing."""
    if is_agent_path(spec):
        if not _PATH.match(spec):
            raise ValueError(f"agent {spec!r} is not a class path: write package.module:Class")
        return
    try:
        names = registered_agents()
    except UserError as err:
        raise ValueError(str(err)) from None
    if spec not in names:
        close = difflib.get_close_matches(spec, names, n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        raise ValueError(
            f"unknown agent {spec!r}; {hint}choose from {', '.join(names)}, or name a class "
            "as package.module:Class"
        )


def _target(spec: str) -> Registration:
    try:
        check_agent_name(spec)
    except ValueError as err:
        raise UserError(str(err)) from None
    return Registration(spec, "path") if is_agent_path(spec) else registered_agents()[spec]


def _import(target: str, spec: str) -> Any:
    module_name, _, class_name = target.partition(":")
    named = spec if spec == target else f"{spec} ({target})"
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise UserError(
            f"agent {named} does not import: {type(err).__name__}: {err} (is its package "
            "installed, or its folder on PYTHONPATH?)"
        ) from None
    except Exception as err:  # the agent's own module failed: still the user's code, one line
        raise UserError(
            f"agent {named}: importing {module_name} failed: {type(err).__name__}: {err}"
        ) from None
    found = getattr(module, class_name, None)
    if found is None:
        raise UserError(f"agent {named}: module {module_name} has no {class_name!r}")
    return found


def agent_class(spec: str) -> type[Agent]:
    """The class `spec` names (a registered name or `package.module:Class`), imported on first
    use and checked against the agent protocol; a `UserError` in one line otherwise."""
    registration = _target(spec)
    found: Any = _import(registration.target, spec)
    named = spec if spec == registration.target else f"{spec} ({registration.target})"
    if not inspect.isclass(found):
        raise UserError(f"agent {named} is not a class but a {type(found).__name__}")
    missing = [member for member in CLASS_MEMBERS if not hasattr(found, member)]
    if missing:
        raise UserError(
            f"agent {named} is not an agent: it lacks {', '.join(missing)} (see {_GUIDE})"
        )
    cls = cast("type[Agent]", found)
    declared = cls.protocol_version
    if declared != AGENT_PROTOCOL_VERSION:
        raise UserError(
            f"agent {named} is written for agent protocol {declared!r}; this craftext-llm "
            f"speaks protocol {AGENT_PROTOCOL_VERSION} (see {_GUIDE})"
        )
    return cls


def build_agent(config: AgentSettings) -> Agent:
    """The agent `config.agent` names, set up from the run's config."""
    cls = agent_class(config.agent)
    agent = cls.from_config(config)
    missing = [member for member in INSTANCE_MEMBERS if not hasattr(agent, member)]
    if missing:
        raise UserError(
            f"agent {config.agent} is not an agent: what its from_config builds lacks "
            f"{', '.join(missing)} (see {_GUIDE})"
        )
    return agent


# ------------------------------------------------------------------------------ identity


def agent_identity(spec: str) -> AgentIdentity | None:
    """The import path and version of the agent `spec` names when it comes from outside this
    package (None for a built-in): the version of the installed distribution that holds its
    module, else its class's `version` attribute, else a digest of its module's source."""
    registration = _target(spec)
    if registration.origin == "built-in":
        return None
    cls = agent_class(spec)
    path = f"{cls.__module__}:{cls.__qualname__}"
    dist = registration.distribution or _distribution_of(cls.__module__)
    if dist is not None:
        return AgentIdentity(
            path=path,
            version=dist.version,
            version_from="distribution",
            distribution=dist.name,
        )
    declared = getattr(cls, "version", None)
    if declared is not None:
        return AgentIdentity(path=path, version=str(declared), version_from="attribute")
    return AgentIdentity(path=path, version=_source_digest(cls), version_from="source")


def _distribution_of(module: str) -> importlib.metadata.Distribution | None:
    """The one installed distribution that lists `module`'s top-level package, if any."""
    names = importlib.metadata.packages_distributions().get(module.partition(".")[0], [])
    if len(set(names)) != 1:
        return None
    try:
        return importlib.metadata.distribution(names[0])
    except importlib.metadata.PackageNotFoundError:
        return None


def _source_digest(cls: type) -> str:
    module = sys.modules[cls.__module__]
    try:
        source = inspect.getsource(module)
    except (OSError, TypeError) as err:
        raise UserError(
            f"agent {cls.__module__}:{cls.__qualname__} has no version: it is not in an "
            f"installed distribution, declares no `version`, and its source cannot be read "
            f"({err})"
        ) from None
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


# ------------------------------------------------------------------------------ Ray


def agent_shipment(spec: str) -> Path | None:
    """The folder of the top-level package (or the file of the top-level module) of an outside
    agent that Ray workers need shipped (`py_modules`): one that lives outside any
    site-packages folder (a checkout, a folder on PYTHONPATH). An installed one is the
    cluster's to install, as this package is; a namespace package spread over several folders
    is not shipped."""
    registration = _target(spec)
    if registration.origin == "built-in":
        return None
    top = sys.modules[agent_class(spec).__module__.partition(".")[0]]
    places = list(getattr(top, "__path__", [])) or [getattr(top, "__file__", None)]
    if len(places) != 1 or places[0] is None:
        return None
    place = Path(places[0])
    return None if {"site-packages", "dist-packages"} & set(place.parts) else place
