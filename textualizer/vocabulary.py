"""Craftax ids -> the names the textualizer uses, for both variants.

Copied by value from craftax's enums because importing craftax would import JAX, which only
`env/` may do; `tests/test_textualizer_vocabulary.py` checks every table against craftax itself.
Names are craftax's own enum names in lower case, so text and logs match the game's vocabulary.
"""

from typing import Literal

from env.variant import Variant

BLOCK_NAMES: tuple[str, ...] = (
    "invalid",
    "out_of_bounds",
    "grass",
    "water",
    "stone",
    "tree",
    "wood",
    "path",
    "coal",
    "iron",
    "diamond",
    "crafting_table",
    "furnace",
    "sand",
    "lava",
    "plant",
    "ripe_plant",
    "wall",
    "darkness",
    "wall_moss",
    "stalagmite",
    "sapphire",
    "ruby",
    "chest",
    "fountain",
    "fire_grass",
    "ice_grass",
    "gravel",
    "fire_tree",
    "ice_shrub",
    "enchantment_table_fire",
    "enchantment_table_ice",
    "necromancer",
    "grave",
    "grave2",
    "grave3",
    "necromancer_vulnerable",
)
"""Full Craftax `BlockType` by value; Craftax-Classic uses the first 17 with the same values."""

NUM_CLASSIC_BLOCKS = 17
OUT_OF_BOUNDS = BLOCK_NAMES.index("out_of_bounds")

ITEM_NAMES: tuple[str, ...] = ("none", "torch", "ladder_down", "ladder_up", "ladder_down_blocked")
"""Full Craftax `ItemType` by value (items lie on top of a block; Classic has none)."""

BACKGROUND_BLOCKS: dict[Variant, frozenset[str]] = {
    Variant.CLASSIC: frozenset({"grass", "sand", "path"}),
    Variant.FULL: frozenset({"grass", "sand", "path", "fire_grass", "ice_grass"}),
}
"""Walkable floor a player can place things on; the `objects` renderer does not list it."""

MELEE_MOB_NAMES: tuple[str, ...] = (
    "zombie",
    "gnome_warrior",
    "orc_soldier",
    "lizard",
    "knight",
    "troll",
    "pigman",
    "frost_troll",
)
PASSIVE_MOB_NAMES: tuple[str, ...] = ("cow", "bat", "snail")
RANGED_MOB_NAMES: tuple[str, ...] = (
    "skeleton",
    "gnome_archer",
    "orc_mage",
    "kobold",
    "knight_archer",
    "deep_thing",
    "fire_elemental",
    "ice_elemental",
)
PROJECTILE_NAMES: tuple[str, ...] = (
    "arrow",
    "dagger",
    "fireball",
    "iceball",
    "arrow",
    "slimeball",
    "fireball",
    "iceball",
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

FULL_ACHIEVEMENTS: dict[int, str] = {
    0: "COLLECT_WOOD",
    1: "PLACE_TABLE",
    2: "EAT_COW",
    3: "COLLECT_SAPLING",
    4: "COLLECT_DRINK",
    5: "MAKE_WOOD_PICKAXE",
    6: "MAKE_WOOD_SWORD",
    7: "PLACE_PLANT",
    8: "DEFEAT_ZOMBIE",
    9: "COLLECT_STONE",
    10: "PLACE_STONE",
    11: "EAT_PLANT",
    12: "DEFEAT_SKELETON",
    13: "MAKE_STONE_PICKAXE",
    14: "MAKE_STONE_SWORD",
    15: "WAKE_UP",
    16: "PLACE_FURNACE",
    17: "COLLECT_COAL",
    18: "COLLECT_IRON",
    19: "COLLECT_DIAMOND",
    20: "MAKE_IRON_PICKAXE",
    21: "MAKE_IRON_SWORD",
    22: "MAKE_ARROW",
    23: "MAKE_TORCH",
    24: "PLACE_TORCH",
    25: "MAKE_DIAMOND_SWORD",
    26: "MAKE_IRON_ARMOUR",
    27: "MAKE_DIAMOND_ARMOUR",
    28: "ENTER_GNOMISH_MINES",
    29: "ENTER_DUNGEON",
    30: "ENTER_SEWERS",
    31: "ENTER_VAULT",
    32: "ENTER_TROLL_MINES",
    33: "ENTER_FIRE_REALM",
    34: "ENTER_ICE_REALM",
    35: "ENTER_GRAVEYARD",
    36: "DEFEAT_GNOME_WARRIOR",
    37: "DEFEAT_GNOME_ARCHER",
    38: "DEFEAT_ORC_SOLIDER",
    39: "DEFEAT_ORC_MAGE",
    40: "DEFEAT_LIZARD",
    41: "DEFEAT_KOBOLD",
    42: "DEFEAT_TROLL",
    43: "DEFEAT_DEEP_THING",
    44: "DEFEAT_PIGMAN",
    45: "DEFEAT_FIRE_ELEMENTAL",
    46: "DEFEAT_FROST_TROLL",
    47: "DEFEAT_ICE_ELEMENTAL",
    48: "DAMAGE_NECROMANCER",
    49: "DEFEAT_NECROMANCER",
    50: "EAT_BAT",
    51: "EAT_SNAIL",
    52: "FIND_BOW",
    53: "FIRE_BOW",
    54: "COLLECT_SAPPHIRE",
    55: "LEARN_FIREBALL",
    56: "CAST_FIREBALL",
    57: "LEARN_ICEBALL",
    58: "CAST_ICEBALL",
    59: "COLLECT_RUBY",
    60: "MAKE_DIAMOND_PICKAXE",
    61: "OPEN_CHEST",
    62: "DRINK_POTION",
    63: "ENCHANT_SWORD",
    64: "ENCHANT_ARMOUR",
    65: "DEFEAT_KNIGHT",
    66: "DEFEAT_ARCHER",
}
"""Full Craftax `Achievement` names by id (the enum's spelling, typo included)."""

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
