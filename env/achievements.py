"""The 22 achievements CrafText goals are written in.

Craftax-Classic has exactly these, with these ids; full Craftax has 67 and its first 22 are the
same ids with the same meaning, so one checker serves both variants.
"""

from env.errors import UserError

ACHIEVEMENTS: tuple[str, ...] = (
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
)
NUM_ACHIEVEMENTS = len(ACHIEVEMENTS)
ACHIEVEMENT_IDS: dict[str, int] = {name: i for i, name in enumerate(ACHIEVEMENTS)}


def achievement_id(name: str) -> int:
    """The id of an achievement name such as `COLLECT_WOOD` (case-insensitive)."""
    key = name.strip().upper()
    if key not in ACHIEVEMENT_IDS:
        raise UserError(f"unknown achievement {name!r}; known: {', '.join(ACHIEVEMENTS)}")
    return ACHIEVEMENT_IDS[key]
