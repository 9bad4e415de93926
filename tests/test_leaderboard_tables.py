"""Which table a card goes in: only the cards replayed here are ranked, a card alone goes apart
whatever replay it records, and a `paper` run off the paper's data, variant, step cap or rule
never sits beside the published rows. Built from the project's published cards (no run needed:
what is checked here is where a card goes, not its replay)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from llm_agents.cli import main
from llm_agents.judging.card import Card, read_card
from llm_agents.judging.published import PUBLISHED, PUBLISHED_TRAINED_EASY
from llm_agents.viewer.leaderboard import cards_markdown, leaderboard_data

ROOT = Path(__file__).resolve().parent.parent
EXPERT = ROOT / "docs" / "cards" / "easy-expert" / "card.json"
OFF_DATA = "dataset: easy_train not the official data at 1c518ae (source: wheel craftext-0.2.2)"


def _sections(data: dict[str, Any]) -> dict[str, list[str]]:
    return {s["id"]: [row["name"] for row in s["rows"]] for s in data["sections"]}


def test_a_card_replayed_here_and_comparable_sits_beside_the_published_rows() -> None:
    card = read_card(EXPERT)
    sections = _sections(leaderboard_data([card], ["expert"], [None], [True]))
    published = [p.model for p in (*PUBLISHED, *PUBLISHED_TRAINED_EASY)]
    assert sections["easy-paper"] == [card.run, *published]
    assert "easy-paper-unverified" not in sections and "easy-paper-differs" not in sections


def test_a_paper_run_off_the_official_data_is_never_in_a_paper_table() -> None:
    card = read_card(EXPERT)
    off = card.model_copy(
        update={
            "run": "wheel-run",
            "protocol": card.protocol.model_copy(update={"paper_differences": [OFF_DATA]}),
        }
    )
    data = leaderboard_data([card, off], ["expert", "wheel"], [None, None], [True, True])
    sections = _sections(data)
    assert "wheel-run" not in sections["easy-paper"] and card.run in sections["easy-paper"]
    assert sections["easy-paper-differs"] == ["wheel-run"]
    row = next(r for s in data["sections"] for r in s["rows"] if r["name"] == "wheel-run")
    assert row["data"] == OFF_DATA.removeprefix("dataset: ") and row["rule"] == "official"
    text = cards_markdown([card, off], replayed=[True, True])
    comparable, _, differs = text.partition("not comparable with the paper's numbers")
    assert "| easy-expert |" in comparable
    assert "wheel-run" not in comparable and "| wheel-run |" in differs
    assert "wheel craftext-0.2.2" in differs


def test_a_card_not_replayed_here_goes_apart_whatever_it_records() -> None:
    card = read_card(EXPERT)
    assert card.replay is not None  # it says it was replayed when it was written
    sections = _sections(leaderboard_data([card], ["expert"], [None], [False]))
    assert sections["easy-paper-unverified"] == [card.run]
    assert card.run not in sections["easy-paper"]
    text = cards_markdown([card], replayed=[False])
    assert text.startswith("**EASY, protocol paper: NOT replayed here**")
    assert "the card says: 605 episodes" in text and "(not checked here)" in text


def _forged(tmp_path: Path) -> Path:
    """The published card with its success rate raised and its digest computed again."""
    data = json.loads(EXPERT.read_text())
    data["figures"]["success"]["rate"] = 1.0
    body = Card.model_validate(data).model_dump(mode="json", exclude={"digest"})
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    body["digest"] = hashlib.sha256(canonical.encode()).hexdigest()
    path = tmp_path / "forged" / "card.json"
    path.parent.mkdir()
    path.write_text(json.dumps(body))
    return path


def test_a_forged_card_given_alone_is_never_ranked(tmp_path: Path, capsys: Any) -> None:
    forged = _forged(tmp_path)
    site, table = tmp_path / "site", tmp_path / "table.md"
    assert main(["leaderboard", str(forged), "--out", str(site)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be replayed here (it is given without its run)" in err[0]
    assert not site.exists()

    assert main(["leaderboard", str(forged), "--unverified", "--out", str(site)]) == 0
    assert main(["leaderboard", str(forged), "--unverified", "--markdown", str(table)]) == 0
    assert "0 replayed here and ranked, 1 not replayed here" in capsys.readouterr().out
    inline = (site / "index.html").read_text()
    data = json.loads(inline.split('type="application/json">')[1].split("</script>")[0])
    sections = _sections(data)
    assert sections["easy-paper-unverified"] == ["easy-expert"]
    assert "easy-expert" not in sections["easy-paper"]
    assert table.read_text().startswith("**EASY, protocol paper: NOT replayed here**")
    assert "| 1.00 [" in table.read_text()


@pytest.mark.parametrize("given", ["absent", "not-a-run"])
def test_a_card_given_with_a_folder_that_is_no_run_is_refused(
    given: str, tmp_path: Path, capsys: Any
) -> None:
    folder = tmp_path / given
    if given == "not-a-run":
        folder.mkdir()
        (folder / "notes.txt").write_text("mine")
    out = tmp_path / "site"
    assert main(["leaderboard", f"{EXPERT}={folder}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("does not exist" in err[0] or "not a run directory" in err[0])
    assert not out.exists()
