"""Craftax's names for both variants, as plain data: actions, achievements, blocks, items, mobs.

Every other module takes Craftax's vocabulary from here. The tables are craftax's enum member
names in id order (index = the enum's value), copied by value because importing craftax imports
JAX, which only `env/` may do at run time and which the agent side must not need;
`tests/test_craftax_names.py` checks every table against the installed craftax. `Variant`
picks a variant's tables.
"""

CLASSIC_ACTIONS: tuple[str, ...] = (
    "NOOP",
    "LEFT",
    "RIGHT",
    "UP",
    "DOWN",
    "DO",
    "SLEEP",
    "PLACE_STONE",
    "PLACE_TABLE",
    "PLACE_FURNACE",
    "PLACE_PLANT",
    "MAKE_WOOD_PICKAXE",
    "MAKE_STONE_PICKAXE",
    "MAKE_IRON_PICKAXE",
    "MAKE_WOOD_SWORD",
    "MAKE_STONE_SWORD",
    "MAKE_IRON_SWORD",
)
"""Craftax-Classic `Action` names by id."""

FULL_ACTIONS: tuple[str, ...] = (
    *CLASSIC_ACTIONS,
    "REST",
    "DESCEND",
    "ASCEND",
    "MAKE_DIAMOND_PICKAXE",
    "MAKE_DIAMOND_SWORD",
    "MAKE_IRON_ARMOUR",
    "MAKE_DIAMOND_ARMOUR",
    "SHOOT_ARROW",
    "MAKE_ARROW",
    "CAST_FIREBALL",
    "CAST_ICEBALL",
    "PLACE_TORCH",
    "DRINK_POTION_RED",
    "DRINK_POTION_GREEN",
    "DRINK_POTION_BLUE",
    "DRINK_POTION_PINK",
    "DRINK_POTION_CYAN",
    "DRINK_POTION_YELLOW",
    "READ_BOOK",
    "ENCHANT_SWORD",
    "ENCHANT_ARMOUR",
    "MAKE_TORCH",
    "LEVEL_UP_DEXTERITY",
    "LEVEL_UP_STRENGTH",
    "LEVEL_UP_INTELLIGENCE",
    "ENCHANT_BOW",
)
"""Full Craftax `Action` names by id: Classic's 17, then its own."""

FULL_ACHIEVEMENTS: tuple[str, ...] = (
    "COLLECT_WOOD",
    "PLACE_TABLE",
    "EAT_COW",
    "COLLECT_SAPLING",
    "COLLECT_DRINK",
    "MAKE_WOOD_PICKAXE",
    "MAKE_WOOD_SWORD",
    "PLACE_PLANT",
    "DEFEAT_ZOMBIE",
    "COLLECT_STONE",
    "PLACE_STONE",
    "EAT_PLANT",
    "DEFEAT_SKELETON",
    "MAKE_STONE_PICKAXE",
    "MAKE_STONE_SWORD",
    "WAKE_UP",
    "PLACE_FURNACE",
    "COLLECT_COAL",
    "COLLECT_IRON",
    "COLLECT_DIAMOND",
    "MAKE_IRON_PICKAXE",
    "MAKE_IRON_SWORD",
    "MAKE_ARROW",
    "MAKE_TORCH",
    "PLACE_TORCH",
    "MAKE_DIAMOND_SWORD",
    "MAKE_IRON_ARMOUR",
    "MAKE_DIAMOND_ARMOUR",
    "ENTER_GNOMISH_MINES",
    "ENTER_DUNGEON",
    "ENTER_SEWERS",
    "ENTER_VAULT",
    "ENTER_TROLL_MINES",
    "ENTER_FIRE_REALM",
    "ENTER_ICE_REALM",
    "ENTER_GRAVEYARD",
    "DEFEAT_GNOME_WARRIOR",
    "DEFEAT_GNOME_ARCHER",
    "DEFEAT_ORC_SOLIDER",
    "DEFEAT_ORC_MAGE",
    "DEFEAT_LIZARD",
    "DEFEAT_KOBOLD",
    "DEFEAT_TROLL",
    "DEFEAT_DEEP_THING",
    "DEFEAT_PIGMAN",
    "DEFEAT_FIRE_ELEMENTAL",
    "DEFEAT_FROST_TROLL",
    "DEFEAT_ICE_ELEMENTAL",
    "DAMAGE_NECROMANCER",
    "DEFEAT_NECROMANCER",
    "EAT_BAT",
    "EAT_SNAIL",
    "FIND_BOW",
    "FIRE_BOW",
    "COLLECT_SAPPHIRE",
    "LEARN_FIREBALL",
    "CAST_FIREBALL",
    "LEARN_ICEBALL",
    "CAST_ICEBALL",
    "COLLECT_RUBY",
    "MAKE_DIAMOND_PICKAXE",
    "OPEN_CHEST",
    "DRINK_POTION",
    "ENCHANT_SWORD",
    "ENCHANT_ARMOUR",
    "DEFEAT_KNIGHT",
    "DEFEAT_ARCHER",
)
"""Full Craftax `Achievement` names by id (the enum's spelling, typo included)."""

NUM_CLASSIC_ACHIEVEMENTS = 22
CLASSIC_ACHIEVEMENTS: tuple[str, ...] = FULL_ACHIEVEMENTS[:NUM_CLASSIC_ACHIEVEMENTS]
"""Craftax-Classic `Achievement` names by id: the first 22 of full Craftax, same ids, same meaning."""

FULL_BLOCKS: tuple[str, ...] = (
    "INVALID",
    "OUT_OF_BOUNDS",
    "GRASS",
    "WATER",
    "STONE",
    "TREE",
    "WOOD",
    "PATH",
    "COAL",
    "IRON",
    "DIAMOND",
    "CRAFTING_TABLE",
    "FURNACE",
    "SAND",
    "LAVA",
    "PLANT",
    "RIPE_PLANT",
    "WALL",
    "DARKNESS",
    "WALL_MOSS",
    "STALAGMITE",
    "SAPPHIRE",
    "RUBY",
    "CHEST",
    "FOUNTAIN",
    "FIRE_GRASS",
    "ICE_GRASS",
    "GRAVEL",
    "FIRE_TREE",
    "ICE_SHRUB",
    "ENCHANTMENT_TABLE_FIRE",
    "ENCHANTMENT_TABLE_ICE",
    "NECROMANCER",
    "GRAVE",
    "GRAVE2",
    "GRAVE3",
    "NECROMANCER_VULNERABLE",
)
"""Full Craftax `BlockType` names by value."""

NUM_CLASSIC_BLOCKS = 17
CLASSIC_BLOCKS: tuple[str, ...] = FULL_BLOCKS[:NUM_CLASSIC_BLOCKS]
"""Craftax-Classic `BlockType` names by value: the first 17 of full Craftax, same values."""

FULL_ITEMS: tuple[str, ...] = (
    "NONE",
    "TORCH",
    "LADDER_DOWN",
    "LADDER_UP",
    "LADDER_DOWN_BLOCKED",
)
"""Full Craftax `ItemType` names by value (items lie on top of a block; Classic has none)."""

FULL_PROJECTILES: tuple[str, ...] = (
    "ARROW",
    "DAGGER",
    "FIREBALL",
    "ICEBALL",
    "ARROW2",
    "SLIMEBALL",
    "FIREBALL2",
    "ICEBALL2",
)
"""Full Craftax `ProjectileType` names by value."""

PASSIVE_MOBS: tuple[str, ...] = (
    "COW",
    "BAT",
    "SNAIL",
)
"""Full Craftax passive mobs by type id (craftax has no name enum for mobs: its
`MOB_ACHIEVEMENT_MAP` names them through their achievements)."""

MELEE_MOBS: tuple[str, ...] = (
    "ZOMBIE",
    "GNOME_WARRIOR",
    "ORC_SOLDIER",
    "LIZARD",
    "KNIGHT",
    "TROLL",
    "PIGMAN",
    "FROST_TROLL",
)
"""Full Craftax melee mobs by type id (`DEFEAT_ORC_SOLIDER` is the orc soldier's achievement)."""

RANGED_MOBS: tuple[str, ...] = (
    "SKELETON",
    "GNOME_ARCHER",
    "ORC_MAGE",
    "KOBOLD",
    "KNIGHT_ARCHER",
    "DEEP_THING",
    "FIRE_ELEMENTAL",
    "ICE_ELEMENTAL",
)
"""Full Craftax ranged mobs by type id (`DEFEAT_ARCHER` is the knight archer's achievement)."""

CLASSIC_MOBS: tuple[str, ...] = (
    "ZOMBIE",
    "COW",
    "SKELETON",
)
"""Craftax-Classic's creatures, one state field each (`zombies`, `cows`, `skeletons`)."""
