"""How an episode page shows each goal kind: its parameters in words and what its checker reads.

One `GoalRendering` per kind in `RENDERINGS`; `rendering_of` refuses a kind without one, so a
new kind in `env.goals` cannot reach a page unrendered (a test holds the registry to
`env.goals.GOAL_KINDS`). The words follow the official checkers as `env.scenario_checker`
reproduces them; the marks on the map come from `env.checker_view`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from env.checker_view import (
    CheckerMarks,
    line_marks,
    localization_marks,
    square_marks,
    star_marks,
)
from env.errors import UserError
from env.goals import GOAL_KINDS
from env.variant import Variant

Cell = tuple[int, int]


def block_words(name: str, count: int = 1) -> str:
    """`CRAFTING_TABLE` as `crafting table`, or `crafting tables` for a count other than one."""
    words = name.lower().replace("_", " ")
    if count == 1:
        return words
    return words + ("es" if words.endswith(("s", "sh", "ch", "x")) else "s")


def _numbered(count: int, name: str) -> str:
    return f"{count} {block_words(name, count)}"


def _achievements(goal: Any) -> str:
    def names(items: Sequence[str]) -> str:
        return ", ".join(item.lower().replace("_", " ") for item in items)

    words = f"reach {names(goal.required)}"
    return words + (f"; never {names(goal.forbidden)}" if goal.forbidden else "")


def _conditional(goal: Any) -> str:
    return (
        f"hold {goal.collect_count} {goal.collect}, then place "
        f"{_numbered(goal.place_count, goal.place)} (the checker fires on the step the "
        f"{goal.collect} count falls from {goal.collect_count} or more to fewer, while "
        f"{goal.place_count} or more {block_words(goal.place, 2)} stand on the map)"
    )


_SIDE_WORDS = {"right": "right of", "left": "left of", "up": "above", "down": "below"}


def _localization(goal: Any) -> str:
    cells = "cell" if goal.distance == 1 else "cells"
    return (
        f"a {block_words(goal.place)} {goal.distance} {cells} {_SIDE_WORDS[goal.side]} a "
        f"{block_words(goal.target)}, both within 5 cells of the player"
    )


def _line(goal: Any) -> str:
    shape = "diagonal" if goal.diagonal else "straight"
    return f"a {shape} line of {_numbered(goal.size, goal.block)}"


def _square(goal: Any) -> str:
    return (
        f"a filled {goal.size}x{goal.size} square of {block_words(goal.block, 2)}, "
        f"no {block_words(goal.block)} on its border"
    )


def _star(goal: Any) -> str:
    return f"a {goal.cross} cross (star) of {block_words(goal.block, 2)} with arms of {goal.size}"


Marker = Callable[[Any, np.ndarray, Cell, Variant], CheckerMarks | None]


def _block(variant: Variant, name: str) -> int:
    return variant.block_names.index(name)


def _no_marks(goal: Any, board: np.ndarray, position: Cell, variant: Variant) -> None:
    return None


@dataclass(frozen=True)
class GoalRendering:
    """How one goal kind is shown."""

    describe: Callable[[Any], str]
    """The goal's typed parameters in words (a dataset goal or a model's reading of one)."""
    marks: Marker
    """What the checker looked at on the episode's last map (None: nothing on the map)."""
    chart: bool = False
    """Whether the page charts the tracked inventory count over the episode."""


RENDERINGS: dict[str, GoalRendering] = {
    "achievements": GoalRendering(_achievements, _no_marks),
    "conditional_placing": GoalRendering(_conditional, _no_marks, chart=True),
    "localization_placing": GoalRendering(
        _localization,
        lambda goal, board, position, variant: localization_marks(
            board,
            position,
            _block(variant, goal.place),
            _block(variant, goal.target),
            goal.side,
            goal.distance,
        ),
    ),
    "build_line": GoalRendering(
        _line,
        lambda goal, board, position, variant: line_marks(
            board, position, _block(variant, goal.block), goal.size, goal.diagonal
        ),
    ),
    "build_square": GoalRendering(
        _square,
        lambda goal, board, position, variant: square_marks(
            board, position, _block(variant, goal.block), goal.size
        ),
    ),
    "build_star": GoalRendering(
        _star,
        lambda goal, board, position, variant: star_marks(
            board, position, _block(variant, goal.block), goal.size, goal.cross
        ),
    ),
}


def rendering_of(kind: str) -> GoalRendering:
    """The rendering of a goal kind; a `UserError` for a kind the viewer does not know."""
    if kind not in RENDERINGS:
        raise UserError(
            f"the viewer cannot show goals of kind {kind!r}; it knows {', '.join(RENDERINGS)}"
        )
    return RENDERINGS[kind]


def unrendered_kinds() -> list[str]:
    """Goal kinds of `env.goals` without a rendering (none, unless one was added there only)."""
    return [kind for kind in GOAL_KINDS if kind not in RENDERINGS]
