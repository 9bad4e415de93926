"""Agent packages that live outside `llm_agents/`, written to a folder by the tests: the example
of docs/writing-an-agent.md exactly as the page shows it, agents that are mistakes beside it,
and installed-package metadata (`*.dist-info`) that registers entry points, as `pip install`
leaves it."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "writing-an-agent.md"
#: The page's example files: a marker naming the file, then its fenced block.
_EXAMPLE = re.compile(r"<!-- example: (\S+) -->\n```\w*\n(.*?)```", re.S)

EXAMPLE_AGENT = "my_agents.terse:TerseAgent"

#: Agents that are mistakes, beside the example (`bad_agents.kinds`).
BAD_KINDS = '''
from typing import ClassVar

from my_agents.terse import TerseAgent

NOT_A_CLASS = 3


class NotAnAgent:
    """Has a `prepare`, and nothing else an agent needs."""

    def prepare(self, slot, observation):
        return None


class FutureAgent(TerseAgent):
    """Written for a protocol this package does not speak."""

    protocol_version: ClassVar[int] = 2


class HalfAgent(TerseAgent):
    """A class with every member, whose `from_config` builds something that is not an agent."""

    @classmethod
    def from_config(cls, config):
        return object()


class UnversionedAgent(TerseAgent):
    """Declares no version: its module's source stands for it."""

    version: ClassVar[str | None] = None
'''


def page_examples() -> dict[str, str]:
    """The page's example files: path -> text."""
    found = dict(_EXAMPLE.findall(PAGE.read_text(encoding="utf-8")))
    assert {"my_agents/terse.py", "pyproject.toml"} <= found.keys(), found.keys()
    return found


def write_outside_package(root: Path, package: str = "my_agents") -> Path:
    """`package` (the page's `my_agents`, under this name) and `bad_agents` under `root`."""
    examples = page_examples()
    (root / package).mkdir(parents=True)
    (root / package / "__init__.py").write_text("")
    terse = examples["my_agents/terse.py"]
    (root / package / "terse.py").write_text(terse)
    if package == "my_agents":
        bad = root / "bad_agents"
        bad.mkdir()
        (bad / "__init__.py").write_text("")
        (bad / "kinds.py").write_text(BAD_KINDS)
        (bad / "unimportable.py").write_text("import no_such_module_for_craftext_tests\n")
        (bad / "raising.py").write_text("raise RuntimeError('this module breaks on import')\n")
    return root


def write_distribution(
    root: Path,
    name: str,
    version: str,
    entry_points: dict[str, str],
    top_level: tuple[str, ...] = (),
) -> Path:
    """The metadata `pip install` leaves for a distribution: `NAME-VERSION.dist-info` under
    `root`, registering `entry_points` (name -> `module:Class`) in the agents' group."""
    folder = root / f"{name.replace('-', '_')}-{version}.dist-info"
    folder.mkdir(parents=True)
    (folder / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    lines = "".join(f"{key} = {value}\n" for key, value in entry_points.items())
    (folder / "entry_points.txt").write_text(f"[craftext_llm.agents]\n{lines}")
    if top_level:
        (folder / "top_level.txt").write_text("".join(f"{name}\n" for name in top_level))
    return folder


def page_distribution(root: Path) -> Path:
    """The page's `pyproject.toml`, installed: its name, version and entry points."""
    project = tomllib.loads(page_examples()["pyproject.toml"])["project"]
    return write_distribution(
        root,
        project["name"],
        project["version"],
        project["entry-points"]["craftext_llm.agents"],
        top_level=("my_agents",),
    )
