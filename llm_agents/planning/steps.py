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

Counts are read as a player would mean them (`read_plan`): a collect that names no count ("Collect
wood", "Gather some stone") or a plural one ("Collect trees") gathers what the plan's later steps
spend of the material before it is collected again (a table two wood, a stone pickaxe one wood
and one stone), a plural at least two; and a table or furnace crafted and then placed ("Craft a
table. Place the table.") is one placement, made where the plan places it. Each such reading is
noted on its step.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from llm_agents.agents.expert.plan import FURNACE_STONE, INVENTORY_CAP, RECIPES, TABLE_WOOD
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
_MAX_COLLECT = INVENTORY_CAP
_TOKEN = re.compile(r"[a-z0-9_]+|[,;]")
#: Put before a word that was plural ("trees"): the reader cannot see it once singular.
_PLURAL = "+plural"
#: A collect whose count the plan's later steps decide: `collect wood ?2` gathers what they
#: need, at least 2.
_OPEN = "?"
#: Put after a table or furnace placement read from a craft verb ("Craft a table").
_CRAFTED = " !crafted"
#: What one placement spends, by block.
_PLACE_COST: dict[str, tuple[str, int]] = {
    "crafting_table": ("wood", TABLE_WOOD),
    "furnace": ("stone", FURNACE_STONE),
    "stone": ("stone", 1),
    "plant": ("sapling", 1),
}


def _normalise(text: str) -> list[str]:
    words = " ".join(_TOKEN.findall(text.lower().replace("-", " ").replace("'s", "")))
    for phrase in sorted(_PHRASES, key=len, reverse=True):
        words = re.sub(rf"\b{phrase}\b", _PHRASES[phrase], words)
    normal: list[str] = []
    for word in words.split():
        single = _singular(word)
        if single != word:
            normal.append(_PLURAL)
        normal.append(single)
    return normal


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
    counted: bool = True
    """The step gave its count ("two trees", "a tree", "wood 3")."""
    plural: bool = False


def _things(words: list[str]) -> list[_Thing]:
    found: list[_Thing] = []
    count, counted, plural, means, previous = 1, False, False, False, ""
    for word in words:
        if word.isdigit() and previous in _THINGS and found and not found[-1].counted:
            # The catalogue's own form puts the count after the material: "collect wood 3".
            last = found[-1]
            found[-1] = _Thing(last.name, int(word), last.after_means, True, last.plural)
        elif word == _PLURAL:
            plural = True
            continue
        elif word in _MEANS:
            means = True
        elif word.isdigit():
            count, counted = int(word), True
        elif word in _COUNTS:
            count, counted = _COUNTS[word], True
        elif word in _THINGS:
            found.append(_Thing(_THINGS[word], count, means, counted, plural))
            count, counted = 1, False
        plural = False
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
    whole step names none. Read alone, a collect without a count gathers its least (one, two
    for a plural): `read_plan` reads it against the steps after it."""
    skills, unread = _read_marked(text, offer)
    return tuple(_plain(skill, 0) for skill in skills), unread


def _read_marked(text: str, offer: SkillOffer) -> tuple[tuple[str, ...], str | None]:
    """`read_step` with the plan-level marks left on (open counts, crafted placements)."""
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
            read_skill(_plain(skill, 0), offer)
        except ValueError as err:
            raise ValueError(f"{_plain(skill, 0)}: {err}") from None
    return skills


def _plain(skill: str, needed: int) -> str:
    """A marked skill in the catalogue's form: an open collect gathers `needed`, at least its
    least and at most the inventory's cap."""
    skill = skill.removesuffix(_CRAFTED)
    if _OPEN not in skill:
        return skill
    head, least = skill.split(f" {_OPEN}")
    count = min(max(int(least), needed), _MAX_COLLECT)
    return head + (f" {count}" if count > 1 else "")


def _objects(things: list[_Thing]) -> list[_Thing]:
    """The things a step works on: those before its means or place, else all of them."""
    direct = [thing for thing in things if not thing.after_means]
    return direct or things


def _collect(things: list[_Thing], rest: list[str], offer: SkillOffer) -> list[str]:
    named = [t for t in _objects(things)]
    if any(t.name == "water" for t in named):
        return ["drink"]
    materials: dict[str, int] = {}
    open_least: dict[str, int] = {}
    for thing in named:
        material = _MATERIAL_OF.get(thing.name, thing.name)
        if material in offer.materials:
            materials[material] = max(materials.get(material, 0), thing.count)
            if not thing.counted:
                least = max(open_least.get(material, 1), 2 if thing.plural else 1)
                open_least[material] = least
    for material in [
        m
        for m in open_least
        if any(t.counted and _MATERIAL_OF.get(t.name, t.name) == m for t in named)
    ]:
        del open_least[material]  # "two trees and more wood": the count given wins
    if not materials:
        what = ", ".join(t.name for t in named) or "nothing"
        raise _Unread(f"names no material ({what}); collect takes {', '.join(offer.materials)}")
    skills = []
    for material, count in materials.items():
        if material in open_least:
            skills.append(f"collect {material} {_OPEN}{open_least[material]}")
            continue
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
            skills += [f"place {thing.name}{_CRAFTED}"] * min(thing.count, _MAX_COLLECT)
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
    objects = _objects(things)
    named = [w for w in rest if w not in _COUNTS and w not in _MEANS and w != _PLURAL]
    # "Eat flora" names no cow: read as a cow hunt, it would be another plan (and one that
    # breaks "do not eat a cow").
    if any(t.name != "cow" for t in objects) or (named and not objects):
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
    """Every step of a plan read (`read_step`), unread ones with their reason, its counts read
    against the steps after it and a crafted-then-placed table placed once (see the module),
    each such reading noted on its step."""
    marked: list[tuple[str, list[str], str | None]] = []
    for text in steps:
        try:
            skills, partly = _read_marked(text, offer)
            marked.append((text, list(skills), partly))
        except ValueError as err:
            marked.append((text, [], str(err)))
    notes: list[list[str]] = [[] for _ in marked]
    _one_placement(marked, notes)
    flat = [
        (i, j, skill) for i, (_, skills, _) in enumerate(marked) for j, skill in enumerate(skills)
    ]
    for position, (i, j, skill) in enumerate(flat):
        if _OPEN not in skill:
            continue
        material = skill.split()[1]
        needed, users = 0, []
        for later_i, _, later in flat[position + 1 :]:
            if later.startswith(f"collect {material}"):
                break
            spent = _spends(_plain(later, 0), material)
            if spent:
                needed += spent
                users.append(later_i + 1)
        plain = _plain(skill, needed)
        marked[i][1][j] = plain
        least = int(skill.split(_OPEN)[1])
        why = "no count given" if least == 1 else "a plural"
        if users:
            steps_named = ", ".join(str(n) for n in dict.fromkeys(users))
            notes[i].append(
                f"{plain}: {why}; gathers the {needed} {material} step(s) {steps_named} spend"
                + (f" (at least {least})" if least > needed else "")
            )
        elif least > 1:
            notes[i].append(f"{plain}: {why}; no later step spends {material}")
    readings = []
    for number, ((text, read, unread), note) in enumerate(zip(marked, notes, strict=True), 1):
        readings.append(
            StepReading(
                number=number,
                text=text,
                skills=tuple(_plain(skill, 0) for skill in read),
                unread=unread,
                notes=tuple(note),
            )
        )
    return readings


def _one_placement(marked: list[tuple[str, list[str], str | None]], notes: list[list[str]]) -> None:
    """A table or furnace crafted ("Craft a table") and placed by the next step that reads
    ("Place the table") is one placement: the crafting step's is dropped."""
    for i, (_, skills, _) in enumerate(marked):
        crafted = [j for j, skill in enumerate(skills) if skill.endswith(_CRAFTED)]
        if not crafted or crafted[-1] != len(skills) - 1:
            continue
        following = next((k for k in range(i + 1, len(marked)) if marked[k][1]), None)
        if following is None:
            continue
        block_place = skills[-1].removesuffix(_CRAFTED)
        later = marked[following][1]
        placed = 0
        while placed < len(later) and later[placed] == block_place:
            placed += 1
        # Drop as many trailing crafted placements as the next step places of the block.
        dropped = 0
        while dropped < placed and skills and skills[-1] == block_place + _CRAFTED:
            skills.pop()
            dropped += 1
        if dropped:
            block = block_place.removeprefix("place ")
            notes[i].append(
                f"crafting a {block} is placing it: step {following + 1} places it, so it is "
                "placed once"
            )


def _spends(skill: str, material: str) -> int:
    """How much of `material` one catalogue skill spends."""
    words = skill.split()
    if words[0] == "craft":
        return int(getattr(RECIPES.get(f"MAKE_{words[1].upper()}"), material, 0))
    if words[0] == "place" and len(words) >= 2:
        cost = _PLACE_COST.get(words[1])
        return cost[1] if cost is not None and cost[0] == material else 0
    return 0
