"""How well instructions were understood: a model's readings scored against the dataset's goals.

Exact match (the whole typed goal) is counted per instruction text. Kind accuracy counts texts
read as a goal of their goal's kind (an invalid answer is not). An achievements goal's fields are
sets: precision and recall are counted per field over atoms (the achievement names of `required`
and of `forbidden` separately), pooled over the texts whose goal is an achievements goal; an
invalid answer, or one of another kind, read nothing, so it lowers recall and leaves precision
alone. A placing goal's typed parameters (block, side, distance, size, ...) are each scored as
right or wrong over the texts read with the right kind, so they measure the parameters apart
from the kind (`parameters`, keyed `kind.field`). Every rate carries a 95% Wilson interval
clustered by goal (`metrics.clustered_rate`): the ~6 phrasings of one goal, and the atoms of
one text, are not independent trials. Confusions name the goal kind read as another, per achievement the field the
goal put it in and the field the model put it in ("forbidden read as required"), and per
parameter the value read for the goal's.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from pydantic import AliasChoices, BaseModel, Field

from env.goals import ALL_CATEGORIES, SCENARIO_CLASSES, SPLITS
from llm_agents.run_data.metrics import SuccessRate, clustered_rate
from llm_agents.run_data.readings import (
    READING_CLASSES,
    AchievementsReading,
    GoalReading,
    Grounding,
)

__all__ = [
    "KIND_CONFUSION",
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
#: The confusion kind of a goal read as a goal of another kind.
KIND_CONFUSION = "goal kind misread"
#: Every placing-goal parameter, as `kind.field`, in goal-kind then field order.
_PARAMETER_ORDER = tuple(
    f"{kind}.{field}"
    for kind, reading in READING_CLASSES.items()
    if reading is not AchievementsReading
    for field in reading.model_fields
    if field != "kind"
)


@dataclass(frozen=True)
class Scored:
    """One instruction text's grounding beside its goal, and where it counts."""

    split: str
    category: str
    truth: GoalReading
    grounding: Grounding
    scenario_class: str = "Achievements"
    goal_id: str | None = None
    """The goal's id, which the rates are clustered by (with the split); None: the goal as
    read right (`truth`) stands for it."""

    @property
    def cluster(self) -> tuple[str, str]:
        """The goal this text's outcomes are clustered by."""
        return (self.split, self.goal_id or self.truth.model_dump_json())


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
    """Per field of the achievements goals among them (`required`, `forbidden`)."""
    kind: SuccessRate | None = None
    """Texts read as a goal of their goal's kind (None in runs scored before goals had kinds)."""
    parameters: dict[str, SuccessRate] = Field(default_factory=dict)
    """Per placing-goal parameter (`kind.field`, e.g. `localization_placing.side`): texts whose
    goal has it and that were read with the right kind, of which the parameter was read right."""


class Confusion(BaseModel):
    """One kind of misreading of one thing, and how often it happened."""

    kind: str
    """E.g. `forbidden read as required`, `required missed`, `forbidden added`, `goal kind
    misread`, `localization_placing side misread`."""
    subject: str = Field(validation_alias=AliasChoices("subject", "achievement"))
    """What was misread: the achievement; for a kind or a parameter, `TRUE as READ`."""
    count: int = Field(ge=1)
    """Texts where it happened."""


class GroundingSummary(BaseModel):
    """Understanding overall, by split, category and scenario class, with the commonest
    confusions."""

    overall: GroundingScore
    """Every text."""
    by_split: dict[str, GroundingScore]
    """Per dataset split present."""
    by_category: dict[str, GroundingScore]
    """Per goal category present."""
    by_scenario_class: dict[str, GroundingScore] = Field(default_factory=dict)
    """Per scenario class present (the paper's Table 2 rows: Achievements, Conditional,
    Localization, Build)."""
    confusions: list[Confusion]
    """The commonest misreadings, most frequent first (at most `TOP_CONFUSIONS`)."""
    invalid_reasons: dict[str, int]
    """Invalid answers per reason, most frequent first."""


Tally = Counter[tuple[str, tuple[str, str]]]
"""(what, goal) -> count."""


def _rate(hits: Tally, total: Tally, what: str) -> SuccessRate | None:
    clusters = {goal: (hits[(w, goal)], n) for (w, goal), n in total.items() if w == what and n}
    return clustered_rate(clusters) if clusters else None


def _texts(items: Sequence[Scored], hit: Callable[[Scored], bool]) -> SuccessRate:
    return clustered_rate((item.cluster, int(hit(item)), 1) for item in items)


def _atoms(reading: GoalReading | None) -> dict[str, frozenset[str]]:
    return reading.atoms() if isinstance(reading, AchievementsReading) else {}


def score(items: Sequence[Scored]) -> GroundingScore:
    """Exact match, kind accuracy, invalid answers, per-field precision / recall and
    per-parameter accuracy over `items` (not empty)."""
    hits: Tally = Counter()
    read: Tally = Counter()
    true: Tally = Counter()
    right: Tally = Counter()
    asked: Tally = Counter()
    for item in items:
        reading, goal = item.grounding.reading, item.cluster
        for field, atoms in _atoms(item.truth).items():
            got = _atoms(reading).get(field, frozenset())
            hits[(field, goal)] += len(atoms & got)
            read[(field, goal)] += len(got)
            true[(field, goal)] += len(atoms)
        if reading is not None and reading.kind == item.truth.kind:
            got_values = reading.parameters()
            for field, value in item.truth.parameters().items():
                key = f"{item.truth.kind}.{field}"
                asked[(key, goal)] += 1
                right[(key, goal)] += got_values[field] == value
    achievements = any(isinstance(i.truth, AchievementsReading) for i in items)
    names = ["required", "forbidden"] if achievements else []
    parameters = {key: _rate(right, asked, key) for key in _PARAMETER_ORDER}
    return GroundingScore(
        texts=len(items),
        exact=_texts(items, lambda i: i.grounding.matches(i.truth)),
        invalid=sum(i.grounding.outcome == "invalid" for i in items),
        fields={
            name: FieldScore(precision=_rate(hits, read, name), recall=_rate(hits, true, name))
            for name in names
        },
        kind=_texts(
            items,
            lambda i: i.grounding.reading is not None and i.grounding.reading.kind == i.truth.kind,
        ),
        parameters={key: rate for key, rate in parameters.items() if rate is not None},
    )


def confusions(items: Iterable[Scored]) -> Counter[tuple[str, str]]:
    """(kind, subject) -> texts, over the valid readings that differ from their goal."""
    found: Counter[tuple[str, str]] = Counter()
    for item in items:
        reading = item.grounding.reading
        if reading is None:
            continue
        if reading.kind != item.truth.kind:
            found[(KIND_CONFUSION, f"{item.truth.kind} as {reading.kind}")] += 1
            continue
        got_values = reading.parameters()
        for field, value in item.truth.parameters().items():
            if got_values[field] != value:
                found[
                    (f"{item.truth.kind} {field} misread", f"{value} as {got_values[field]}")
                ] += 1
        truth, atoms = _atoms(item.truth), _atoms(reading)
        where_true = {atom: field for field, names in truth.items() for atom in names}
        where_read = {atom: field for field, names in atoms.items() for atom in names}
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
    by_class: dict[str, list[Scored]] = defaultdict(list)
    for item in items:
        by_split[item.split].append(item)
        by_category[item.category].append(item)
        by_class[item.scenario_class].append(item)
    reasons = Counter(
        (item.grounding.reason or "").split(":")[0]
        for item in items
        if item.grounding.outcome == "invalid"
    )
    return GroundingSummary(
        overall=score(items),
        by_split={split: score(by_split[split]) for split in SPLITS if split in by_split},
        by_category={c: score(by_category[c]) for c in ALL_CATEGORIES if c in by_category},
        by_scenario_class={c: score(by_class[c]) for c in SCENARIO_CLASSES if c in by_class},
        confusions=[
            Confusion(kind=kind, subject=subject, count=count)
            for (kind, subject), count in sorted(
                confusions(items).items(), key=lambda entry: (-entry[1], entry[0])
            )[:TOP_CONFUSIONS]
        ],
        invalid_reasons=dict(reasons.most_common()),
    )
