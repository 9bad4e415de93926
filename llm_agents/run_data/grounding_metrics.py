"""How well instructions were understood: a model's readings scored against the dataset's goals.

Exact match is counted per instruction text. Precision and recall are counted per field over
atoms (for EASY, the achievement names of `required` and of `forbidden` separately), pooled over
the texts; an invalid answer read nothing, so it lowers recall and leaves precision alone. Every
rate carries a 95% Wilson interval (`SuccessRate`). Confusions name, per achievement, the field
the goal put it in and the field the model put it in ("forbidden read as required").
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from pydantic import BaseModel, Field

from env.goals import CATEGORIES, SPLITS
from llm_agents.run_data.metrics import SuccessRate
from llm_agents.run_data.readings import GoalReading, Grounding

__all__ = [
    "Confusion",
    "FieldScore",
    "GroundingScore",
    "GroundingSummary",
    "Scored",
    "confusions",
    "score",
    "summarize_groundings",
]

#: Confusions kept in a summary, commonest first.
TOP_CONFUSIONS = 15


@dataclass(frozen=True)
class Scored:
    """One instruction text's grounding beside its goal, and where it counts."""

    split: str
    category: str
    truth: GoalReading
    grounding: Grounding


class FieldScore(BaseModel):
    """Precision and recall of one field's atoms; None where nothing was there to count."""

    precision: SuccessRate | None
    """Atoms read into the field that the goal has there, out of all atoms read into it."""
    recall: SuccessRate | None
    """Atoms of the goal's field that were read into it, out of all the goal has there."""


class GroundingScore(BaseModel):
    """Understanding over a set of instruction texts."""

    texts: int = Field(ge=1)
    """Instruction texts scored."""
    exact: SuccessRate
    """Texts read as exactly their goal (an invalid answer is not)."""
    invalid: int = Field(ge=0)
    """Texts whose answer was not a well-formed goal."""
    fields: dict[str, FieldScore]
    """Per field of the goal (`required`, `forbidden`)."""


class Confusion(BaseModel):
    """One kind of misreading of one achievement, and how often it happened."""

    kind: str
    """E.g. `forbidden read as required`, `required missed`, `forbidden added`."""
    achievement: str
    """The achievement misread."""
    count: int = Field(ge=1)
    """Texts where it happened."""


class GroundingSummary(BaseModel):
    """Understanding overall, by split and by category, with the commonest confusions."""

    overall: GroundingScore
    """Every text."""
    by_split: dict[str, GroundingScore]
    """Per dataset split present."""
    by_category: dict[str, GroundingScore]
    """Per goal category present."""
    confusions: list[Confusion]
    """The commonest misreadings, most frequent first (at most `TOP_CONFUSIONS`)."""
    invalid_reasons: dict[str, int]
    """Invalid answers per reason, most frequent first."""


def _rate(hits: int, total: int) -> SuccessRate | None:
    return SuccessRate.of(hits, total) if total else None


def score(items: Sequence[Scored]) -> GroundingScore:
    """Exact match, invalid answers and per-field precision / recall over `items` (not empty)."""
    hits: Counter[str] = Counter()
    read: Counter[str] = Counter()
    true: Counter[str] = Counter()
    for item in items:
        truth = item.truth.atoms()
        reading = item.grounding.reading.atoms() if item.grounding.reading else {}
        for field, atoms in truth.items():
            got = reading.get(field, frozenset())
            hits[field] += len(atoms & got)
            read[field] += len(got)
            true[field] += len(atoms)
    names = list(items[0].truth.atoms()) if items else []
    return GroundingScore(
        texts=len(items),
        exact=SuccessRate.of(sum(i.grounding.matches(i.truth) for i in items), len(items)),
        invalid=sum(i.grounding.outcome == "invalid" for i in items),
        fields={
            name: FieldScore(
                precision=_rate(hits[name], read[name]), recall=_rate(hits[name], true[name])
            )
            for name in names
        },
    )


def confusions(items: Iterable[Scored]) -> Counter[tuple[str, str]]:
    """(kind, achievement) -> texts, over the valid readings that differ from their goal."""
    found: Counter[tuple[str, str]] = Counter()
    for item in items:
        if item.grounding.reading is None:
            continue
        truth, reading = item.truth.atoms(), item.grounding.reading.atoms()
        where_true = {atom: field for field, atoms in truth.items() for atom in atoms}
        where_read = {atom: field for field, atoms in reading.items() for atom in atoms}
        for atom in where_true.keys() | where_read.keys():
            was, got = where_true.get(atom), where_read.get(atom)
            if was == got:
                continue
            if was is None:
                kind = f"{got} added"
            elif got is None:
                kind = f"{was} missed"
            else:
                kind = f"{was} read as {got}"
            found[(kind, atom)] += 1
    return found


def summarize_groundings(items: Sequence[Scored]) -> GroundingSummary | None:
    """The summary of `items`; None when there are none."""
    if not items:
        return None
    by_split: dict[str, list[Scored]] = defaultdict(list)
    by_category: dict[str, list[Scored]] = defaultdict(list)
    for item in items:
        by_split[item.split].append(item)
        by_category[item.category].append(item)
    reasons = Counter(
        (item.grounding.reason or "").split(":")[0]
        for item in items
        if item.grounding.outcome == "invalid"
    )
    return GroundingSummary(
        overall=score(items),
        by_split={split: score(by_split[split]) for split in SPLITS if split in by_split},
        by_category={c: score(by_category[c]) for c in CATEGORIES if c in by_category},
        confusions=[
            Confusion(kind=kind, achievement=atom, count=count)
            for (kind, atom), count in sorted(
                confusions(items).items(), key=lambda entry: (-entry[1], entry[0])
            )[:TOP_CONFUSIONS]
        ],
        invalid_reasons=dict(reasons.most_common()),
    )
