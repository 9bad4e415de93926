"""The skills agent's catalogue: typed skills, what a variant and difficulty offer, and the
layered parser from a model's free text to one skill (or `invalid`, with the reason).

A skill is one subgoal the expert's controllers can carry out (`skill_runner`): `collect wood
3`, `place stone right 2 of tree`, `build line stone 3 diagonal`, `craft wood_pickaxe`, `go to
water`, `eat`, `drink`, `sleep`, `attack zombie`, `explore`, `noop`. The names a skill may take
come from the variant's tables (a block, creature or item the variant lacks is not offered) and
the placing skills from the difficulty's goal kinds (EASY offers no `build` and no `place ... of
...`), with the parameters of the typed placing goals (`env.goals`).

Parser stages, first match wins (reasoning blocks dropped first, as for actions):
1. `field`: the last `SKILL: <skill>` line decides;
2. `exact`: the whole answer, else its last line that is a skill (lines copied from the prompt
   skipped), reads as a skill;
in both, a value that is no skill as a whole is read up to its first `:`, `(`, `,` or `;` (a
skill followed by a comment, such as a copied history line);
otherwise `invalid`, with the reason of the line that came closest (an unknown skill word, or the
parameter that is not in the catalogue). The parser never raises on any text.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag

from env import craftax_names
from env.goals import CROSS_TYPES, DIFFICULTY_KINDS, SIDES, CrossType, Difficulty, Side
from env.variant import Variant
from llm_agents.agents.expert.plan import RECIPES
from llm_agents.backends.reasoning import split_reasoning

SkillName = Literal[
    "collect", "place", "build", "craft", "go_to", "eat", "drink", "sleep", "attack", "explore",
    "noop",
]  # fmt: skip
SkillStage = Literal["field", "exact", "choice", "invalid"]

#: Materials `collect` gathers, and the block each comes from (saplings: grass).
MATERIAL_SOURCE: dict[str, str] = {
    "wood": "tree",
    "stone": "stone",
    "coal": "coal",
    "iron": "iron",
    "diamond": "diamond",
    "sapling": "grass",
}
#: Blocks `place` puts down (the variant's block names, lower case).
PLACEABLE = ("stone", "crafting_table", "furnace", "plant")
_BLOCK_ALIASES = {"table": "crafting_table", "sapling": "plant"}
_MAX_COUNT = 9
_MAX_SIZE = 9
_MAX_DISTANCE = 9


class _Skill(BaseModel):
    model_config = ConfigDict(frozen=True)

    @property
    def text(self) -> str:
        """The skill as the model writes it (the catalogue's form)."""
        raise NotImplementedError

    @property
    def label(self) -> str:
        """The skill without its counts and places (the histogram's key)."""
        return self.text


class Collect(_Skill):
    """Gather `count` more of a material (DO on its block; a pickaxe of the right tier first)."""

    name: Literal["collect"] = "collect"
    material: str
    count: int = Field(1, ge=1, le=_MAX_COUNT)

    @property
    def text(self) -> str:
        return f"collect {self.material}" + (f" {self.count}" if self.count > 1 else "")

    @property
    def label(self) -> str:
        return f"collect {self.material}"


class Place(_Skill):
    """Put a block down in front of the player; with `side`, `distance` and `reference`, at
    that side and distance of a block of that kind (as localization goals name it)."""

    name: Literal["place"] = "place"
    block: str
    side: Side | None = None
    distance: int | None = Field(None, ge=0, le=_MAX_DISTANCE)
    reference: str | None = None

    @property
    def text(self) -> str:
        where = f" {self.side} {self.distance} of {self.reference}" if self.reference else ""
        return f"place {self.block}{where}"

    @property
    def label(self) -> str:
        return f"place {self.block}" + (" at" if self.reference else "")


class Build(_Skill):
    """Build a line (straight or diagonal), a filled square or a star of one block kind, with
    the parameters of the build goals."""

    name: Literal["build"] = "build"
    shape: Literal["line", "square", "star"]
    block: str
    size: int = Field(ge=1, le=_MAX_SIZE)
    diagonal: bool = False
    cross: CrossType = "straight"

    @property
    def text(self) -> str:
        extra = " diagonal" if self.shape == "line" and self.diagonal else ""
        if self.shape == "star":
            extra = f" {self.cross}"
        return f"build {self.shape} {self.block} {self.size}{extra}"

    @property
    def label(self) -> str:
        return f"build {self.shape}"


class Craft(_Skill):
    """Make a tool at a crafting table (and a furnace for iron ones) that is already nearby."""

    name: Literal["craft"] = "craft"
    item: str

    @property
    def text(self) -> str:
        return f"craft {self.item}"


class GoTo(_Skill):
    """Walk next to the nearest known block of a kind (exploring until one is seen)."""

    name: Literal["go_to"] = "go_to"
    block: str

    @property
    def text(self) -> str:
        return f"go to {self.block}"


class Attack(_Skill):
    """Hunt a creature down and hit it until it dies."""

    name: Literal["attack"] = "attack"
    creature: str

    @property
    def text(self) -> str:
        return f"attack {self.creature}"


class Simple(_Skill):
    """A skill without parameters: eat (a cow), drink (water), sleep (until awake), explore
    (walk towards unseen ground for a while), noop (one step of nothing)."""

    name: Literal["eat", "drink", "sleep", "explore", "noop"]

    @property
    def text(self) -> str:
        return self.name


def _skill_kind(value: object) -> str:
    name = value.get("name") if isinstance(value, dict) else getattr(value, "name", None)
    return "simple" if name in ("eat", "drink", "sleep", "explore", "noop") else str(name)


AnySkill = Annotated[
    Annotated[Collect, Tag("collect")]
    | Annotated[Place, Tag("place")]
    | Annotated[Build, Tag("build")]
    | Annotated[Craft, Tag("craft")]
    | Annotated[GoTo, Tag("go_to")]
    | Annotated[Attack, Tag("attack")]
    | Annotated[Simple, Tag("simple")],
    Discriminator(_skill_kind),
]
"""Any skill, told apart by its `name`."""


@dataclass(frozen=True)
class SkillOffer:
    """The names each skill may take in a run: its variant's and its difficulty's."""

    variant: Variant
    difficulty: Difficulty
    materials: tuple[str, ...]
    blocks: tuple[str, ...]
    """Every block of the variant (`go to`, and the reference of `place ... of ...`)."""
    placeable: tuple[str, ...]
    items: tuple[str, ...]
    creatures: tuple[str, ...]
    place_at: bool
    """Whether `place` takes a side, distance and reference block (Medium, Hard)."""
    shapes: tuple[str, ...]
    """The `build` shapes the difficulty's goals use (none on EASY)."""

    def forms(self) -> list[str]:
        """The catalogue as the prompt lists it: one line per skill form."""
        forms = [
            f"collect <material> [n]: gather n more (default 1); material: "
            f"{', '.join(self.materials)}",
            f"place <block>: put a block in front of you; block: {', '.join(self.placeable)}",
        ]
        if self.place_at:
            forms.append(
                "place <block> <side> <distance> of <reference>: a block at that side "
                f"({', '.join(SIDES)}) and distance of a <reference> block"
            )
        for shape in self.shapes:
            extra = {
                "line": " [diagonal]",
                "square": "",
                "star": f" <{'|'.join(CROSS_TYPES)}>",
            }[shape]
            forms.append(f"build {shape} <block> <size>{extra}")
        forms += [
            f"craft <item>: at a nearby crafting table; item: {', '.join(self.items)}",
            "go to <block>: walk next to the nearest such block",
            f"attack <creature>: creature: {', '.join(self.creatures)}",
            "eat: hunt a cow and eat it",
            "drink: drink water",
            "sleep: sleep until rested",
            "explore: walk towards unexplored ground for a while",
            "noop: do nothing for one step",
        ]
        return forms

    def grammar(self) -> tuple[str, ...]:
        """Every skill the catalogue offers, written in its form (each reads back as itself):
        the answers `--choice guided` holds the model to."""
        return _grammar(self)


@cache
def _grammar(offer: SkillOffer) -> tuple[str, ...]:
    skills: list[_Skill] = [
        Collect(material=material, count=count)
        for material in offer.materials
        for count in range(1, _MAX_COUNT + 1)
    ]
    skills += [Place(block=block) for block in offer.placeable]
    if offer.place_at:
        skills += [
            Place(block=block, side=side, distance=distance, reference=reference)
            for block in offer.placeable
            for side in SIDES
            for distance in range(_MAX_DISTANCE + 1)
            for reference in offer.blocks
        ]
    for shape in offer.shapes:
        for block in offer.placeable:
            for size in range(1, _MAX_SIZE + 1):
                if shape == "line":
                    skills += [
                        Build(shape="line", block=block, size=size, diagonal=diagonal)
                        for diagonal in (False, True)
                    ]
                elif shape == "star":
                    skills += [
                        Build(shape="star", block=block, size=size, cross=cross)
                        for cross in CROSS_TYPES
                    ]
                else:
                    skills.append(Build(shape="square", block=block, size=size))
    skills += [Craft(item=item) for item in offer.items]
    skills += [GoTo(block=block) for block in offer.blocks]
    skills += [Attack(creature=creature) for creature in offer.creatures]
    skills += [Simple(name=name) for name in ("eat", "drink", "sleep", "explore", "noop")]
    return tuple(skill.text for skill in skills)


def grammar_digest(offer: SkillOffer) -> str:
    """SHA-256 of the catalogue's grammar (`SkillOffer.grammar`): part of the identity of a
    run whose answers it holds."""
    return hashlib.sha256("\n".join(offer.grammar()).encode()).hexdigest()


@cache
def skill_offer(variant: Variant, difficulty: Difficulty) -> SkillOffer:
    """What `variant` and `difficulty` offer (what the variant lacks is not offered)."""
    blocks = tuple(
        name.lower()
        for name in variant.block_names
        if name not in ("INVALID", "OUT_OF_BOUNDS", "DARKNESS")
    )
    actions = set(variant.action_names)
    items = tuple(action.removeprefix("MAKE_").lower() for action in RECIPES if action in actions)
    if variant is Variant.CLASSIC:
        mobs = craftax_names.CLASSIC_MOBS
    else:
        mobs = (
            *craftax_names.PASSIVE_MOBS,
            *craftax_names.MELEE_MOBS,
            *craftax_names.RANGED_MOBS,
        )
    kinds = DIFFICULTY_KINDS[difficulty]
    return SkillOffer(
        variant=variant,
        difficulty=difficulty,
        materials=tuple(MATERIAL_SOURCE),
        blocks=blocks,
        placeable=tuple(b for b in PLACEABLE if b in blocks),
        items=items,
        creatures=tuple(dict.fromkeys(m.lower() for m in mobs)),
        place_at="localization_placing" in kinds,
        shapes=tuple(s for s in ("line", "square", "star") if f"build_{s}" in kinds),
    )


class SkillParse(BaseModel):
    """What the parser read from one answer: a skill, or why none."""

    model_config = ConfigDict(frozen=True)

    skill: AnySkill | None
    stage: SkillStage
    reason: str | None = None
    """Why the answer is no skill of the catalogue (`invalid` only)."""
    raw: str


_WORD = re.compile(r"[a-z0-9_]+")
_FIELD = re.compile(r"^\W*skill\s*[:=]\s*(.+?)\s*$", re.IGNORECASE | re.MULTILINE)


def _words(text: str) -> list[str]:
    return _WORD.findall(text.lower().replace("-", "_"))


def _known(value: str, options: Sequence[str], what: str) -> str:
    value = _BLOCK_ALIASES.get(value, value) if what == "block" else value
    if value in options:
        return value
    singular = value[:-1] if value.endswith("s") else value
    if singular in options:
        return singular
    raise _Bad(f"unknown {what} {value!r}; known: {', '.join(options)}")


def _number(word: str, what: str, low: int, high: int) -> int:
    if not word.isdigit() or not low <= int(word) <= high:
        raise _Bad(f"{what} must be a whole number from {low} to {high}, not {word!r}")
    return int(word)


class _Bad(Exception):
    """A line that names a skill with a parameter outside the catalogue."""


def _read(words: list[str], offer: SkillOffer) -> AnySkill:
    """The skill `words` name, or `_Bad` with the reason."""
    if not words:
        raise _Bad("empty answer")
    verb, rest = words[0], words[1:]
    if verb == "go" and rest[:1] == ["to"]:
        verb, rest = "go_to", rest[1:]
    elif verb == "goto":
        verb = "go_to"
    if verb in ("eat", "drink", "sleep", "explore", "noop"):
        if rest:
            raise _Bad(f"{verb} takes no parameters")
        return Simple(name=verb)
    if verb == "collect":
        if not rest or len(rest) > 2:
            raise _Bad("write collect <material> [n]")
        count = _number(rest[1], "n", 1, _MAX_COUNT) if len(rest) == 2 else 1
        return Collect(material=_known(rest[0], offer.materials, "material"), count=count)
    if verb == "craft":
        if not rest:
            raise _Bad("write craft <item>")
        return Craft(item=_known("_".join(rest), offer.items, "item"))
    if verb == "go_to":
        if not rest:
            raise _Bad("write go to <block>")
        return GoTo(block=_known("_".join(rest), offer.blocks, "block"))
    if verb == "attack":
        if len(rest) != 1:
            raise _Bad("write attack <creature>")
        return Attack(creature=_known(rest[0], offer.creatures, "creature"))
    if verb == "place":
        return _place(rest, offer)
    if verb == "build":
        return _build(rest, offer)
    raise _Bad(f"unknown skill {verb!r}; skills: {', '.join(_VERBS)}")


_VERBS = ("collect", "place", "build", "craft", "go to", "eat", "drink", "sleep", "attack",
          "explore", "noop")  # fmt: skip


_PLACE_FILLER = frozenset(
    ("of", "the", "a", "an", "from", "to", "tiles", "tile", "blocks", "block", "cells", "cell",
     "side", "away", "existing", "nearest", "at")
)  # fmt: skip
_SIDE_WORDS: dict[str, str] = {
    "above": "up", "over": "up", "north": "up", "below": "down", "under": "down",
    "beneath": "down", "south": "down", "east": "right", "west": "left",
}  # fmt: skip
_NUMBER_WORDS = {
    word: str(number)
    for number, word in enumerate(("zero", "one", "two", "three", "four", "five", "six", "seven",
                                   "eight", "nine", "ten"))
}  # fmt: skip


def _place(rest: list[str], offer: SkillOffer) -> Place:
    if not rest:
        raise _Bad("write place <block>")
    block = _known(rest[0], offer.placeable, "block")
    if len(rest) == 1:
        return Place(block=block)
    if not offer.place_at:
        raise _Bad(f"place takes only a block on {offer.difficulty}: write place {block}")
    # Small models write a localization as prose ("2 blocks to the left of the furnace",
    # "two blocks above the tree"): the same three parameters, read through its wording.
    where = [
        _SIDE_WORDS.get(word, _NUMBER_WORDS.get(word, word))
        for word in rest[1:]
        if word not in _PLACE_FILLER
    ]
    sides = [w for w in where if w in SIDES]
    numbers = [w for w in where if w.isdigit()]
    others = [w for w in where if w not in SIDES and not w.isdigit()]
    if len(sides) != 1 or len(numbers) != 1 or len(others) != 1:
        raise _Bad("write place <block> <side> <distance> of <reference>")
    return Place(
        block=block,
        side=sides[0],
        distance=_number(numbers[0], "distance", 0, _MAX_DISTANCE),
        reference=_known(others[0], offer.blocks, "block"),
    )


def _build(rest: list[str], offer: SkillOffer) -> Build:
    if not offer.shapes:
        raise _Bad(f"nothing is built on {offer.difficulty}: no build skill is offered")
    if len(rest) < 3:
        raise _Bad("write build <shape> <block> <size>")
    shape = _known(rest[0], offer.shapes, "shape")
    block = _known(rest[1], offer.placeable, "block")
    size = _number(rest[2], "size", 1, _MAX_SIZE)
    extra = rest[3:]
    if shape == "line":
        if extra not in ([], ["diagonal"], ["straight"]):
            raise _Bad("a line is straight or diagonal: write build line <block> <size> [diagonal]")
        return Build(shape="line", block=block, size=size, diagonal=extra == ["diagonal"])
    if shape == "star":
        cross = _known(extra[0], CROSS_TYPES, "cross") if len(extra) == 1 else "straight"
        if len(extra) > 1:
            raise _Bad("write build star <block> <size> <straight|diagonal|combined>")
        return Build(shape="star", block=block, size=size, cross=cross)
    if extra:
        raise _Bad("write build square <block> <size>")
    return Build(shape="square", block=block, size=size)


def read_skill(text: str, offer: SkillOffer) -> AnySkill:
    """The skill `text` names in the catalogue form; raises ValueError with the reason."""
    try:
        return _read(_words(text), offer)
    except _Bad as bad:
        raise ValueError(str(bad)) from None


def parse_skill(
    text: str, offer: SkillOffer, prompt: str | Sequence[str] | None = None
) -> SkillParse:
    """Read one skill from a model's answer (the module's stages); never raises."""
    answer = split_reasoning(text).answer
    fields = _FIELD.findall(answer)
    if fields:
        return _attempt(fields[-1], offer, "field", text)
    whole = _attempt(answer, offer, "exact", text)
    if whole.skill is not None:
        return whole
    pieces = [prompt] if isinstance(prompt, str) else list(prompt or ())
    echoed = {" ".join(_words(line)) for piece in pieces for line in piece.splitlines()}
    lines = [
        line
        for line in answer.splitlines()
        if _words(line) and " ".join(_words(line)) not in echoed
    ]
    closest: SkillParse | None = None
    for line in reversed(lines):
        attempt = _attempt(line, offer, "exact", text)
        if attempt.skill is not None:
            return attempt
        if closest is None and not (attempt.reason or "").startswith("unknown skill"):
            closest = attempt
    if closest is not None:
        return closest
    if not answer.strip():
        return SkillParse(skill=None, stage="invalid", reason="empty answer", raw=text)
    return whole


_TAIL = re.compile(r"[:(,;]")


def _attempt(line: str, offer: SkillOffer, stage: SkillStage, raw: str) -> SkillParse:
    """`line` read as a skill; failing that, its part before a `:`, `(`, `,` or `;` (a skill
    followed by a comment, as when a history line `place stone: failed (...)` is copied)."""
    try:
        return SkillParse(skill=_read(_words(line), offer), stage=stage, raw=raw)
    except _Bad as bad:
        head = _TAIL.split(line, maxsplit=1)[0]
        if head != line and _words(head):
            try:
                return SkillParse(skill=_read(_words(head), offer), stage=stage, raw=raw)
            except _Bad:
                pass
        return SkillParse(skill=None, stage="invalid", reason=str(bad), raw=raw)
