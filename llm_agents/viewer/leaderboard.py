"""`craftext-llm leaderboard`: results cards set beside each other and beside the published
numbers, as one static page (no server: its data inline, a small script, works from file://)
and as Markdown tables.

Only what this command checked is ranked: a card given with its run (`CARD=RUN_DIR`) whose
records replay and give every figure of the card (one they do not give is refused, naming what
differs). A card given alone proves nothing of itself (anyone can write one, digest included),
whatever replay it says it passed: it is shown only with `--unverified`, in tables of their own
headed as not replayed here, never ranked.

The page has a sortable table per difficulty and protocol, the success rates drawn with their
intervals; each row states its success rule, its departures from the protocol and its data
source. The CrafText paper's rows (its zero-shot LLMs on EASY, its trained agents' Medium
totals) sit in the `paper` tables of their difficulty, BALROG's Crafter rows beside the cards
played under `--protocol balrog`; both marked as published. A `paper` run whose data, variant,
step cap, way of reading answers (held to a schema) or success rule differ from the paper's is
never set beside them: it has a table of its own. The site is self-contained: each row links a copy of its card and card.md and, where its
run has a `view` report, a copy of that report.
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
from llm_agents.evaluation.protocol import protocol_for
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
    OFFICIAL_COMMIT,
    PUBLISHED_BY_DIFFICULTY,
    PUBLISHED_KIND,
    PUBLISHED_TRAINED_EASY,
)
from llm_agents.judging.replay_check import RunDoesNotReplay
from llm_agents.run_data.markup import inline_json, markdown_code, markdown_text
from llm_agents.run_data.metrics import SuccessRate
from llm_agents.run_data.store import RESULTS_FILE, STEPS_FILE, atomic_write_text, read_results

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
#: Where the site keeps its copies of the runs' `view` reports, one folder per card.
REPORTS_DIR = "reports"
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

    @property
    def replayed_here(self) -> bool:
        """Whether this command replays the card's run: given with it, a run that kept its
        step log. What the card itself says of a replay is never taken for one."""
        return self.run_dir is not None and (self.run_dir / STEPS_FILE).is_file()


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
        if entry.run_dir is not None:
            _check_own_run(entry.card, card, entry.run_dir)
        read.append((entry, card))
    return read


def _check_own_run(path: Path, card: Card, run_dir: Path) -> None:
    """A `UserError` unless `run_dir` is a run directory, and the one `card` was written from
    (the run's start time, which the card records, is the run's own)."""
    if not run_dir.is_dir():
        raise UserError(f"run folder {run_dir} of card {path} does not exist")
    results = run_dir / RESULTS_FILE
    if not results.is_file():
        raise UserError(f"{run_dir} (given with card {path}) is not a run directory")
    started = read_results(results).started_at
    if started != card.started_at:
        raise UserError(
            f"card {path} is not the card of the run in {run_dir}: the card's run started "
            f"{card.started_at.isoformat()}, this one {started.isoformat()}"
        )


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


def _data_source(card: Card) -> str:
    """Where the run's instructions came from, as the card records it."""
    if not card.split_digests:
        return "no instruction data (open-ended task)"
    for difference in card.protocol.paper_differences:
        if difference.startswith("dataset: "):
            return difference.removeprefix("dataset: ")
    return f"the official CrafText data at {OFFICIAL_COMMIT[:7]}"


def _comparable(card: Card) -> bool:
    """Whether a `paper` card may sit beside the paper's rows: nothing in it departs from the
    paper's protocol where that changes the numbers (data, variant, step cap, answers held to a
    schema, success rule)."""
    return card.protocol.name != "paper" or not card.protocol.paper_differences


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
        "rule": card.success_rule,
        "data": _data_source(card),
        "differences": card.protocol.paper_differences,
        "code": card.code_version,
        "about": f"code {card.code_version}; "
        + (", ".join(f"{k} {v}" for k, v in card.hardware.items()) or "hardware not recorded"),
        "card": f"{CARDS_DIR}/{slug}.json",
        "card_md": f"{CARDS_DIR}/{slug}.md",
        "view": view,
    }


def _published_rows(difficulty: Difficulty) -> list[dict[str, Any]]:
    zero_shot = difficulty == "easy"
    rule = protocol_for("paper", difficulty).value("success_rule")
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
            "rule": rule,
            "data": "the paper's",
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
            "rule": None,
            "data": "no instruction data (open-ended task)",
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
    """The page's inline data: its sections (`_Table`s), each with its goal-set columns and rows
    (the cards replayed here, then the published rows that sit beside them), then the sections
    of the cards not replayed here (`replayed` False; all are replayed by default)."""
    flags = list(replayed) if replayed is not None else [True] * len(cards)
    rows_of = list(zip(cards, slugs, views, flags, strict=True))
    sections = []
    for table in _tables([card for card, *_ in rows_of], flags):
        rows = [
            _card_row(card, slug, view)
            for card, slug, view, was in rows_of
            if table.holds(card, was)
        ]
        if (
            table.beside_published
            and table.protocol == "paper"
            and table.difficulty in PUBLISHED_BY_DIFFICULTY
        ):
            rows += _published_rows(table.difficulty)
        if table.beside_published and table.protocol == "balrog":
            rows += _balrog_rows()
        present = {c for row in rows for c in row["rates"]}
        sections.append(
            {
                "id": table.id,
                "title": table.title,
                "note": table.note,
                "unverified": not table.replayed,
                "difficulty": table.difficulty,
                "protocol": table.protocol,
                # The paper's column order first (Medium: train, paraphrased, new objects).
                "categories": [
                    c
                    for c in dict.fromkeys(
                        (*DIFFICULTY_CATEGORIES[table.difficulty], *ALL_CATEGORIES)
                    )
                    if c in present
                ],
                "rows": rows,
            }
        )
    return {"sections": sections}


class _Table(BaseModel):
    """One table of the leaderboard: the cards of a difficulty and protocol, replayed here or
    not, and (under `paper`) comparable with the paper's protocol or not."""

    difficulty: Difficulty
    protocol: str
    replayed: bool
    comparable: bool = True

    def holds(self, card: Card, replayed: bool) -> bool:
        return (
            (card.protocol.difficulty, card.protocol.name) == (self.difficulty, self.protocol)
            and replayed == self.replayed
            # Cards not replayed here are one table whatever they say: no table of them is
            # set beside the published rows.
            and (not self.replayed or _comparable(card) == self.comparable)
        )

    @property
    def beside_published(self) -> bool:
        return self.replayed and self.comparable

    @property
    def id(self) -> str:
        return f"{self.difficulty}-{self.protocol}" + (
            "-unverified" if not self.replayed else "" if self.comparable else "-differs"
        )

    @property
    def title(self) -> str:
        name = self.difficulty.upper() if self.difficulty == "easy" else self.difficulty.title()
        title = f"{name}, protocol {self.protocol}"
        if not self.replayed:
            return title + ": NOT replayed here"
        if not self.comparable:
            return title + ": not comparable with the paper's numbers"
        return title

    @property
    def note(self) -> str | None:
        if not self.replayed:
            return (
                "These cards were given without their runs, so nothing here checked them. A "
                "card alone proves nothing (anyone can write one, digest included), whatever "
                "replay it says it passed: its figures are only what it says. Not ranked."
            )
        if not self.comparable:
            return (
                "Replayed here, under the paper protocol's name, but their data, variant, step "
                "cap, answers held to a schema or success rule differ from the paper's (each "
                "row says how): not set beside the published rows."
            )
        return None


def _tables(cards: Sequence[Card], replayed: Sequence[bool]) -> list[_Table]:
    """The tables the cards fill, in the page's order (difficulty, then protocol; replayed
    ones first), with the published difficulties' `paper` tables always among them."""
    found = [
        _Table(
            difficulty=card.protocol.difficulty,
            protocol=card.protocol.name,
            replayed=was,
            comparable=_comparable(card) or not was,
        )
        for card, was in zip(cards, replayed, strict=True)
    ]
    found += [
        _Table(difficulty=d, protocol="paper", replayed=True) for d in _PUBLISHED_DIFFICULTIES
    ]
    unique = {table.id: table for table in found}
    order = {name: i for i, name in enumerate(("paper", "default", "balrog"))}
    levels = {name: i for i, name in enumerate(("easy", "medium", "hard"))}
    return sorted(
        unique.values(),
        key=lambda t: (not t.replayed, levels[t.difficulty], order[t.protocol], not t.comparable),
    )


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
    """The cards as Markdown tables, one per table of the page (`_Table`) that holds a card,
    each under a bold line naming it and what its rows were checked against: a row per card
    (what ran, under what rule, on what data, with what departures, and its headline figures,
    its run linked to `links`' card.md where given). Every recorded text is escaped
    (`markup`)."""
    hrefs = list(links) if links is not None else [None] * len(cards)
    flags = list(replayed) if replayed is not None else [True] * len(cards)
    rows_of = list(zip(cards, hrefs, flags, strict=True))
    parts = []
    for table in _tables(cards, flags):
        rows = [(card, href) for card, href, was in rows_of if table.holds(card, was)]
        if not rows:
            continue
        heading = f"**{table.title}**" + (f". {table.note}" if table.note else "")
        parts.append(heading + "\n\n" + _markdown_table(rows, replayed=table.replayed))
    return "\n".join(parts)


def _replay_cell(card: Card, replayed: bool) -> str:
    if replayed:
        return "replayed here"
    if card.replay is None:
        return "none recorded"
    # What the card says, quoted as such: a card alone cannot show it happened.
    return (
        f"the card says: {card.replay.episodes} episodes by "
        f"{markdown_code(card.replay.code_version)} on {card.replay.replayed_at:%Y-%m-%d} "
        "(not checked here)"
    )


def _markdown_table(rows: Sequence[tuple[Card, str | None]], *, replayed: bool) -> str:
    header = (
        "| Run | Agent | Model | Departures | Success rule | Data | Episodes | Success "
        "[95% CI, clustered] | Progression | Crafter score | Tokens / episode | Wall s / "
        "episode | Hardware | Code | Finished | Replay |"
    )
    lines = [header, "|" + "---|" * 16]
    text = markdown_text
    for card, href in sorted(rows, key=lambda r: r[0].run):
        f = card.figures
        departures = "; ".join(_departures(card) + card.protocol.paper_differences) or "none"
        hardware = card.hardware.get("gpus") or card.hardware.get("cpu") or "not recorded"
        if "cpu_cores" in card.hardware and "gpus" not in card.hardware:
            hardware += f" ({card.hardware['cpu_cores']} cores)"
        wall = f.cost.wall_seconds_per_episode
        cells = [
            f"[{text(card.run)}]({href})" if href else text(card.run),
            text(card.agent),
            markdown_code(card.model.spec) if card.model.spec else "—",
            text(departures),
            markdown_code(card.success_rule),
            text(_data_source(card)),
            str(f.episodes),
            _cell(f.success),
            f"{f.scores.progression:.1f} ± {f.scores.progression_stderr:.1f}",
            f"{f.scores.crafter_score:.2f}",
            f"{f.cost.prompt_tokens_per_episode + f.cost.completion_tokens_per_episode:,.0f}",
            "—" if wall is None else f"{wall:.1f}",
            text(hardware),
            markdown_code(card.code_version) if card.code_version else "—",
            card.finished_at.strftime("%Y-%m-%d") if card.finished_at else "—",
            _replay_cell(card, replayed),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ the site


def _render(data: dict[str, Any]) -> str:
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("llm_agents.viewer", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
    )
    return environment.get_template("leaderboard.html.j2").render(data_json=inline_json(data))


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
    leaves `out` as it was. Everything a page links is copied in (each card, its card.md written
    from it, its run's `view` report), so the folder can be published as it is."""
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    scratch.chmod(0o755)  # mkdtemp's is private; the site is for reading
    try:
        views: list[str | None] = []
        (scratch / CARDS_DIR).mkdir()
        for (entry, card), slug in zip(read, slugs, strict=True):
            shutil.copyfile(entry.card, scratch / CARDS_DIR / f"{slug}.json")
            (scratch / CARDS_DIR / f"{slug}.md").write_text(card_markdown(card), encoding="utf-8")
            report = entry.run_dir / VIEW_INDEX if entry.run_dir is not None else None
            if report is not None and report.is_file():
                shutil.copytree(report.parent, scratch / REPORTS_DIR / slug, symlinks=False)
                views.append(f"{REPORTS_DIR}/{slug}/{VIEW_INDEX.name}")
            else:
                views.append(None)
        data = leaderboard_data(
            [card for _, card in read], slugs, views, [entry.replayed_here for entry, _ in read]
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
    """Each card's card.md (beside its card.json), relative to the Markdown file's folder: only
    where it is the card's own rendering, since nothing seals a card.md (one edited by hand
    could say anything, markup included); the link is left out otherwise."""
    links: list[str | None] = []
    for entry, card in read:
        md = entry.card.with_name(CARD_MD_FILE)
        own = md.is_file() and md.read_text(encoding="utf-8") == card_markdown(card)
        links.append(
            Path(os.path.relpath(md.resolve(), markdown.resolve().parent)).as_posix()
            if own
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
    """Check the cards (each once; against its run where given: replayed, every figure
    recomputed) and write the site into `out` and the Markdown tables into `markdown`; returns
    what was written, a line each. A card not replayed here (`Entry.replayed_here`) is refused
    unless `unverified`, then shown apart, never ranked."""
    if out is None and markdown is None:
        raise UserError("leaderboard writes --out DIR, --markdown FILE or both: give one")
    if out is not None:
        _check_out(Path(out))
    if markdown is not None and not Path(markdown).resolve().parent.is_dir():
        raise UserError(f"the folder of --markdown {markdown} does not exist")
    read = _read(entries)
    replayed = [entry.replayed_here for entry, _ in read]
    if not unverified:
        for entry, was in zip((entry for entry, _ in read), replayed, strict=True):
            if not was:
                why = (
                    "it is given without its run"
                    if entry.run_dir is None
                    else f"its run in {entry.run_dir} kept no step log to replay"
                )
                raise UserError(
                    f"card {entry.card} cannot be replayed here ({why}): give it as "
                    f"{entry.card}=RUN_DIR, or pass --unverified to show it apart, not ranked"
                )
    _verify(read)
    cards = [card for _, card in read]
    ranked = sum(replayed)
    counted = (
        f"{len(cards)} cards ({ranked} replayed here and ranked, "
        f"{len(cards) - ranked} not replayed here, shown apart)"
    )
    done = []
    if out is not None:
        _write_site(Path(out), read, _slugs(cards))
        done.append(f"wrote {Path(out) / INDEX_FILE}: {counted} beside the published rows")
    if markdown is not None:
        links = _md_links(read, Path(markdown))
        atomic_write_text(Path(markdown), cards_markdown(cards, links, replayed))
        unlinked = [
            str(entry.card) for (entry, _), link in zip(read, links, strict=True) if not link
        ]
        done.append(
            f"wrote {markdown}: Markdown tables of {counted}"
            + (
                f"; not linked, having no card.md of their own beside them: {', '.join(unlinked)}"
                if unlinked
                else ""
            )
        )
    return done
