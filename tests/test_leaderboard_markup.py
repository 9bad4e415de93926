"""Nothing a card says runs in a page built from it: every text field of a (resealed) card given
markup, the leaderboard's page, its Markdown tables and card.md pages, and the docs site built
from them show that markup as text in Chromium; no script runs and no element is added."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from headless import launch_chromium, open_page
from pydantic import ValidationError
from test_docs import build_site, copy_site_sources

from llm_agents.cli import main
from llm_agents.judging.card import Card, card_markdown, read_card
from llm_agents.run_data.markup import inline_json, markdown_code, markdown_text

ROOT = Path(__file__).resolve().parent.parent
PUBLISHED_CARD = ROOT / "docs" / "cards" / "easy-expert" / "card.json"
#: Markup of every kind a page could act on: a script closing the inline JSON's element, an
#: image whose error handler runs, a comment opening, a table's bar, a link, a code span.
HOSTILE = (
    "x</script><script>window.pwned=1</script>"
    '<img src=x onerror="window.pwned=1" data-pwned="1"><!--|[a](javascript:window.pwned=1)'
    '`<b data-pwned="1">b</b>`'
)
GENERATED = (
    "<!-- cards: the table below is generated from results cards; do not edit it by hand. -->",
    "<!-- /cards -->",
)


def _resealed(data: dict[str, Any]) -> str:
    """An edited card as JSON, with the digest of its new content, as anyone can write it."""
    body = Card.model_validate(data).model_dump(mode="json", exclude={"digest"})
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return json.dumps(body | {"digest": hashlib.sha256(canonical.encode()).hexdigest()})


def _hostile(data: dict[str, Any]) -> tuple[dict[str, Any], int]:
    """`data` with every text a card may hold (each string, each absent value, each key of a
    free table) given the hostile value, as far as the card's schema accepts; and how many."""
    changed = 0

    def valid() -> bool:
        try:
            Card.model_validate(data)
        except ValidationError:
            return False
        return True

    def walk(node: Any) -> None:
        nonlocal changed
        if isinstance(node, dict):
            for key in list(node):
                value = node[key]
                if isinstance(value, str | None):
                    node[key] = HOSTILE + (value or "")
                    if valid():
                        changed += 1
                    else:
                        node[key] = value
                else:
                    walk(value)
                renamed = HOSTILE + key
                node[renamed] = node.pop(key)
                if valid():
                    changed += 1
                else:
                    node[key] = node.pop(renamed)
        elif isinstance(node, list):
            for index, item in enumerate(node):
                if isinstance(item, str):
                    node[index] = HOSTILE + item
                    changed += 1
                else:
                    walk(item)

    walk(data)
    data["protocol"]["paper_differences"].append(HOSTILE)
    return data, changed + 1


@pytest.fixture(scope="module")
def hostile_card(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data, changed = _hostile(json.loads(PUBLISHED_CARD.read_text()))
    # The run label, agent, model spec, variant, digests, code, hardware, goal sets...
    assert changed >= 20
    folder = tmp_path_factory.mktemp("hostile") / "card"
    folder.mkdir()
    (folder / "card.json").write_text(_resealed(data))
    (folder / "card.md").write_text(card_markdown(read_card(folder / "card.json")))
    return folder / "card.json"


def test_markdown_text_is_shown_as_written() -> None:
    assert markdown_text("a|b<c>[d]`e`\\f&g\nh") == (
        "a&#124;b&lt;c&gt;&#91;d&#93;&#96;e&#96;&#92;f&amp;g h"
    )
    assert markdown_code("hf:qwen2.5-coder-0.5b") == "`hf:qwen2.5-coder-0.5b`"
    assert markdown_code("a|b") == "<code>a&#124;b</code>"
    assert markdown_code("") == "<code></code>"
    text = inline_json({"k": "</script><!--&"})
    assert "<" not in text and ">" not in text and "&" not in text
    assert json.loads(text) == {"k": "</script><!--&"}


def test_no_field_of_a_card_reaches_markdown_as_markup(hostile_card: Path, tmp_path: Path) -> None:
    table = tmp_path / "board.md"
    assert main(["leaderboard", str(hostile_card), "--unverified", "--markdown", str(table)]) == 0
    for text in (table.read_text(), card_markdown(read_card(hostile_card))):
        assert "<script" not in text and "<img" not in text and "<!--" not in text
        assert "<b " not in text and "](javascript" not in text
    # One row: the bars in the fields did not split it into more cells.
    rows = [line for line in table.read_text().splitlines() if line.startswith("| ")]
    assert len(rows) == 2 and rows[0].count(" | ") == rows[1].count(" | ")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    yield from launch_chromium()


def _nothing_ran(page: Any) -> None:
    assert page.evaluate("typeof window.pwned") == "undefined"
    assert page.locator("[data-pwned]").count() == 0
    assert page.locator("img[src='x']").count() == 0
    assert page.locator("a[href^='javascript']").count() == 0
    scripts = page.locator("script").evaluate_all("nodes => nodes.map(n => n.textContent)")
    assert not [text for text in scripts if "<script>window.pwned" in text]
    # Shown as text instead.
    assert "onerror=" in page.inner_text("body")


@pytest.mark.slow
def test_markup_in_a_card_runs_nowhere_in_chromium(
    hostile_card: Path, tmp_path: Path, browser: Any, capsys: Any
) -> None:
    site = tmp_path / "site"
    assert main(["leaderboard", str(hostile_card), "--unverified", "--out", str(site)]) == 0
    page, problems = open_page(browser, site / "index.html")
    _nothing_ran(page)
    assert (
        page.locator("#table-easy-paper-unverified .name").inner_text() == HOSTILE + "easy-expert"
    )
    assert problems == []

    # The docs site, its results page generated from the card, the card's card.md beside it.
    (tmp_path / "project").mkdir()
    project = copy_site_sources(tmp_path / "project")
    cards = project / "docs" / "cards" / "easy-expert"
    shutil.copyfile(hostile_card, cards / "card.json")
    shutil.copyfile(hostile_card.with_name("card.md"), cards / "card.md")
    table = tmp_path / "table.md"
    arguments = [str(cards / "card.json"), "--unverified", "--markdown", str(table)]
    assert main(["leaderboard", *arguments]) == 0
    results = project / "docs" / "results.md"
    before, rest = results.read_text().split(GENERATED[0])
    _, after = rest.split(GENERATED[1])
    # Linked as the docs link their cards, from the results page's folder.
    generated = table.read_text().replace("](project/docs/cards/", "](cards/")
    assert "](cards/easy-expert/card.md)" in generated
    results.write_text(before + GENERATED[0] + "\n\n" + generated + "\n" + GENERATED[1] + after)
    built = build_site(project, tmp_path / "docs-site")
    assert built.returncode == 0, built.stderr
    for path in ("results/index.html", "cards/easy-expert/card/index.html"):
        page, _ = open_page(browser, tmp_path / "docs-site" / path)
        _nothing_ran(page)
    capsys.readouterr()
