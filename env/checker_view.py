"""Where a placing or building goal's checker looks on a map, and which cells satisfied it.

`env.scenario_checker` answers yes or no, in JAX, for a batch; a report needs the why for one
state: the region searched and the cells that completed the goal. These numpy functions
recompute that from a map and the player's position, with the checker's own rules (its window
placement, size clamping, JAX's wrap-and-clamp neighbour reads), so what they mark is what the
checker counted.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from env.checker_geometry import (
    LOCAL_RADIUS,
    REACH,
    STAR_FILTER,
    WINDOW,
    WINDOW_RADIUS,
    square_offsets,
)

Cell = tuple[int, int]
"""A map cell: (row, column)."""


@dataclass(frozen=True)
class CheckerMarks:
    """What a checker looked at on one map, in map coordinates."""

    region: tuple[int, int, int, int]
    """First row, first column, rows, columns of the area the checker searched (it may reach
    past the map's edge, where the checker reads nothing)."""
    blocks: tuple[Cell, ...] = ()
    """Cells of the goal's block inside the region (for a localization goal, of the placed one)."""
    met: bool = False
    """Whether the checker is satisfied on this map."""
    completed: tuple[Cell, ...] = ()
    """Cells that satisfied the checker: empty when it was not satisfied (or, for a star read
    with arms of 0 blocks, satisfied by no cell at all)."""
    references: tuple[Cell, ...] = ()
    """Localization: the reference (target) blocks within reach."""
    targets: tuple[Cell, ...] = ()
    """Localization: where the placed block must stand, one per reference."""
    notes: tuple[str, ...] = field(default=())
    """Quirks of the official checker that this goal meets (a size checked as another, ...)."""


def _cells(mask: np.ndarray, row0: int, column0: int) -> tuple[Cell, ...]:
    return tuple((int(r) + row0, int(c) + column0) for r, c in np.argwhere(mask))


def _window_origin(shape: tuple[int, ...], position: Cell) -> Cell:
    """The window's first row and column as `jax.lax.dynamic_slice` places it: a negative start
    counts from the far end (near the top or left edge the window jumps to the bottom or right
    of the map), then the start is clamped so the whole window lies inside the map."""

    def start(wanted: int, size: int) -> int:
        return int(np.clip(wanted + size if wanted < 0 else wanted, 0, size - WINDOW))

    return start(position[0] - WINDOW_RADIUS, shape[0]), start(
        position[1] - WINDOW_RADIUS, shape[1]
    )


def _window_index(index: int) -> int:
    # What JAX reads at a neighbour index: a negative one wraps once, one past the end clamps.
    return index + WINDOW if index < 0 else min(index, WINDOW - 1)


def _first_run(
    window: np.ndarray, offsets: list[Cell], value: int
) -> tuple[tuple[Cell, ...], bool]:
    """The window cells of the first center (row-major) holding `value` at every offset."""
    for r in range(WINDOW):
        for c in range(WINDOW):
            cells = [(_window_index(r + dr), _window_index(c + dc)) for dr, dc in offsets]
            if all(window[cell] == value for cell in cells):
                return tuple(cells), True
    return (), False


def line_marks(
    board: np.ndarray, position: Cell, block: int, size: int, diagonal: bool
) -> CheckerMarks:
    """A `build_line` goal: the 21x21 window and the line that completed it."""
    row0, column0 = _window_origin(board.shape, position)
    window = (board[row0 : row0 + WINDOW, column0 : column0 + WINDOW] == block).astype(np.int32)
    length = int(np.clip(size, 2, REACH))
    notes = []
    if size > REACH:
        notes.append(f"the official checker looks for a line of {REACH}, not {size}")
    if length == 2:
        notes.append(
            "the official checker looks for a line of 2 as two empty cells, with no such block "
            "in the window (straight) or exactly 3 (diagonal)"
        )
    wanted = 0 if length == 2 else 1
    total = int(window.sum())
    expected = (3 if length == 2 else length) if diagonal else (0 if length == 2 else length)
    directions = [(1, 1), (1, -1)] if diagonal else [(1, 0), (0, 1)]
    completed: tuple[Cell, ...] = ()
    if total == expected:
        for dr, dc in directions:
            cells, found = _first_run(window, [(k * dr, k * dc) for k in range(length)], wanted)
            if found:
                completed = tuple((r + row0, c + column0) for r, c in cells)
                break
    return CheckerMarks(
        region=(row0, column0, WINDOW, WINDOW),
        blocks=_cells(window == 1, row0, column0),
        met=bool(completed),
        completed=completed,
        notes=tuple(notes),
    )


def square_marks(board: np.ndarray, position: Cell, block: int, size: int) -> CheckerMarks:
    """A `build_square` goal: the 21x21 window and the square (border clear) that completed it."""
    row0, column0 = _window_origin(board.shape, position)
    window = (board[row0 : row0 + WINDOW, column0 : column0 + WINDOW] == block).astype(np.int32)
    side = int(np.clip(size, 2, REACH))
    notes = (
        [f"the official checker looks for a square of {side}, not {size}"] if side != size else []
    )
    filled, ring = square_offsets(side)
    completed: tuple[Cell, ...] = ()
    for r in range(WINDOW):
        for c in range(WINDOW):
            solid = [(_window_index(r + dr), _window_index(c + dc)) for dr, dc in filled]
            clear = [(_window_index(r + dr), _window_index(c + dc)) for dr, dc in ring]
            if all(window[cell] == 1 for cell in solid) and all(
                window[cell] == 0 for cell in clear
            ):
                completed = tuple((a + row0, b + column0) for a, b in solid)
                break
        if completed:
            break
    return CheckerMarks(
        region=(row0, column0, WINDOW, WINDOW),
        blocks=_cells(window == 1, row0, column0),
        met=bool(completed),
        completed=completed,
        notes=tuple(notes),
    )


#: Row and column steps of each side code (`env.goals.SIDES` order: right, left, up, down).
SIDE_STEPS: dict[str, Cell] = {"right": (0, 1), "left": (0, -1), "up": (-1, 0), "down": (1, 0)}


def localization_marks(
    board: np.ndarray, position: Cell, placed: int, target: int, side: str, distance: int
) -> CheckerMarks:
    """A `localization_placing` goal: the 11x11 area around the player, each reference block in
    it with the cell the placed block must take, and the pair that satisfied the checker."""
    row0, column0 = position[0] - LOCAL_RADIUS, position[1] - LOCAL_RADIUS
    size = 2 * LOCAL_RADIUS + 1

    def inside(cell: Cell) -> bool:
        return (
            row0 <= cell[0] < row0 + size
            and column0 <= cell[1] < column0 + size
            and 0 <= cell[0] < board.shape[0]
            and 0 <= cell[1] < board.shape[1]
        )

    area = [(r, c) for r in range(row0, row0 + size) for c in range(column0, column0 + size)]
    dr, dc = SIDE_STEPS[side]
    references: list[Cell] = []
    targets: list[Cell] = []
    completed: list[Cell] = []
    blocks: list[Cell] = []
    for cell in filter(inside, area):
        if board[cell] == placed:
            blocks.append(cell)
        if board[cell] == target:
            wanted = (cell[0] + dr * distance, cell[1] + dc * distance)
            references.append(cell)
            targets.append(wanted)
            if not completed and inside(wanted) and board[wanted] == placed:
                completed = [cell, wanted]
    return CheckerMarks(
        region=(row0, column0, size, size),
        blocks=tuple(blocks),
        met=bool(completed),
        completed=tuple(completed),
        references=tuple(references),
        targets=tuple(targets),
    )


def star_marks(
    board: np.ndarray, position: Cell, block: int, size: int, cross: str
) -> CheckerMarks:
    """A `build_star` goal, as the official call checks it (its arguments out of order: the
    cross's arm is the cross-type code, the search radius the goal's size): the searched area
    and the blocks of the first cross found."""
    arm = ("straight", "diagonal", "combined").index(cross)
    radius = min(size, WINDOW_RADIUS)
    row0, column0 = position[0] - radius, position[1] - radius
    found = np.zeros((WINDOW, WINDOW), np.int32)
    blocks = []
    for r in range(-radius, radius + 1):
        for c in range(-radius, radius + 1):
            cell = (position[0] + r, position[1] + c)
            if (
                0 <= cell[0] < board.shape[0]
                and 0 <= cell[1] < board.shape[1]
                and board[cell] == block
            ):
                found[r + WINDOW_RADIUS, c + WINDOW_RADIUS] = 1
                blocks.append(cell)
    notes = [
        f"the official checker reads this {cross} star as arms of {arm} block(s) within "
        f"{size} cells of the player (its arguments are passed out of order)"
    ]
    centre = STAR_FILTER // 2
    first = centre - arm // 2
    taps = [k for k in range(STAR_FILTER) if first <= k < first + arm]
    outputs = WINDOW - STAR_FILTER + 1
    completed: tuple[Cell, ...] = ()
    for r, c in itertools.product(range(outputs), range(outputs)) if arm else ():
        across = [(r + centre, c + k) for k in taps]
        down = [(r + k, c + centre) for k in taps]
        main = [(r + k, c + k) for k in taps]
        anti = [(r + k, c + STAR_FILTER - 1 - k) for k in taps if STAR_FILTER - 1 - k in taps]
        for arms in ((across, down), (main, anti)):
            if all(sum(int(found[cell]) for cell in cells) == arm for cells in arms):
                shift = (position[0] - WINDOW_RADIUS, position[1] - WINDOW_RADIUS)
                completed = tuple(
                    sorted({(a + shift[0], b + shift[1]) for cells in arms for a, b in cells})
                )
                break
        if completed:
            break
    if arm == 0:
        notes.append("an arm of 0 blocks: the official checker is met on any map")
    return CheckerMarks(
        region=(row0, column0, 2 * radius + 1, 2 * radius + 1),
        blocks=tuple(blocks),
        met=bool(completed) or arm == 0,
        completed=completed,
        notes=tuple(notes),
    )
