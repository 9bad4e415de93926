"""`env.checker_view` marks what the JAX checker counted: on random maps with planted shapes,
a goal has completing cells exactly when `env.scenario_checker` says it is met."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from env.checker_view import line_marks, localization_marks, square_marks, star_marks
from env.goals import CROSS_TYPES, SIDES
from env.scenario_checker import _line, _localization, _square, _star
from env.variant import Variant

SIZE = 40
BLOCK, OTHER = 3, 5


class Game(NamedTuple):
    map: Any
    player_position: Any


def _checked(check: Any) -> Any:
    return jax.jit(
        lambda board, position, params: check(Game(board, position), params, Variant.CLASSIC)
    )


def _world(rng: np.random.Generator, shape: str) -> tuple[np.ndarray, tuple[int, int], int]:
    """A map of scattered blocks with, often, a shape planted near the player."""
    board = rng.choice([1, 2, OTHER, BLOCK], size=(SIZE, SIZE), p=[0.6, 0.3, 0.07, 0.03])
    position = (int(rng.integers(0, SIZE)), int(rng.integers(0, SIZE)))
    length = int(rng.integers(2, 5))
    if shape != "none":
        row, column = int(rng.integers(3, SIZE - 6)), int(rng.integers(6, SIZE - 6))
        # No other block of the kind where the window can reach: lines need an exact count.
        around = board[max(0, row - 17) : row + 17, max(0, column - 17) : column + 17]
        around[around == BLOCK] = 1
        for k in range(length):
            if shape == "line":
                board[row + k, column] = BLOCK
            elif shape == "diagonal":
                board[row + k, column - k] = BLOCK
            else:
                board[row : row + length, column : column + length] = BLOCK
        position = (
            int(np.clip(row + rng.integers(-6, 7), 0, SIZE - 1)),
            int(np.clip(column + rng.integers(-6, 7), 0, SIZE - 1)),
        )
    return board, position, length


@pytest.mark.parametrize("kind", ["line", "square", "localization", "star"])
def test_marks_complete_exactly_when_the_checker_is_met(kind: str) -> None:
    rng = np.random.default_rng(7)
    check = _checked(
        {"line": _line, "square": _square, "localization": _localization, "star": _star}[kind]
    )
    met = 0
    for case in range(150):
        shape = ["none", "line", "diagonal", "square"][case % 4]
        board, position, length = _world(rng, shape)
        size = length if case % 3 else int(rng.integers(2, 6))
        if kind == "line":
            diagonal = shape == "diagonal" if case % 5 else bool(case % 2)
            params = [BLOCK, size, int(diagonal), 0]
            marks = line_marks(board, position, BLOCK, size, diagonal)
        elif kind == "square":
            params = [BLOCK, size, 0, 0]
            marks = square_marks(board, position, BLOCK, size)
        elif kind == "localization":
            side = int(rng.integers(0, 4))
            distance = int(rng.integers(0, 4))
            params = [BLOCK, OTHER, side, distance]
            marks = localization_marks(board, position, BLOCK, OTHER, SIDES[side], distance)
        else:
            cross = int(rng.integers(0, 3))
            params = [BLOCK, size, cross, 0]
            marks = star_marks(board, position, BLOCK, size, CROSS_TYPES[cross])
        truth = bool(check(jnp.asarray(board), jnp.asarray(position), jnp.asarray(params)))
        assert marks.met == truth, (case, shape, params, position)
        # A star read with arms of 0 blocks is met by no cell at all.
        unbuilt = kind == "star" and params[2] == 0
        assert bool(marks.completed) == (truth and not unbuilt)
        met += truth
        for cell in marks.completed:
            if kind != "line" or size > 2:  # a line of 2 is two empty cells
                assert board[cell] in (BLOCK, OTHER)
    assert 10 < met < 140  # both outcomes are exercised
