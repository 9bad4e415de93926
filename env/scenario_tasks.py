"""Goals of every kind as one fixed-shape task encoding the JAX checker reads (no JAX here).

A task is a kind index (`GOAL_KINDS` order, the official `Scenarios` order), the achievement
masks (used by `achievements` goals) and `NUM_PARAMS` int32 parameters whose meaning depends on
the kind (see `encode_goal`). A batch can then mix kinds: one row per episode.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict

from env.achievements import NUM_ACHIEVEMENTS
from env.errors import UserError
from env.goals import (
    CROSS_TYPES,
    GOAL_KINDS,
    SIDES,
    AnyGoal,
    BuildLineGoal,
    BuildSquareGoal,
    BuildStarGoal,
    ConditionalPlacingGoal,
    Goal,
    LocalizationGoal,
)
from env.variant import Variant

NUM_PARAMS = 4
KIND_INDEX = {kind: index for index, kind in enumerate(GOAL_KINDS)}
#: The inventory counts a conditional-placing goal can name, in the checker's order.
INVENTORY_SLOTS = ("wood", "stone", "coal", "iron", "diamond", "sapling", "ruby", "sapphire")
CLASSIC_INVENTORY_SLOTS = INVENTORY_SLOTS[:6]


class EncodedTasks(BaseModel):
    """A batch of goals as the checker's arrays, one row per goal."""

    model_config = ConfigDict(frozen=True, arbitrary_types_allowed=True)

    kind: np.ndarray
    """int32 (n,): index into `GOAL_KINDS`."""
    required: np.ndarray
    """bool (n, 22)."""
    forbidden: np.ndarray
    """bool (n, 22)."""
    params: np.ndarray
    """int32 (n, NUM_PARAMS)."""


def encode_goals(goals: Sequence[AnyGoal], variant: Variant) -> EncodedTasks:
    """The checker's arrays for `goals` in `variant`; a `UserError` names a goal it cannot score
    there (a block or an inventory item the variant lacks)."""
    kind = np.zeros(len(goals), np.int32)
    required = np.zeros((len(goals), NUM_ACHIEVEMENTS), bool)
    forbidden = np.zeros((len(goals), NUM_ACHIEVEMENTS), bool)
    params = np.zeros((len(goals), NUM_PARAMS), np.int32)
    for row, goal in enumerate(goals):
        kind[row] = KIND_INDEX[goal.kind]
        if isinstance(goal, Goal):
            required[row] = goal.required_mask()
            forbidden[row] = goal.forbidden_mask()
        else:
            params[row] = encode_goal(goal, variant)
    return EncodedTasks(kind=kind, required=required, forbidden=forbidden, params=params)


def encode_goal(goal: AnyGoal, variant: Variant) -> list[int]:
    """The int32 parameters of one goal that is not an achievements goal:

    - conditional placing: inventory slot (`INVENTORY_SLOTS`), count to collect, block, count
    - localization: placed block, target block, side (`SIDES`), distance
    - line: block, size, 1 if diagonal; square: block, size; star: block, size, cross code
    """

    def block(name: str) -> int:
        blocks = variant.block_names
        if name not in blocks:
            raise UserError(
                f"goal {goal.id!r} ({goal.split}) needs block {name}, which {variant.value} "
                "Craftax lacks"
            )
        return blocks.index(name)

    if isinstance(goal, ConditionalPlacingGoal):
        slots = CLASSIC_INVENTORY_SLOTS if variant is Variant.CLASSIC else INVENTORY_SLOTS
        if goal.collect not in slots:
            raise UserError(
                f"goal {goal.id!r} ({goal.split}) counts {goal.collect}, which {variant.value} "
                "Craftax has no inventory slot for"
            )
        return [
            slots.index(goal.collect),
            goal.collect_count,
            block(goal.place),
            goal.place_count,
        ]
    if isinstance(goal, LocalizationGoal):
        return [block(goal.place), block(goal.target), SIDES.index(goal.side), goal.distance]
    if isinstance(goal, BuildLineGoal):
        return [block(goal.block), goal.size, int(goal.diagonal), 0]
    if isinstance(goal, BuildSquareGoal):
        return [block(goal.block), goal.size, 0, 0]
    if isinstance(goal, BuildStarGoal):
        return [block(goal.block), goal.size, CROSS_TYPES.index(goal.cross), 0]
    raise UserError(f"goal {goal.id!r} of kind {goal.kind} has no checker")
