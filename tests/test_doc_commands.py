"""Every command the planning guides show runs as written: each `craftext-llm` line of their
bash blocks is parsed by the CLI's own parser and its settings built and checked as the command
would (nothing is played or loaded), and each `python -m benchmarks.tune_planner` line by that
script's parser and settings."""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import pytest

from benchmarks import tune_planner
from llm_agents.cli import _settings, build_parser, score_config

ROOT = Path(__file__).resolve().parents[1]
GUIDES = (
    "docs/guides/tuning-a-planner.md",
    "docs/commands/plan-score.md",
    "docs/commands/plan.md",
)
_BLOCK = re.compile(r"```bash\n(.*?)```", re.S)


_LOOP = re.compile(r"for (\w+) in (\S+)")
_VARIABLE = re.compile(r"\$\{?(\w+)[^}\s\"/]*\}?")


def commands(page: str) -> list[list[str]]:
    """The page's command lines, continuations joined, comments left off, and a shell loop's
    variable given its first value (any other variable a word of its own)."""
    found = []
    for block in _BLOCK.findall((ROOT / page).read_text(encoding="utf-8")):
        values = dict(_LOOP.findall(block))

        def value(match: re.Match[str], values: dict[str, str] = values) -> str:
            return values.get(match.group(1), match.group(1).lower())

        block = _VARIABLE.sub(value, block)
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words[:1] == ["craftext-llm"] or words[:3] == [
                "python",
                "-m",
                "benchmarks.tune_planner",
            ]:
                found.append(words)  # fmt: skip
    return found


CASES = [(page, words) for page in GUIDES for words in commands(page)]


def test_the_guides_show_commands() -> None:
    for page in GUIDES:
        assert commands(page), page
    assert any(words[1] == "plan-score" for _, words in CASES)


@pytest.mark.parametrize(("page", "words"), CASES, ids=[" ".join(w)[:80] for _, w in CASES])
def test_each_command_of_the_guides_parses_and_its_settings_hold(
    page: str, words: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    # The guides run from a checkout, where the benchmarks' prompt folders are.
    (tmp_path / "benchmarks").symlink_to(ROOT / "benchmarks")
    if words[0] == "craftext-llm":
        args = build_parser().parse_args(words[1:])
        if words[1] == "plan-score":
            score_config(args)
        elif getattr(args, "settings_class", None) is not None:
            _settings(args)
        return
    argv = words[3:]

    def reached(*given: Any) -> None:
        raise Reached(given)

    monkeypatch.setattr(tune_planner, "train", reached)
    monkeypatch.setattr(tune_planner, "compare", reached)
    if argv[0] in ("train", "compare"):
        # The settings are built and checked; the run itself is where the test stops.
        with pytest.raises(Reached):
            tune_planner.main(argv)
    else:
        with pytest.raises(SystemExit) as exit_:
            tune_planner.main([argv[0], "--help"])
        assert exit_.value.code == 0


class Reached(Exception):
    """The command got past its settings to its work."""
