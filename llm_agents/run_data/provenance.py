"""Which code produced a record: `code_version`, recorded in each run's results and each episode.

Run from a checkout, the version is its `git describe` (tags, else the commit), and a checkout
with uncommitted changes adds a digest of its sources, since two different edits of one commit
are different code. Installed from a wheel (no checkout), it is the package's version with that
digest, since every commit once called itself 0.1.0. A run resumed under other code is allowed
(the settings, templates and data that decide answers are checked apart); the report notes a run
whose episodes came from more than one version.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import logging
import os
import platform
import subprocess
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

logger = logging.getLogger(__name__)

#: The packages whose sources make the project's code (as `pyproject.toml` ships them).
PACKAGES = ("env", "textualizer", "prompts", "llm_agents")
#: The kinds of file among them that decide what a run does (code, prompt and page templates).
_SOURCE_SUFFIXES = frozenset({".py", ".j2", ".css"})
#: Where the packages lie: the checkout's root, or the site-packages directory of an install.
_ROOT = Path(__file__).resolve().parents[2]
_DIGEST_CHARS = 12

__all__ = [
    "PACKAGES",
    "code_note",
    "code_version",
    "hardware",
    "note_other_code",
    "pooled_hardware",
    "sources_digest",
]


def sources_digest(root: Path = _ROOT) -> str:
    """SHA-256 of the packages' source files under `root`: their paths and bytes, in path order."""
    digest = hashlib.sha256()
    for package in PACKAGES:
        files = sorted(
            path
            for path in (root / package).rglob("*")
            if path.suffix in _SOURCE_SUFFIXES and "__pycache__" not in path.parts
        )
        for path in files:
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def _describe(root: Path) -> str | None:
    """`git describe` of the checkout whose root is `root`; None when it is not one (an
    install, a checkout git cannot read, or no git at all)."""

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", "-C", str(root), *args],
                capture_output=True,
                text=True,
                timeout=10,
                check=False,
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    # Packages installed inside some other repository (a venv in a project) are not its code.
    if top is None or Path(top).resolve() != root.resolve():
        return None
    return git("describe", "--tags", "--always", "--dirty", f"--abbrev={_DIGEST_CHARS}")


def _package_version() -> str:
    try:
        return importlib.metadata.version("craftext-llm")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def code_version(root: Path | None = None) -> str:
    """The version of the code under `root` (default: the code running, worked out once per
    process): `git describe` of its checkout, with `+src.` and a digest of the sources when
    the checkout has uncommitted changes; else the package version with that digest."""
    return _running_code_version() if root is None else _code_version(root)


@functools.cache
def _running_code_version() -> str:
    return _code_version(_ROOT)


def _code_version(root: Path) -> str:
    described = _describe(root)
    if described is not None and not described.endswith("-dirty"):
        return described
    base = described if described is not None else _package_version()
    return f"{base}+src.{sources_digest(root)[:_DIGEST_CHARS]}"


def note_other_code(out: Path, recorded: Mapping[str, Any]) -> None:
    """Say so (a warning) when the run in `out`, whose results record `recorded` versions, is
    resumed by code of another version: allowed, and each episode records its own."""
    before, now = recorded.get("code"), code_version()
    if before != now:
        logger.warning(
            "%s was recorded by code %s; resuming it with %s (each episode records the code "
            "that played it, and the report notes a run that mixes them)",
            out,
            before or "of an unrecorded version",
            now,
        )


def code_note(versions: Iterable[str | None], what: str = "episodes") -> str | None:
    """The report's note on a run whose records (`what`) came from more than one code version,
    each with its count, commonest first; None when they all came from one."""
    counts = Counter(version or "not recorded" for version in versions)
    if len(counts) < 2:
        return None
    listed = ", ".join(f"{version} ({count})" for version, count in counts.most_common())
    return f"Note: the {what} of this run came from different code: {listed}."


def _first_line_value(path: Path, key: str) -> str | None:
    """The value of the first `key: value` line of a /proc-style file; None when unreadable."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    for line in lines:
        name, sep, value = line.partition(":")
        if sep and name.strip() == key:
            return value.strip()
    return None


def hardware() -> dict[str, str]:
    """The machine this process runs on, as a results card shows it: CPU model and cores,
    memory, and the NVIDIA GPUs the driver lists. Read from /proc (no GPU library imported);
    what cannot be read is left out."""
    found = {"platform": f"{platform.system()} {platform.machine()}"}
    cpu = _first_line_value(Path("/proc/cpuinfo"), "model name") or platform.processor()
    if cpu:
        found["cpu"] = cpu
    found["cpu_cores"] = str(
        len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    )
    memory = _first_line_value(Path("/proc/meminfo"), "MemTotal")
    if memory and memory.split()[0].isdigit():
        found["memory_gib"] = f"{int(memory.split()[0]) / 2**20:.1f}"
    gpus = sorted(Path("/proc/driver/nvidia/gpus").glob("*/information"))
    names = [name for gpu in gpus if (name := _first_line_value(gpu, "Model"))]
    if names:
        found["gpus"] = ", ".join(names)
    return found


def pooled_hardware(machines: Iterable[Mapping[str, str]]) -> dict[str, str]:
    """Several workers' machines (`hardware` on each) as the one record a card shows: each
    field's distinct values in the order first seen, joined by ` + ` (one value where they
    agree), and how many workers played (`workers`)."""
    pooled: dict[str, list[str]] = {}
    count = 0
    for machine in machines:
        count += 1
        for key, value in machine.items():
            values = pooled.setdefault(key, [])
            if value not in values:
                values.append(value)
    return {key: " + ".join(values) for key, values in pooled.items()} | {"workers": str(count)}
