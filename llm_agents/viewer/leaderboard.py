"""`craftext-llm leaderboard`: results cards set beside each other and beside the published
numbers, as one static page (no server: its data inline, a small script, works from file://)
and as a Markdown table.

The page has a sortable table per difficulty and protocol, the success rates drawn with their
intervals. The CrafText paper's rows (its zero-shot LLMs on EASY, its trained agents' Medium
totals) sit in the `paper` tables of their difficulty, BALROG's Crafter rows beside the cards
played under `--protocol balrog`; both marked as published. Each card's row links to a copy of
the card in the site and, where its run folder is given (`CARD=RUN_DIR`), to the run's `view`
report. A card given with its run is checked against it first (its records replayed, its
figures recomputed): one the run does not give is refused, naming what differs.

Only cards whose runs were replayed are ranked: at `card` time (the card records it) or here,
given as `CARD=RUN_DIR`. Others are shown only with `--unverified`, in tables of their own
marked as not replayed. Each card's row links its card.md and states its departures from the
protocol.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jinja2
from pydantic import BaseModel

from env.errors import UserError
from env.goals import ALL_CATEGORIES, DIFFICULTY_CATEGORIES, Difficulty
from llm_agents.judging.card import (
    CARD_FILE,
    CARD_MD_FILE,
    Card,
    card_markdown,
    model_size_billions,
    read_card,
    verify_card,
)
from llm_agents.judging.published import (
    BALROG_PUBLISHED,
    PUBLISHED_BY_DIFFICULTY,
    PUBLISHED_KIND,
    PUBLISHED_TRAINED_EASY,
)
from llm_agents.judging.replay_check import RunDoesNotReplay
from llm_agents.run_data.metrics import SuccessRate
from llm_agents.run_data.store import STEPS_FILE, atomic_write_text

__all__ = [
    "CardsRefused",
    "Entry",
    "build_leaderboard",
    "cards_markdown",
    "leaderboard_data",
    "parse_entries",
]

INDEX_FILE = "index.html"
CARDS_DIR = "cards"
#: Marks a folder this command wrote, so a rebuild may replace it whole (and nothing else).
MARKER_FILE = ".craftext-leaderboard"
#: Where `craftext-llm view RUN_DIR` writes a run's report.
VIEW_INDEX = Path("report") / "index.html"
#: The difficulties the paper publishes numbers for, whose `paper` tables always show them.
_PUBLISHED_DIFFICULTIES: tuple[Difficulty, ...] = ("easy", "medium")


class CardsRefused(Exception):
    """Cards that their runs' records do not give (exit 1): `details` names each figure."""

    def __init__(self, message: str, details: list[str]) -> None:
        super().__init__(message)
        self.details = details


class Entry(BaseModel):
    """A card on the command line, with the run folder it came from when given."""

    card: Path
    run_dir: Path | None = None

    def replayed(self, card: Card) -> bool:
        """Whether the card's run was replayed: when the card was written, or here (given with
        a run that kept its step log)."""
        return card.replay is not None or (
            self.run_dir is not None and (self.run_dir / STEPS_FILE).is_file()
        )


def parse_entries(arguments: Sequence[str]) -> list[Entry]:
    """`CARD` or `CARD=RUN_DIR` arguments as entries (the split is at the last `=` whose left
    side is an existing file, so a path holding `=` still reads)."""
    if not arguments:
        raise UserError("leaderboard needs at least one card")
    entries = []
    for argument in arguments:
        card, sep, run = argument.rpartition("=")
        if sep and card and Path(card).is_file():
            entries.append(Entry(card=Path(card), run_dir=Path(run)))
        else:
            entries.append(Entry(card=Path(argument)))
    return entries


def _read(entries: Sequence[Entry]) -> list[tuple[Entry, Card]]:
    if not entries:
        raise UserError("leaderboard needs at least one card")
    read: list[tuple[Entry, Card]] = []
    seen: dict[str, Path] = {}
    for entry in entries:
        if entry.card.is_dir() and (entry.card / CARD_FILE).is_file():
            entry = entry.model_copy(update={"card": entry.card / CARD_FILE})
        card = read_card(entry.card)
        # The same file, a copy of it, or another card of the same run (written again).
        same_run = f"{card.settings_digest} {card.started_at.isoformat()}"
        for key in (str(entry.card.resolve()), card.digest, same_run):
            if key in seen:
                raise UserError(
                    f"card {entry.card} is given twice (also as {seen[key]}): give each once"
                )
            seen[key] = entry.card
        if entry.run_dir is not None and not entry.run_dir.is_dir():
            raise UserError(f"run folder {entry.run_dir} of card {entry.card} does not exist")
        read.append((entry, card))
    return read


def _verify(read: Sequence[tuple[Entry, Card]]) -> None:
    refused: list[str] = []
    names: list[str] = []
    for entry, card in read:
        if entry.run_dir is None:
            continue
        try:
            differences = verify_card(card, entry.run_dir)
        except RunDoesNotReplay as failed:
            differences = failed.differences
        if differences:
            names.append(str(entry.card))
            refused += [f"{entry.card}: {difference}" for difference in differences]
    if refused:
        raise CardsRefused(
            f"refused {len(names)} card(s) that their runs' records do not give: "
            f"{', '.join(names)}",
            refused,
        )


# ------------------------------------------------------------------------------ the rows


def _interval(rate: SuccessRate | None) -> dict[str, Any] | None:
    if rate is None:
        return None
    # Shown as Python rounds it, so the page and the card's Markdown agree (JS's toFixed
    # rounds some halves the other way).
    return {
        "text": f"{rate.rate:.2f}",
        "title": rate.cell(),
        "rate": rate.rate,
        "low": rate.low,
        "high": rate.high,
        "n": rate.episodes,
        "g": rate.clusters,
    }


def _published_rate(value: float | None) -> dict[str, Any] | None:
    if value is None:
        return None
    return {
        "text": f"{value:.2f}",
        "title": "published rate",
        "rate": value,
        "low": None,
        "high": None,
        "n": None,
    }


def _progression(mean: float, stderr: float) -> str:
    return f"{mean:.1f} ± {stderr:.1f}"


def _departures(card: Card) -> list[str]:
    """What the card's run changed of its protocol, a phrase each."""
    departures = [
        f"{name} = {json.dumps(d['run'])}" for name, d in card.protocol.departures.items()
    ]
    if card.protocol.limit:
        departures.append(f"first {card.protocol.limit} episodes of the schedule")
    return departures


def _card_row(card: Card, slug: str, view: str | None) -> dict[str, Any]:
    figures = card.figures
    tokens = figures.cost.prompt_tokens_per_episode + figures.cost.completion_tokens_per_episode
    departures = _departures(card)
    return {
        "published": False,
        "name": card.run,
        "agent": card.agent,
        "model": card.model.spec or "scripted (no model)",
        "size": card.model.size_billions,
        "has_model": card.model.spec is not None,
        "rates": {c: _interval(r) for c, r in figures.success_by_category.items()},
        "overall": _interval(figures.success),
        "progression": figures.scores.progression,
        "progression_text": _progression(
            figures.scores.progression, figures.scores.progression_stderr
        ),
        "crafter_score": figures.scores.crafter_score,
        "crafter_text": f"{figures.scores.crafter_score:.2f}",
        "episodes": figures.episodes,
        "tokens": tokens,
        "tokens_text": f"{tokens:,.0f}",
        "departures": departures,
        "code": card.code_version,
        "about": f"code {card.code_version}; "
        + (", ".join(f"{k} {v}" for k, v in card.hardware.items()) or "hardware not recorded"),
        "card": f"{CARDS_DIR}/{slug}.json",
        "card_md": f"{CARDS_DIR}/{slug}.md",
        "view": view,
    }


def _published_rows(difficulty: Difficulty) -> list[dict[str, Any]]:
    zero_shot = difficulty == "easy"
    kind = PUBLISHED_KIND[difficulty]
    published = [(result, not zero_shot, kind) for result in PUBLISHED_BY_DIFFICULTY[difficulty]]
    if zero_shot:
        trained_kind = "the paper's trained agent, EASY split"
        published += [(result, True, trained_kind) for result in PUBLISHED_TRAINED_EASY]
    return [
        {
            "published": True,
            "source": f"CrafText paper ({source})",
            "name": result.model,
            "agent": "trained agent (paper)" if trained else "zero-shot LLM (paper)",
            "model": result.model,
            "size": None if trained else model_size_billions(result.model),
            "has_model": not trained,
            "rates": {c: _published_rate(result.rate(c)) for c in result.rates},
            "overall": None,
        }
        for result, trained, source in published
    ]


def _balrog_rows() -> list[dict[str, Any]]:
    return [
        {
            "published": True,
            "source": "BALROG's Crafter leaderboard (LLM track, 10 episodes of up to 2,000 steps)",
            "name": model,
            "agent": "LLM (BALROG)",
            "model": model,
            "size": model_size_billions(model),
            "has_model": True,
            "rates": {},
            "overall": None,
            "progression": progression,
            "progression_text": _progression(progression, stderr),
        }
        for model, progression, stderr in BALROG_PUBLISHED
    ]


def _slugs(cards: Sequence[Card]) -> list[str]:
    slugs: list[str] = []
    for card in cards:
        base = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in card.run) or "card"
        slug, number = base, 2
        while slug in slugs:
            slug, number = f"{base}-{number}", number + 1
        slugs.append(slug)
    return slugs


def leaderboard_data(
    cards: Sequence[Card],
    slugs: Sequence[str],
    views: Sequence[str | None],
    replayed: Sequence[bool] | None = None,
) -> dict[str, Any]:
    """The page's inline data: its sections (difficulty x protocol), each with its goal-set
    columns and rows (the replayed cards, then the published rows that sit beside them), then
    a section of their own for the cards not replayed (`replayed` False; all are by default)."""
    flags = list(replayed) if replayed is not None else [True] * len(cards)
    ranked = [(c, s, v) for c, s, v, r in zip(cards, slugs, views, flags, strict=True) if r]
    sections = _sections(ranked, published=True)
    unranked = [(c, s, v) for c, s, v, r in zip(cards, slugs, views, flags, strict=True) if not r]
    if unranked:
        sections += _sections(unranked, published=False)
    return {"sections": sections}


def _sections(
    rows_of: Sequence[tuple[Card, str, str | None]], *, published: bool
) -> list[dict[str, Any]]:
    cards = [card for card, _, _ in rows_of]
    keys = {(c.protocol.difficulty, c.protocol.name) for c in cards}
    if published:
        keys |= {(d, "paper") for d in _PUBLISHED_DIFFICULTIES}
    order = {name: i for i, name in enumerate(("paper", "default", "balrog"))}
    levels = {name: i for i, name in enumerate(("easy", "medium", "hard"))}
    sections = []
    for difficulty, protocol in sorted(keys, key=lambda k: (levels[k[0]], order[k[1]])):
        rows = [
            _card_row(card, slug, view)
            for card, slug, view in rows_of
            if (card.protocol.difficulty, card.protocol.name) == (difficulty, protocol)
        ]
        if published and protocol == "paper" and difficulty in PUBLISHED_BY_DIFFICULTY:
            rows += _published_rows(difficulty)
        if published and protocol == "balrog":
            rows += _balrog_rows()
        present = {c for row in rows for c in row["rates"]}
        sections.append(
            {
                "id": f"{difficulty}-{protocol}" + ("" if published else "-unverified"),
                "title": f"{difficulty.upper() if difficulty == 'easy' else difficulty.title()}"
                f", protocol {protocol}" + ("" if published else " (NOT replayed)"),
                "unverified": not published,
                "difficulty": difficulty,
                "protocol": protocol,
                # The paper's column order first (Medium: train, paraphrased, new objects).
                "categories": [
                    c
                    for c in dict.fromkeys((*DIFFICULTY_CATEGORIES[difficulty], *ALL_CATEGORIES))
                    if c in present
                ],
                "rows": rows,
            }
        )
    return sections


# ------------------------------------------------------------------------------ Markdown


def _cell(rate: SuccessRate | None) -> str:
    if rate is None:
        return "—"
    return f"{rate.rate:.2f} [{rate.low:.2f}, {rate.high:.2f}]"


def cards_markdown(
    cards: Sequence[Card],
    links: Sequence[str | None] | None = None,
    replayed: Sequence[bool] | None = None,
) -> str:
    """The cards as a Markdown table (a row per card: what ran, under what, on what, and its
    headline figures, its run linked to `links`' card.md where given), for a results page
    generated from them; the cards not replayed (`replayed` False) in a second table of their
    own, under a heading that says so."""
    hrefs = list(links) if links is not None else [None] * len(cards)
    flags = list(replayed) if replayed is not None else [True] * len(cards)
    ranked = [(c, h) for c, h, r in zip(cards, hrefs, flags, strict=True) if r]
    unranked = [(c, h) for c, h, r in zip(cards, hrefs, flags, strict=True) if not r]
    text = _markdown_table(ranked) if ranked else ""
    if unranked:
        text += (
            ("\n" if text else "")
            + "**Not replayed** (these cards record no replay of their runs and were not given "
            "with them: their figures are what the cards say)\n\n" + _markdown_table(unranked)
        )
    return text


def _markdown_table(rows: Sequence[tuple[Card, str | None]]) -> str:
    header = (
        "| Run | Agent | Model | Difficulty | Protocol (departures) | Episodes | Success "
        "[95% CI, clustered] | Progression | Crafter score | Tokens / episode | Wall s / "
        "episode | Hardware | Code | Finished |"
    )
    lines = [header, "|" + "---|" * 14]
    for card, href in sorted(
        rows, key=lambda r: (r[0].protocol.difficulty, r[0].protocol.name, r[0].run)
    ):
        f = card.figures
        departures = "; ".join(_departures(card)) or "none"
        hardware = card.hardware.get("gpus") or card.hardware.get("cpu") or "not recorded"
        if "cpu_cores" in card.hardware and "gpus" not in card.hardware:
            hardware += f" ({card.hardware['cpu_cores']} cores)"
        wall = f.cost.wall_seconds_per_episode
        lines.append(
            "| "
            + " | ".join(
                [
                    f"[{card.run}]({href})" if href else card.run,
                    card.agent,
                    f"`{card.model.spec}`" if card.model.spec else "—",
                    card.protocol.difficulty,
                    f"{card.protocol.name} ({departures})",
                    str(f.episodes),
                    _cell(f.success),
                    f"{f.scores.progression:.1f} ± {f.scores.progression_stderr:.1f}",
                    f"{f.scores.crafter_score:.2f}",
                    f"{f.cost.prompt_tokens_per_episode + f.cost.completion_tokens_per_episode:,.0f}",
                    "—" if wall is None else f"{wall:.1f}",
                    hardware,
                    f"`{card.code_version}`",
                    card.finished_at.strftime("%Y-%m-%d") if card.finished_at else "—",
                ]
            ).replace("\n", " ")
            + " |"
        )
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ the site


def _render(data: dict[str, Any]) -> str:
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("llm_agents.viewer", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
    )
    # Inline JSON inside <script>: "</" would end the element early.
    inline = json.dumps(data, ensure_ascii=False).replace("</", "<\\/")
    return environment.get_template("leaderboard.html.j2").render(data_json=inline)


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER_FILE).is_file():
        raise UserError(
            f"--out {out} holds other files: give an absent or empty folder (an earlier "
            "leaderboard is replaced)"
        )


def _write_site(out: Path, read: Sequence[tuple[Entry, Card]], slugs: Sequence[str]) -> None:
    """Write the whole site into a scratch folder beside `out`, then put it in place: a failure
    leaves `out` as it was."""
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    scratch.chmod(0o755)  # mkdtemp's is private; the site is for reading
    try:
        views = []
        for (entry, card), slug in zip(read, slugs, strict=True):
            (scratch / CARDS_DIR).mkdir(exist_ok=True)
            shutil.copyfile(entry.card, scratch / CARDS_DIR / f"{slug}.json")
            (scratch / CARDS_DIR / f"{slug}.md").write_text(card_markdown(card), encoding="utf-8")
            view = entry.run_dir / VIEW_INDEX if entry.run_dir is not None else None
            views.append(
                Path(os.path.relpath(view.resolve(), out.resolve())).as_posix()
                if view is not None and view.is_file()
                else None
            )
        data = leaderboard_data(
            [card for _, card in read], slugs, views, [entry.replayed(card) for entry, card in read]
        )
        (scratch / INDEX_FILE).write_text(_render(data), encoding="utf-8")
        (scratch / MARKER_FILE).write_text("written by craftext-llm leaderboard\n")
        if out.exists():
            old = parent / f".{out.name}.{os.getpid()}.old"
            os.replace(out, old)
            os.replace(scratch, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(scratch, out)
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise


def _md_links(read: Sequence[tuple[Entry, Card]], markdown: Path) -> list[str | None]:
    """Each card's card.md (beside its card.json), relative to the Markdown file's folder."""
    links: list[str | None] = []
    for entry, _ in read:
        md = entry.card.with_name(CARD_MD_FILE)
        links.append(
            Path(os.path.relpath(md.resolve(), markdown.resolve().parent)).as_posix()
            if md.is_file()
            else None
        )
    return links


def build_leaderboard(
    entries: Sequence[Entry],
    *,
    out: str | Path | None = None,
    markdown: str | Path | None = None,
    unverified: bool = False,
) -> list[str]:
    """Check the cards (each once; against its run where given) and write the site into `out`
    and the Markdown table into `markdown`; returns what was written, a line each. A card
    whose run was not replayed (`Entry.replayed`) is refused unless `unverified`, then shown
    apart."""
    if out is None and markdown is None:
        raise UserError("leaderboard writes --out DIR, --markdown FILE or both: give one")
    if out is not None:
        _check_out(Path(out))
    if markdown is not None and not Path(markdown).resolve().parent.is_dir():
        raise UserError(f"the folder of --markdown {markdown} does not exist")
    read = _read(entries)
    replayed = [entry.replayed(card) for entry, card in read]
    if not unverified:
        for (entry, _), was in zip(read, replayed, strict=True):
            if not was:
                raise UserError(
                    f"card {entry.card} records no replay of its run: give it as "
                    f"{entry.card}=RUN_DIR to replay the run now, or pass --unverified to show "
                    "it apart, not ranked"
                )
    _verify(read)
    cards = [card for _, card in read]
    done = []
    if out is not None:
        _write_site(Path(out), read, _slugs(cards))
        checked = sum(entry.run_dir is not None for entry, _ in read)
        done.append(
            f"wrote {Path(out) / INDEX_FILE}: {len(cards)} cards ({checked} checked against "
            "their runs) beside the published rows"
        )
    if markdown is not None:
        atomic_write_text(
            Path(markdown), cards_markdown(cards, _md_links(read, Path(markdown)), replayed)
        )
        done.append(f"wrote {markdown}: a Markdown table of {len(cards)} cards")
    return done
