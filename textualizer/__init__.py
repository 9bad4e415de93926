"""numpy Craftax state -> typed `Observation` -> text (`objects`, `grid`, `table`)."""

from textualizer.observation import Mob, Observation, Offset
from textualizer.observe import observe, observe_batch
from textualizer.render import RENDERERS, render

__all__ = ["RENDERERS", "Mob", "Observation", "Offset", "observe", "observe_batch", "render"]
