"""The official CrafText names the dataset modules use, as plain tables: where each split lives,
the official enums (craftext_constants at 1c518ae), the target-state records' fields, which checker
builds which goal kind, and the official loader's quirks the parser reproduces."""

from __future__ import annotations

from typing import Any

from env.craftax_names import FULL_BLOCKS
from env.goals import GOAL_KINDS, GoalKind, Split

# Where each split lives, relative to the `scenarious` package, under each spelling the released
# wheel and the official repository use ("parafrased", "paramets"). The official loader reads a
# missing name as an empty split (`hasattr`), so only the EASY ones must be there.
SPLIT_BINDINGS: dict[Split, tuple[str, tuple[str, ...]]] = {
    "easy_train": ("SMALL.instructions", ("easy",)),
    "easy_test_paraphrased": ("SMALL.test", ("easy_test_paraphrased",)),
    "easy_test_other_params": (
        "SMALL.test",
        ("easy_test_other_params", "easy_test_other_paramets"),
    ),
    "medium_train": ("SMALL.instructions", ("medium",)),
    "medium_test_paraphrased": (
        "SMALL.test",
        ("medium_test_parafrased", "medium_test_paraphrased"),
    ),
    "medium_test_other_params": (
        "SMALL.test",
        ("medium_test_other_paramets", "medium_test_other_params"),
    ),
    "hard_train": ("SMALL.instructions", ("hard",)),
    "hard_test_paraphrased": ("SMALL.test", ("hard_test_parafrased", "hard_test_paraphrased")),
    "hard_test_other_params": (
        "SMALL.test",
        ("hard_test_other_paramets", "hard_test_other_params"),
    ),
}
OFFICIAL_MISSING_INSTRUCTION = "Unknown instruction"
REQUIRED_SPLITS = ("easy_train", "easy_test_paraphrased", "easy_test_other_params")

# The official enums the goals name (craftext_constants at 1c518ae). BlockType is Craftax's own.
ENUMS: dict[str, dict[str, int]] = {
    "BlockType": {name: index for index, name in enumerate(FULL_BLOCKS)},
    "InventoryItems": {
        name: index
        for index, name in enumerate(
            [
                "WOOD",
                "STONE",
                "COAL",
                "IRON",
                "DIAMOND",
                "SAPLING",
                "WOOD_PICKAXE",
                "STONE_PICKAXE",
                "IRON_PICKAXE",
                "WOOD_SWORD",
                "STONE_SWORD",
                "IRON_SWORD",
            ]
        )
    },
    "MediumInventoryItems": {
        name: index
        for index, name in enumerate(
            [
                "WOOD",
                "STONE",
                "COAL",
                "IRON",
                "DIAMOND",
                "SAPLING",
                "PICKAXE",
                "SWORD",
                "BOW",
                "ARROWS",
                "ARMOUR",
                "TORCHES",
                "RUBY",
                "SAPPHIRE",
                "POTIONS",
                "BOOKS",
            ]
        )
    },
    "CrossType": {"STRAIGHT": 0, "DIAGONAL": 1, "COMBINED": 2},
    "Scenarios": {
        "CONDITIONAL_ACHIEVEMENTS": 0,
        "CONDITIONAL_PLACING": 1,
        "LOCALIZATION_PLACE": 2,
        "BUILD_LINE": 3,
        "BUILD_SQUARE": 4,
        "BUILD_STAR": 5,
        "TIME_CONSTRAINED_PLACEMENT": 6,
        "EXPLORE": 7,
    },
}
# The official checker's inventory lookup by enum code (`check_inventory`): codes 6-11, 14 and 15
# count diamonds, and lax.switch clamps codes past the end to the last branch.
COUNTED_ITEM = [
    "wood",
    "stone",
    "coal",
    "iron",
    "diamond",
    "sapling",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "diamond",
    "ruby",
    "sapphire",
    "diamond",
    "diamond",
]
# The target-state records' fields in constructor order (target_state.py), with their defaults.
STATE_FIELDS: dict[str, dict[str, Any]] = {
    "ConditionalPlacingState": {
        "object_inventory_enum": -1,
        "object_to_place": 0,
        "count_to_collect": 0,
        "count_to_stand": 1,
    },
    "LocalizaPlacingState": {
        "object_name": -1,
        "target_object_name": -1,
        "side": -1,
        "distance": 5,
    },
    "BuildLineState": {"block_type": 0, "size": 3, "radius": 3, "is_diagonal": False},
    "BuildSquareState": {"block_type": 0, "size": 3, "radius": 5},
    "BuildStarState": {"block_type": 0, "size": 3, "radius": 3, "cross_type": -1},
}
#: The official checkers the data uses, by `Scenarios` member: `GOAL_KINDS` is in the official
#: `Scenarios` order (the checker's kind index too, `env.scenario_tasks`); the later members
#: (time-constrained placement, explore) have no goal kind.
SCENARIO_KINDS: dict[str, GoalKind] = {
    name: GOAL_KINDS[code] for name, code in ENUMS["Scenarios"].items() if code < len(GOAL_KINDS)
}
STATE_KINDS: dict[str, GoalKind] = {
    "ConditionalPlacingState": "conditional_placing",
    "LocalizaPlacingState": "localization_placing",
    "BuildLineState": "build_line",
    "BuildSquareState": "build_square",
    "BuildStarState": "build_star",
}
SCENARIOS_PACKAGE = "craftext.dataset.scenarious"
# Where the `scenarious` package may sit below the given root: repository clone or unpacked
# wheel, the `craftext` package itself, `craftext/dataset`, or `scenarious` itself.
SCENARIOS_PREFIXES = ("craftext/dataset/scenarious", "dataset/scenarious", "scenarious", "")
TARGET_STATE_FUNCTION = "create_target_state"
ACHIEVEMENT_ENUM = "Achievement"

SPLIT_MODULE_FILES = ("SMALL/instructions.py", "SMALL/instructions/__init__.py", "SMALL/test.py")
