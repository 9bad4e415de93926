"""Craftax ids -> the names the textualizer uses, for both variants.

Names are craftax's own enum names (`env.craftax_names`) in lower case, so text and logs match
the game's vocabulary. The other game constants here are copied by value because importing
craftax would import JAX, which only `env/` may do; `tests/test_textualizer_vocabulary.py`
checks them against craftax itself.
"""

from typing import Literal

from env import craftax_names as names
from env.variant import Variant


def _lower(values: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(value.lower() for value in values)


BLOCK_NAMES: tuple[str, ...] = _lower(names.FULL_BLOCKS)
"""Full Craftax `BlockType` by value; Craftax-Classic uses the first 17 with the same values."""

OUT_OF_BOUNDS = BLOCK_NAMES.index("out_of_bounds")

ITEM_NAMES: tuple[str, ...] = _lower(names.FULL_ITEMS)
"""Full Craftax `ItemType` by value (items lie on top of a block; Classic has none)."""

BACKGROUND_BLOCKS: dict[Variant, frozenset[str]] = {
    Variant.CLASSIC: frozenset({"grass", "sand", "path"}),
    Variant.FULL: frozenset({"grass", "sand", "path", "fire_grass", "ice_grass"}),
}
"""Walkable floor a player can place things on; the `objects` renderer does not list it."""

MELEE_MOB_NAMES: tuple[str, ...] = _lower(names.MELEE_MOBS)
PASSIVE_MOB_NAMES: tuple[str, ...] = _lower(names.PASSIVE_MOBS)
RANGED_MOB_NAMES: tuple[str, ...] = _lower(names.RANGED_MOBS)
PROJECTILE_NAMES: tuple[str, ...] = tuple(
    name.rstrip("2") for name in _lower(names.FULL_PROJECTILES)
)
"""Full Craftax `ProjectileType` by value; the two tiers of a projectile look the same."""

FLOOR_NAMES: tuple[str, ...] = (
    "overworld",
    "dungeon",
    "gnomish mines",
    "sewers",
    "vaults",
    "troll mines",
    "fire realm",
    "ice realm",
    "graveyard",
)

VIEW_SHAPE: dict[Variant, tuple[int, int]] = {Variant.CLASSIC: (7, 9), Variant.FULL: (9, 11)}
"""craftax `OBS_DIM` (rows, columns) of the local view centred on the player."""

LIGHT_THRESHOLD = 0.05
"""Full Craftax hides a tile whose light-map value is not above this (as its symbolic obs)."""

TIERS: tuple[str, ...] = ("", "wood", "stone", "iron", "diamond")
"""Full Craftax pickaxe/sword level -> material."""

ARMOUR_TIERS: tuple[str, ...] = ("", "iron", "diamond")
ARMOUR_SLOTS: tuple[str, ...] = ("helmet", "chestplate", "leggings", "boots")
ENCHANTMENTS: tuple[str, ...] = ("", "fire", "ice")
POTION_COLOURS: tuple[str, ...] = ("red", "green", "blue", "pink", "cyan", "yellow")
SPELLS: tuple[str, ...] = ("fireball", "iceball")

DIRECTION_NAMES: dict[int, Literal["left", "right", "up", "down"]] = {
    1: "left",
    2: "right",
    3: "up",
    4: "down",
}
"""`player_direction` value -> the move action that points that way (craftax `Action`)."""

FACING_OFFSETS: dict[str, tuple[int, int]] = {
    "left": (-1, 0),
    "right": (1, 0),
    "up": (0, 1),
    "down": (0, -1),
}
"""Facing direction -> (dx, dy) of the faced tile in the textualizer's convention."""

MONSTERS_TO_OPEN_LADDER = 8
"""craftax `MONSTERS_KILLED_TO_CLEAR_LEVEL`: kills on a floor before its down ladder opens."""
