"""Text from records made safe for the formats pages are written in: a Markdown table cell or
line (`markdown_text`, `markdown_code`) and JSON inside an HTML `<script>` element
(`inline_json`).

Every field a card or a run records is someone's text (a run label, a model spec, an agent's
import path, a hardware string): a page built from it must show it, never run it. Markdown
passes raw HTML through to the page it renders, so each character that Markdown or HTML reads
as markup is written as its HTML character reference, which both render as the character
itself and neither reads as syntax.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["inline_json", "markdown_code", "markdown_text"]

#: The characters Markdown or HTML read as markup in running text and table cells: `&` (so a
#: written reference stays text), HTML's `<` `>`, a table's `|`, a link's `[` `]`, a code
#: span's backtick, and the backslash that would escape the character after it.
_REFERENCES = {
    ord("&"): "&amp;",
    ord("<"): "&lt;",
    ord(">"): "&gt;",
    ord("|"): "&#124;",
    ord("["): "&#91;",
    ord("]"): "&#93;",
    ord("`"): "&#96;",
    ord("\\"): "&#92;",
    # A line break would end a table row or a list item early.
    ord("\n"): " ",
    ord("\r"): " ",
}


def markdown_text(value: object) -> str:
    """`value` as one line of Markdown text that renders as exactly its characters."""
    return str(value).translate(_REFERENCES)


#: What a backtick code span cannot hold: its own delimiter, a bar (it still splits a table's
#: row) and a line break.
_NOT_IN_A_CODE_SPAN = frozenset("`|\n\r")


def markdown_code(value: object) -> str:
    """`value` set as code: a backtick code span, whose content Markdown shows as written
    (`<` included), unless the text holds what a span cannot; then an HTML `<code>` element
    with its content escaped."""
    text = str(value)
    if text and _NOT_IN_A_CODE_SPAN.isdisjoint(text):
        return f"`{text}`"
    return f"<code>{markdown_text(text)}</code>"


def inline_json(data: Any) -> str:
    """`data` as JSON to place inside an HTML `<script>` element: `<`, `>` and `&` written as
    `\\u` escapes, so no value can close the element (`</script>`) or open a comment (`<!--`)
    that changes where it ends; `JSON.parse` reads the same data back."""
    text = json.dumps(data, ensure_ascii=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
