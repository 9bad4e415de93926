"""The action catalogue: every action of both Craftax variants with its id and what it does.

Ids and names are those of craftax's `Action` enums, as `env.craftax_names` holds them (the
variant's `action_names`). The descriptions are ours,
written from craftax's game logic: "nearby" means one of the 8 cells around the player,
"facing" means the cell the player looks at (the last direction it moved or tried to move).
"""

from __future__ import annotations

from functools import cache

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from env.variant import Variant, as_variant


class ActionSpec(BaseModel):
    """One action of a variant."""

    model_config = ConfigDict(frozen=True)

    id: int
    """The integer id craftax's `Action` enum gives it."""
    name: str
    """The enum member's name, e.g. `MAKE_WOOD_PICKAXE`."""
    description: str
    """Its effect and preconditions in a sentence or two, for prompts."""


_MOVES: tuple[tuple[str, str], ...] = (
    ("LEFT", "west"),
    ("RIGHT", "east"),
    ("UP", "north"),
    ("DOWN", "south"),
)


def _move_descriptions(variant: Variant) -> list[str]:
    if variant is Variant.FULL:
        blocked = "(water, lava, a solid block or a creature)"
        hazard = ""
    else:
        blocked = "(water, a solid block or a creature)"
        hazard = " Stepping into lava kills you."
    return [
        f"Face {heading} and step one cell {heading}; if that cell is blocked {blocked} "
        f"you only turn to face it.{hazard}"
        for _, heading in _MOVES
    ]


_CLASSIC_DESCRIPTIONS: tuple[str, ...] = (
    "Do nothing for one step.",
    *_move_descriptions(Variant.CLASSIC),
    "Interact with the faced cell: attack a zombie, skeleton or cow (a killed cow is eaten), "
    "collect wood from a tree, stone or coal (needs a wood pickaxe), iron (needs a stone "
    "pickaxe) or diamond (needs an iron pickaxe), drink water, eat a ripe plant, or search "
    "grass for a sapling (10% chance).",
    "Fall asleep to restore energy; you wake up by yourself when energy is full.",
    "Put 1 stone on the faced cell (free ground or water).",
    "Spend 2 wood to build a crafting table on the faced free cell.",
    "Spend 1 stone to build a furnace on the faced free cell.",
    "Plant 1 sapling on the faced grass cell; it ripens into food later.",
    "Craft a wood pickaxe from 1 wood; needs a crafting table nearby.",
    "Craft a stone pickaxe from 1 wood and 1 stone; needs a crafting table nearby.",
    "Craft an iron pickaxe from 1 wood, 1 stone, 1 coal and 1 iron; needs a crafting table "
    "and a furnace nearby.",
    "Craft a wood sword from 1 wood; needs a crafting table nearby.",
    "Craft a stone sword from 1 wood and 1 stone; needs a crafting table nearby.",
    "Craft an iron sword from 1 wood, 1 stone, 1 coal and 1 iron; needs a crafting table and "
    "a furnace nearby.",
)

_FULL_DESCRIPTIONS: tuple[str, ...] = (
    "Do nothing for one step.",
    *_move_descriptions(Variant.FULL),
    "Interact with the faced cell: attack a creature (killed cows are eaten), collect wood "
    "from a tree, stone or coal (needs a wood pickaxe), iron (needs a stone pickaxe), diamond "
    "(needs an iron pickaxe), sapphire or ruby (need a diamond pickaxe), drink water, eat a "
    "ripe plant, open a chest, or search grass for a sapling (10% chance).",
    "Fall asleep to restore energy; you wake up by yourself when energy is full.",
    "Put 1 stone on the faced cell (free ground, water or lava).",
    "Spend 2 wood to build a crafting table on the faced free cell.",
    "Spend 1 stone to build a furnace on the faced free cell.",
    "Plant 1 sapling on the faced grass cell; it ripens into food later.",
    "Craft a wood pickaxe from 1 wood; needs a crafting table nearby and no better pickaxe.",
    "Craft a stone pickaxe from 1 wood and 1 stone; needs a crafting table nearby.",
    "Craft an iron pickaxe from 1 wood, 1 stone, 1 coal and 1 iron; needs a crafting table "
    "and a furnace nearby.",
    "Craft a wood sword from 1 wood; needs a crafting table nearby and no better sword.",
    "Craft a stone sword from 1 wood and 1 stone; needs a crafting table nearby.",
    "Craft an iron sword from 1 wood, 1 stone, 1 coal and 1 iron; needs a crafting table and "
    "a furnace nearby.",
    "Rest to recover health until it is full (stops if food or drink run out).",
    "Go down a floor; you must stand on a down ladder and have killed 8 creatures on this floor.",
    "Go up a floor; you must stand on an up ladder.",
    "Craft a diamond pickaxe from 1 wood and 3 diamonds; needs a crafting table nearby.",
    "Craft a diamond sword from 1 wood and 2 diamonds; needs a crafting table nearby.",
    "Craft one piece of iron armour from 3 iron and 3 coal; needs a crafting table and a "
    "furnace nearby.",
    "Craft one piece of diamond armour from 3 diamonds; needs a crafting table nearby.",
    "Shoot an arrow in the facing direction; needs a bow and at least 1 arrow.",
    "Craft 2 arrows from 1 wood and 1 stone; needs a crafting table nearby.",
    "Cast a fireball in the facing direction; needs the learned fireball spell and 2 mana.",
    "Cast an iceball in the facing direction; needs the learned iceball spell and 2 mana.",
    "Put 1 torch on the faced free cell to light the area.",
    "Drink a red potion (needs one); each colour has a random effect on health, mana or energy.",
    "Drink a green potion (needs one).",
    "Drink a blue potion (needs one).",
    "Drink a pink potion (needs one).",
    "Drink a cyan potion (needs one).",
    "Drink a yellow potion (needs one).",
    "Read a book (needs one) to learn a new spell.",
    "Enchant your sword while facing an enchantment table; costs 9 mana and 1 ruby (fire "
    "table) or 1 sapphire (ice table).",
    "Enchant your armour while facing an enchantment table; costs 9 mana and 1 ruby or sapphire.",
    "Craft 4 torches from 1 wood and 1 coal; needs a crafting table nearby.",
    "Spend 1 experience point to raise dexterity.",
    "Spend 1 experience point to raise strength.",
    "Spend 1 experience point to raise intelligence.",
    "Enchant your bow while facing an enchantment table; costs 9 mana and 1 ruby or sapphire.",
)

#: Compass heading of each movement action, as the prompts and observations name it.
MOVE_HEADINGS: dict[str, str] = dict(_MOVES)


def _build(names: tuple[str, ...], descriptions: tuple[str, ...]) -> tuple[ActionSpec, ...]:
    return tuple(
        ActionSpec(id=i, name=name, description=description)
        for i, (name, description) in enumerate(zip(names, descriptions, strict=True))
    )


_CATALOGUES: dict[Variant, tuple[ActionSpec, ...]] = {
    Variant.CLASSIC: _build(Variant.CLASSIC.action_names, _CLASSIC_DESCRIPTIONS),
    Variant.FULL: _build(Variant.FULL.action_names, _FULL_DESCRIPTIONS),
}


def action_catalogue(variant: Variant | str) -> tuple[ActionSpec, ...]:
    """All actions of a variant, in id order."""
    return _CATALOGUES[as_variant(variant)]


def action_names(variant: Variant | str) -> tuple[str, ...]:
    """The action names of a variant, in id order (index = action id)."""
    return as_variant(variant).action_names


@cache
def _ids(variant: Variant) -> dict[str, int]:
    return {name: i for i, name in enumerate(variant.action_names)}


def action_id(name: str, variant: Variant | str) -> int:
    """The id of an action name (exact enum name, case-insensitive) in a variant."""
    resolved = as_variant(variant)
    key = name.strip().upper()
    ids = _ids(resolved)
    if key not in ids:
        raise UserError(
            f"unknown action {name!r} for the {resolved.value} variant; "
            f"known: {', '.join(resolved.action_names)}"
        )
    return ids[key]
