"""The documentation: the README stays a front page, and the MkDocs site under docs/ builds under
`--strict`, so a broken link or anchor, or a page left out of the nav, fails the suite.

The site is built by the real `mkdocs` (the `dev` extra), into a temporary folder; the checks
that it fails are real builds of a copy of the site with one fault added. The reference pages
are generated from the code as the site builds (scripts/docs_reference.py, an mkdocs hook): the
tests check that they cover every flag of the parser, and that the hand-written pages name only
flags the parser has.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from llm_agents.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
HOOK = ROOT / "scripts" / "docs_reference.py"
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
    """What the site is built from (mkdocs.yml, docs/, the reference hook and the changelog it
    reads), copied under `target`."""
    shutil.copy2(ROOT / "mkdocs.yml", target / "mkdocs.yml")
    shutil.copy2(ROOT / "CHANGELOG.md", target / "CHANGELOG.md")
    shutil.copytree(ROOT / "docs", target / "docs")
    (target / "scripts").mkdir()
    shutil.copy2(HOOK, target / "scripts" / HOOK.name)
    return target


def reference_generator() -> Any:
    """scripts/docs_reference.py, the hook that generates the reference pages, as a module."""
    spec = importlib.util.spec_from_file_location("docs_reference", HOOK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def generated() -> dict[str, str]:
    """Every generated page, by its path under docs/."""
    return reference_generator().pages()


def hand_pages() -> list[Path]:
    """The pages written by hand: docs/ and the README."""
    return [*sorted((ROOT / "docs").rglob("*.md")), README]


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


def _flags_on(page: str) -> set[str]:
    """The flags a reference page's tables name (each row's first cell)."""
    return {
        flag
        for line in page.splitlines()
        if line.startswith("| `--")
        for flag in re.findall(r"`(--[\w-]+)`", line.split(" | ")[0])
    }


@pytest.mark.parametrize("command", sorted(_long_options(build_parser())))
def test_every_flag_of_the_parser_is_on_its_command_page(
    command: str, generated: dict[str, str]
) -> None:
    page = generated.get(f"reference/cli/{command}.md")
    assert page is not None, f"craftext-llm {command} has no generated reference page"
    missing = sorted(_long_options(build_parser())[command] - _flags_on(page))
    assert not missing, f"craftext-llm {command}: flags its reference page lacks: {missing}"


def test_a_new_command_and_flag_get_a_page_with_no_edit() -> None:
    """What another command would get: the generator reads whatever the parser holds."""
    generator = reference_generator()
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    extra = commands.add_parser("brand-new", help="a command added later")
    extra.add_argument("--brand-new-flag", type=int, default=3, choices=[3, 4], help="its help")
    page = generator.command_page("brand-new", extra, "a command added later")
    [row] = [line for line in page.splitlines() if line.startswith("| `--brand-new-flag`")]
    assert "its help" in row and "`3`" in row and "`4`" in row
    assert "brand-new" in generator.subcommands(parser)


#: A flag a hand page names after `craftext-llm COMMAND`, up to the end of that command (a
#: comment, a pipe, `;`, `&&`, or the end of the code span or line).
_COMMAND_LINE = re.compile(r"craftext-llm\s+([a-z][\w-]*)([^`#|;&\n]*)")


def _commands_written(text: str) -> list[tuple[str, str]]:
    """(command, the rest of its line) for every `craftext-llm COMMAND ...` a page writes, a
    shell line continued by `\\` joined first."""
    joined = re.sub(r"\\\n\s*", " ", text)
    return _COMMAND_LINE.findall(joined)


def _unknown_flags(text: str, options: dict[str, set[str]]) -> list[str]:
    """`COMMAND --FLAG` for each flag `text` writes after `craftext-llm COMMAND` that the
    command's parser lacks."""
    return [
        f"{command} {flag}"
        for command, rest in _commands_written(text)
        if command in options
        for flag in re.findall(r"(?<![\w-])--[a-z][\w-]*", rest)
        if flag not in options[command] | {"--help", "--verbose"}
    ]


def test_hand_pages_name_only_flags_their_command_has() -> None:
    options = _long_options(build_parser())
    wrong = [
        f"{path.relative_to(ROOT)}: craftext-llm {found}"
        for path in hand_pages()
        for found in _unknown_flags(path.read_text(encoding="utf-8"), options)
    ]
    assert not wrong, wrong


def test_the_check_of_hand_pages_finds_a_flag_that_does_not_exist() -> None:
    options = _long_options(build_parser())
    text = "```bash\ncraftext-llm eval --model m \\\n    --no-such-flag 3   # --not-this\n```"
    assert _unknown_flags(text, options) == ["eval --no-such-flag"]
    assert _unknown_flags("`craftext-llm report RUN --success-rule official`", options) == []


def test_every_backend_option_is_on_the_backends_page(generated: dict[str, str]) -> None:
    page = generated["reference/backends.md"]
    for name, cls in reference_generator().backends():
        assert f"## {name}" in page
        for option in cls.accepted_options():
            assert f"`{option}`" in page, f"{name} option {option} is not documented"


@pytest.mark.parametrize(
    ("record", "field"),
    [
        ("EpisodeRecord", "episode_id"),
        ("EpisodeRecord", "instruction_variant"),
        ("StepRecord", "raw_output"),
        ("StepRecord", "action_id"),
        ("StepRecord", "computed_prompt_tokens"),
        ("EpisodeRecord", "goal_at_game_over"),
    ],
)
def test_record_fields_are_documented_with_their_meaning(
    record: str, field: str, generated: dict[str, str]
) -> None:
    page = generated["reference/records.md"]
    section = page.split(f"### {record}\n", 1)[1].split("\n### ", 1)[0]
    [row] = [line for line in section.splitlines() if line.startswith(f"| `{field}` |")]
    meaning = row.rstrip(" |").rsplit(" | ", 1)[1]
    assert len(meaning.split()) >= 3, row


def test_every_record_file_names_its_schema_version(generated: dict[str, str]) -> None:
    page = generated["reference/records.md"]
    for name in ("results.json", "episodes.jsonl", "steps.jsonl", "card.json"):
        [row] = [line for line in page.splitlines() if line.startswith(f"| `{name}` |")]
        assert row.rstrip(" |").rsplit(" | ", 1)[1], row
    from llm_agents.judging.card import CARD_SCHEMA_VERSION

    assert f"`schema_version` {CARD_SCHEMA_VERSION}" in page


def test_the_agent_api_page_documents_the_protocol(generated: dict[str, str]) -> None:
    page = generated["reference/agent-api.md"]
    for heading in (
        "## Agent",
        "## Decision",
        "## ChoiceSet",
        "## AgentSettings",
        "## Observation",
    ):
        assert f"\n{heading}\n" in page, heading
    from llm_agents.agents.protocol import CLASS_MEMBERS

    for member in CLASS_MEMBERS:
        assert f"| `{member}` |" in page, member


def test_no_table_cell_holds_a_bar_inside_a_code_span() -> None:
    """The code host's Markdown ends a table cell at a `|` even inside a code span."""
    found = [
        f"{path.relative_to(ROOT)}:{number}: {span}"
        for path in hand_pages()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if line.lstrip().startswith("|")
        for span in re.findall(r"`[^`]+`", line)
        if "|" in span
    ]
    assert not found, found


#: What a user page must not say: the project's issue numbers, the machines it borrowed, what
#: happened on a day, or where a contributor's checkout keeps reference data.
_DIARY = re.compile(
    r"\bissues? [0-9]+|this stop|the lease|\btoday|borrowed|session's time|shared/data",
    re.IGNORECASE,
)
#: Contributor pages, which may say where the reference data lives.
_CONTRIBUTOR_PAGES = {"development.md", "benchmarks.md", "first-test-run.md"}


def test_user_pages_speak_to_users() -> None:
    found = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()[:80]}"
        for path in hand_pages()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        for match in _DIARY.finditer(line)
        if not (path.name in _CONTRIBUTOR_PAGES and "shared/data" in match.group(0))
    ]
    assert not found, found
