"""How far the official placing and building checkers look, as plain numbers: the windows around
the player and the shapes they search. The JAX checker (`env.scenario_checker`), its numpy view
(`env.checker_view`) and the scripted expert read them here, so they cannot drift apart."""

#: Line and square checks: a (2 * WINDOW_RADIUS + 1)-cell square window around the player; the
#: expert keeps other blocks of a line's kind farther than this.
WINDOW_RADIUS = 10
WINDOW = 2 * WINDOW_RADIUS + 1
#: Localization checks: both blocks within LOCAL_RADIUS tiles (Chebyshev) of the player.
LOCAL_RADIUS = 5
LOCAL = 2 * LOCAL_RADIUS + 1
#: The star check's filter width (its longest arm and centre).
STAR_FILTER = 7
REACH = 4
"""The farthest neighbour offset any line or square looks at, in rows or columns."""


def square_offsets(side: int) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """The filled cells and the border ring of a square of `side`, relative to the checked
    center (the top-left cell for even sides, the middle for 3)."""
    first = -1 if side == 3 else 0
    filled = [(r, c) for r in range(first, first + side) for c in range(first, first + side)]
    ring = [
        (r, c)
        for r in range(first - 1, first + side + 1)
        for c in range(first - 1, first + side + 1)
        if (r, c) not in filled
    ]
    return filled, ring
