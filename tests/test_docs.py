"""The documentation: the README stays a front page, and the MkDocs site under docs/ builds under
`--strict`, so a broken link or anchor, or a page left out of the nav, fails the suite.

The site is built by the real `mkdocs` (the `dev` extra), into a temporary folder; the checks
that it fails are real builds of a copy of the site with one fault added.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from llm_agents.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
README_MAX_LINES = 300
#: A Markdown link's target: `[text](target)`, the target up to `)` or a space.
LINK = re.compile(r"\]\(([^)\s]+)\)")


def build_site(project: Path, site: Path) -> subprocess.CompletedProcess[str]:
    """`mkdocs build --strict` of the project folder holding mkdocs.yml, into `site`."""
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=project,
        capture_output=True,
        text=True,
        timeout=300,
    )


def copy_site_sources(target: Path) -> Path:
    """The mkdocs.yml and docs/ of this checkout, copied under `target`."""
    shutil.copy2(ROOT / "mkdocs.yml", target / "mkdocs.yml")
    shutil.copytree(ROOT / "docs", target / "docs")
    return target


def nav_pages() -> list[str]:
    """Every page the nav of mkdocs.yml lists, as paths under docs/."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    pages: list[str] = []

    def walk(entry: object) -> None:
        if isinstance(entry, str):
            pages.append(entry)
        elif isinstance(entry, list):
            for item in entry:
                walk(item)
        elif isinstance(entry, dict):
            for value in entry.values():
                walk(value)

    walk(config["nav"])
    return pages


def test_the_site_builds_under_strict_with_no_warning(tmp_path: Path) -> None:
    result = build_site(ROOT, tmp_path / "site")
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert "WARNING" not in output, output


def test_a_page_left_out_of_the_nav_fails_the_build(tmp_path: Path) -> None:
    project = copy_site_sources(tmp_path)
    (project / "docs" / "orphan-page.md").write_text("# Not in the nav\n", encoding="utf-8")
    result = build_site(project, tmp_path / "site")
    assert result.returncode != 0
    assert "orphan-page.md" in result.stdout + result.stderr


@pytest.mark.parametrize(
    ("link", "named"),
    [
        ("[a page](no-such-page.md)", "no-such-page.md"),
        ("[resume](commands/eval.md#no-such-heading)", "no-such-heading"),
    ],
    ids=["broken link", "broken anchor"],
)
def test_a_broken_link_fails_the_build(tmp_path: Path, link: str, named: str) -> None:
    project = copy_site_sources(tmp_path)
    page = project / "docs" / "install.md"
    page.write_text(page.read_text(encoding="utf-8") + f"\nSee {link}.\n", encoding="utf-8")
    result = build_site(project, tmp_path / "site")
    assert result.returncode != 0
    assert named in result.stdout + result.stderr


def test_the_readme_is_a_front_page() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
    )


def test_the_readme_starts_with_make_demo_and_make_test() -> None:
    lines = [line for line in README.read_text(encoding="utf-8").splitlines() if line.strip()]
    assert lines[0].startswith("# "), lines[0]
    assert lines[1].startswith("```"), "the first thing after the title is the commands block"
    commands = [line.split("#")[0].strip() for line in lines[2:4]]
    assert commands == ["make demo", "make test"], lines[1:5]
    # ... and both are targets of the Makefile
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    for target in ("demo", "test"):
        assert re.search(rf"^{target}:", makefile, re.MULTILINE), target


def test_every_page_the_readme_links_to_exists() -> None:
    targets = [
        target
        for target in LINK.findall(README.read_text(encoding="utf-8"))
        if not re.match(r"[a-z]+:", target)  # http:, https:, mailto:
    ]
    docs_links = [target for target in targets if target.startswith("docs/")]
    assert docs_links, "the README links into docs/"
    missing = [target for target in targets if not (ROOT / target.split("#")[0]).exists()]
    assert not missing, missing


def test_every_readme_docs_link_is_a_page_of_the_nav() -> None:
    nav = set(nav_pages())
    linked = {
        target.split("#")[0].removeprefix("docs/")
        for target in LINK.findall(README.read_text(encoding="utf-8"))
        if target.startswith("docs/") and target.split("#")[0].endswith(".md")
    }
    assert linked - nav == set()


def test_every_command_has_a_guide_in_the_nav() -> None:
    nav = set(nav_pages())
    missing = [
        f"craftext-llm {name}: write docs/commands/{name}.md and add it to the nav"
        for name in COMMANDS
        if f"commands/{name}.md" not in nav
    ]
    assert not missing, missing


def _long_options(parser: argparse.ArgumentParser) -> dict[str, set[str]]:
    """Each subcommand's long options, the `--no-` spelling of a boolean flag included."""
    subparsers = next(
        action for action in parser._actions if isinstance(action, argparse._SubParsersAction)
    )
    return {
        name: {
            option
            for action in command._actions
            for option in action.option_strings
            if option.startswith("--") and option != "--help"
        }
        for name, command in subparsers.choices.items()
    }


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_flag_is_documented(command: str) -> None:
    docs = "\n".join(
        path.read_text(encoding="utf-8") for path in sorted((ROOT / "docs").rglob("*.md"))
    )
    options = _long_options(build_parser())[command]
    undocumented = sorted(
        option
        for option in options
        # a boolean flag is documented by either spelling (`--paraphrases`, `--no-paraphrases`)
        if not any(
            re.search(rf"{re.escape(spelling)}(?![\w-])", docs)
            for spelling in {option, option.replace("--no-", "--", 1), "--no-" + option[2:]}
        )
    )
    assert not undocumented, f"craftext-llm {command}: flags no docs page names: {undocumented}"
