"""Observation -> text, by style name."""

from collections.abc import Callable

from env.errors import UserError
from textualizer.observation import Observation
from textualizer.render_grid import render_grid
from textualizer.render_objects import render_objects
from textualizer.render_table import render_table

_RENDERERS: dict[str, Callable[[Observation], str]] = {
    "objects": render_objects,
    "grid": render_grid,
    "table": render_table,
}
RENDERERS: tuple[str, ...] = tuple(_RENDERERS)
"""Style names `render` accepts; the first is the default."""


def render(obs: Observation, style: str = "objects") -> str:
    """The observation as text in the named style (`objects`, `grid` or `table`)."""
    if style not in _RENDERERS:
        raise UserError(f"unknown observation style {style!r}; styles: {', '.join(RENDERERS)}")
    return _RENDERERS[style](obs)
