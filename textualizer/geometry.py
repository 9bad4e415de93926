"""Words for offsets in the textualizer's convention (+dx right/east, +dy up/north)."""

from textualizer.observation import Offset


def steps(offset: Offset) -> int:
    """Moves needed to walk onto the tile (Manhattan distance, no diagonal moves)."""
    return abs(offset[0]) + abs(offset[1])


def compass(offset: Offset) -> str:
    """`N`, `NE`, ... `NW` for an offset; `N` is up (the UP action), `E` is right."""
    dx, dy = offset
    vertical = "N" if dy > 0 else "S" if dy < 0 else ""
    horizontal = "E" if dx > 0 else "W" if dx < 0 else ""
    return vertical + horizontal or "here"


def signed(value: int) -> str:
    """`+2`, `0`, `-1`: the sign always shown so offsets read unambiguously."""
    return f"{value:+d}" if value else "0"


def format_offset(offset: Offset) -> str:
    """`(2,-1)`: compact, because offsets are most of the `objects` text."""
    return f"({offset[0]},{offset[1]})"


def number(value: float) -> str:
    """`9` for whole values, `8.5` otherwise (health is fractional in full Craftax)."""
    return f"{value:g}" if value == int(value) else f"{value:.1f}"
