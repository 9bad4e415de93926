"""Reading a plan's steps into the skills catalogue's skills (`agents.skill_catalogue`).

A step is read in the catalogue's words and in the words plans are written in: the dataset's
paraphrases ("smelter", "workbench", "rock", "timber") and the textualizer's names
(`crafting_table`, `wood_pickaxe`). Its first verb the reader knows decides what it does
(collect, place, craft, go to, attack, eat, drink, sleep, explore), the things after it what
with: "Collect some wood" is `collect wood`, "Navigate to smelter" `go to furnace`, "Deposit rock
on ground" `place stone`, "Craft two furnaces" `place furnace` twice (a table and a furnace are
made by placing them), "Gather coal and iron" `collect coal` then `collect iron`. A step that
names no verb or no thing the catalogue knows ("Move left", "Smelt iron in furnace", "Craft a
pickaxe": which one?) is unread, with the reason: nothing is guessed.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from llm_agents.agents.skills.catalogue import SkillOffer, read_skill
from llm_agents.planning.records import StepReading

#: Phrases of more than one word, longest first, rewritten as one token before reading.
_PHRASES: dict[str, str] = {
    "apparatus for smelting ore": "furnace",
    "apparatus for smelting": "furnace",
    "heating station": "furnace",
    "smelting station": "furnace",
    "smelting furnace": "furnace",
    "crafting table": "crafting_table",
    "crafting bench": "crafting_table",
    "crafting station": "crafting_table",
    "craft table": "crafting_table",
    "work bench": "crafting_table",
    "work table": "crafting_table",
    "iron ore": "iron",
    "coal ore": "coal",
    "pick up": "collect",
    "cut down": "collect",
    "chop down": "collect",
    "go to": "go",
    "wake up": "wake",
}
for _tier in ("wood", "stone", "iron"):
    for _tool in ("pickaxe", "sword"):
        for _adjective in {_tier, "wooden" if _tier == "wood" else _tier}:
            _PHRASES[f"{_adjective} {_tool}"] = f"{_tier}_{_tool}"
            _PHRASES[f"{_adjective}_{_tool}"] = f"{_tier}_{_tool}"

#: Word -> the thing it names (a block, material, item or creature, in the catalogue's names).
_THINGS: dict[str, str] = {
    "crafting_table": "crafting_table", "table": "crafting_table", "workbench": "crafting_table",
    "bench": "crafting_table", "workstation": "crafting_table",
    "furnace": "furnace", "smelter": "furnace", "foundry": "furnace", "kiln": "furnace",
    "forge": "furnace", "oven": "furnace", "smeltery": "furnace",
    "stone": "stone", "rock": "stone", "cobblestone": "stone", "boulder": "stone",
    "pebble": "stone", "tree": "tree", "wood": "wood", "log": "wood", "timber": "wood",
    "lumber": "wood", "coal": "coal", "iron": "iron", "diamond": "diamond", "gem": "diamond",
    "water": "water", "lake": "water", "pond": "water", "river": "water",
    "sapling": "sapling", "seed": "sapling", "plant": "plant", "grass": "grass", "sand": "sand",
    "lava": "lava", "cow": "cow", "cattle": "cow", "beef": "cow", "meat": "cow",
    "zombie": "zombie", "skeleton": "skeleton",
    "wood_pickaxe": "wood_pickaxe", "stone_pickaxe": "stone_pickaxe",
    "iron_pickaxe": "iron_pickaxe", "wood_sword": "wood_sword", "stone_sword": "stone_sword",
    "iron_sword": "iron_sword", "pickaxe": "pickaxe", "sword": "sword",
}  # fmt: skip
#: Word -> what a step beginning with it does.
_VERBS: dict[str, str] = {
    **dict.fromkeys(
        ("collect", "gather", "mine", "chop", "harvest", "obtain", "get", "acquire", "cut",
         "dig", "take", "fetch", "extract", "punch", "break", "grab", "procure", "secure"),
        "collect",
    ),
    **dict.fromkeys(
        ("place", "put", "set", "deposit", "position", "situate", "drop", "lay", "install",
         "plant", "erect"),
        "place",
    ),
    **dict.fromkeys(
        ("craft", "make", "create", "build", "construct", "produce", "fashion", "assemble"),
        "craft",
    ),
    **dict.fromkeys(
        ("go", "move", "navigate", "approach", "walk", "head", "travel", "find", "locate",
         "reach", "return", "search", "seek", "proceed", "stand", "run"),
        "go_to",
    ),
    **dict.fromkeys(("attack", "kill", "defeat", "fight", "slay", "hit", "strike", "hunt"),
                    "attack"),
    **dict.fromkeys(("eat", "consume"), "eat"),
    "drink": "drink",
    **dict.fromkeys(("sleep", "rest", "nap"), "sleep"),
    "explore": "explore",
}  # fmt: skip
_COUNTS = {"a": 1, "an": 1, "one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6,
           "seven": 7, "eight": 8, "nine": 9, "ten": 10, "twice": 2}  # fmt: skip
#: Words after which a step names its means or place, not what it works on ("Mine iron with a
#: pickaxe", "Craft a sword at the table").
_MEANS = frozenset({"at", "using", "with", "near", "beside", "on", "in", "by", "next", "inside",
                    "via", "from", "into", "onto", "for", "to", "of", "nearby", "close"})  # fmt: skip
_SIDES = {"left": "left", "right": "right", "up": "up", "down": "down", "above": "up",
          "below": "down", "north": "up", "south": "down", "west": "left", "east": "right"}  # fmt: skip
_MATERIAL_OF = {"tree": "wood", "plant": "sapling", "grass": "sapling"}
_BLOCK_OF = {"wood": "tree", "sapling": "grass"}
_PLACED_AS = {"sapling": "plant"}
_CREATURES = frozenset({"cow", "zombie", "skeleton"})
_MAX_COLLECT = 9
_TOKEN = re.compile(r"[a-z0-9_]+|[,;]")


def _normalise(text: str) -> list[str]:
    words = " ".join(_TOKEN.findall(text.lower().replace("-", " ").replace("'s", "")))
    for phrase in sorted(_PHRASES, key=len, reverse=True):
        words = re.sub(rf"\b{phrase}\b", _PHRASES[phrase], words)
    return [_singular(word) for word in words.split()]


def _singular(word: str) -> str:
    if word in _THINGS or word in _VERBS or word in _COUNTS:
        return word
    for suffix, replacement in (("ies", "y"), ("es", ""), ("s", "")):
        if word.endswith(suffix) and (stem := word[: -len(suffix)] + replacement) in _THINGS:
            return stem
    return word


@dataclass(frozen=True)
class _Thing:
    name: str
    count: int
    after_means: bool
    """Named after a word such as "at" or "with" (the means or place, not the object)."""


def _things(words: list[str]) -> list[_Thing]:
    found: list[_Thing] = []
    count, means, previous = 1, False, ""
    for word in words:
        if word.isdigit() and previous in _THINGS and found and found[-1].count == 1:
            # The catalogue's own form puts the count after the material: "collect wood 3".
            found[-1] = _Thing(found[-1].name, int(word), found[-1].after_means)
        elif word in _MEANS:
            means = True
        elif word.isdigit():
            count = int(word)
        elif word in _COUNTS:
            count = _COUNTS[word]
        elif word in _THINGS:
            found.append(_Thing(_THINGS[word], count, means))
            count = 1
        previous = word
    return found


class _Unread(Exception):
    """A step that names nothing the catalogue knows."""


def _clauses(words: list[str]) -> list[list[str]]:
    """A step cut where a new action begins: after a comma or semicolon, at "then", or at
    "and" followed by a verb ("Find and kill a cow", "Move to tree, gather wood")."""
    clauses: list[list[str]] = [[]]
    for i, word in enumerate(words):
        following = words[i + 1] if i + 1 < len(words) else ""
        if word in (",", ";", "then") or (word == "and" and following in _VERBS):
            if clauses[-1]:
                clauses.append([])
            continue
        clauses[-1].append(word)
    return [clause for clause in clauses if clause]


def read_step(text: str, offer: SkillOffer) -> tuple[tuple[str, ...], str | None]:
    """The skills (in the catalogue's form) a plan step names, in order, and why a part of it
    reads as none (None when every part was read); raises ValueError with the reason when the
    whole step names none."""
    skills: list[str] = []
    unread: list[str] = []
    for clause in _clauses(_normalise(text)):
        try:
            skills += _read_clause(clause, offer)
        except ValueError as err:
            unread.append(str(err))
    if not skills:
        raise ValueError("; ".join(unread) or "empty step")
    return tuple(skills), "; ".join(unread) or None


def _read_clause(words: list[str], offer: SkillOffer) -> list[str]:
    verb_at = next((i for i, word in enumerate(words) if word in _VERBS), None)
    if verb_at is None:
        raise ValueError("no action the skills know (collect, place, craft, go to, attack, ...)")
    verb, rest = _VERBS[words[verb_at]], words[verb_at + 1 :]
    things = _things(rest)
    try:
        skills = _SKILLS[verb](things, rest, offer)
    except _Unread as unread:
        raise ValueError(f"{words[verb_at]}: {unread}") from None
    for skill in skills:
        try:
            read_skill(skill, offer)
        except ValueError as err:
            raise ValueError(f"{skill}: {err}") from None
    return skills


def _objects(things: list[_Thing]) -> list[_Thing]:
    """The things a step works on: those before its means or place, else all of them."""
    direct = [thing for thing in things if not thing.after_means]
    return direct or things


def _collect(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    named = [t for t in _objects(things)]
    if any(t.name == "water" for t in named):
        return ["drink"]
    materials: dict[str, int] = {}
    for thing in named:
        material = _MATERIAL_OF.get(thing.name, thing.name)
        if material in offer.materials:
            materials[material] = max(materials.get(material, 0), thing.count)
    if not materials:
        what = ", ".join(t.name for t in named) or "nothing"
        raise _Unread(f"names no material ({what}); collect takes {', '.join(offer.materials)}")
    skills = []
    for material, count in materials.items():
        while count > 0:
            part = min(count, _MAX_COLLECT)
            skills.append(f"collect {material}" + (f" {part}" if part > 1 else ""))
            count -= part
    return skills


def _place(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    blocks = [t for t in _objects(things) if _PLACED_AS.get(t.name, t.name) in offer.placeable]
    if not blocks:
        what = ", ".join(t.name for t in things) or "nothing"
        raise _Unread(f"names no block to place ({what}); place takes {', '.join(offer.placeable)}")
    block = blocks[0]
    name = _PLACED_AS.get(block.name, block.name)
    if offer.place_at:
        where = _where(things, rest, block)
        if where is not None:
            return [f"place {name} {where}"]
    return [f"place {name}"] * min(block.count, _MAX_COLLECT)


def _where(things: list[_Thing], rest: list[str], block: _Thing) -> str | None:
    """`side distance of reference` when the step names all three ("2 blocks left of the
    furnace"), else None."""
    sides = [_SIDES[w] for w in rest if w in _SIDES]
    numbers = [w for w in rest if w.isdigit()] or [
        str(_COUNTS[w]) for w in rest if w in _COUNTS and w not in ("a", "an")
    ]
    references = [t for t in things if t is not block and t.after_means]
    if len(sides) != 1 or len(numbers) != 1 or len(references) != 1:
        return None
    reference = _BLOCK_OF.get(references[0].name, references[0].name)
    return f"{sides[0]} {numbers[0]} of {reference}"


def _craft(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    skills: list[str] = []
    craftable = [t for t in things if t.name in (*offer.items, "crafting_table", "furnace")]
    direct = [t for t in craftable if not t.after_means]
    for thing in direct or craftable or _objects(things):
        if thing.name in offer.items:
            skills.append(f"craft {thing.name}")
        elif thing.name in ("crafting_table", "furnace"):
            skills += [f"place {thing.name}"] * min(thing.count, _MAX_COLLECT)
        elif thing.name in ("pickaxe", "sword"):
            raise _Unread(f"which {thing.name}? (wood, stone or iron)")
    if not skills:
        what = ", ".join(t.name for t in things) or "nothing"
        raise _Unread(
            f"names nothing craftable ({what}); craft takes {', '.join(offer.items)}, "
            "crafting_table, furnace"
        )
    return skills


def _go_to(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    for thing in things:
        block = _BLOCK_OF.get(thing.name, thing.name)
        if block in offer.blocks:
            return [f"go to {block}"]
    what = ", ".join(t.name for t in things) or "nothing"
    raise _Unread(f"names no block to go to ({what})")


def _attack(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    creatures = [t.name for t in things if t.name in offer.creatures]
    if not creatures:
        raise _Unread(f"names no creature; attack takes {', '.join(offer.creatures)}")
    return [f"attack {creatures[0]}"]


def _eat(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    if any(t.name != "cow" for t in _objects(things)):
        raise _Unread("eat hunts a cow; the skills eat nothing else")
    return ["eat"]


_Reader = Callable[[list[_Thing], list[str], SkillOffer], list[str]]


def _simple(name: str) -> _Reader:
    def read(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
        if name == "explore" and things:
            return _go_to(things, rest, offer)
        return [name]

    return read


_SKILLS: dict[str, _Reader] = {
    "collect": _collect,
    "place": _place,
    "craft": _craft,
    "go_to": _go_to,
    "attack": _attack,
    "eat": _eat,
    "drink": _simple("drink"),
    "sleep": _simple("sleep"),
    "explore": _simple("explore"),
}


def read_plan(steps: list[str], offer: SkillOffer) -> list[StepReading]:
    """Every step of a plan read (`read_step`), unread ones with their reason."""
    readings = []
    for number, text in enumerate(steps, 1):
        try:
            skills, partly = read_step(text, offer)
            readings.append(StepReading(number=number, text=text, skills=skills, unread=partly))
        except ValueError as err:
            readings.append(StepReading(number=number, text=text, unread=str(err)))
    return readings
