"""The frames an image-seeing model is shown: Craftax's own pixel renderer, as its Pixels
environments draw for their agents, batched in JAX.

Each variant's Pixels env (`Craftax-Classic-Pixels-v1`, `Craftax-Pixels-v1`) renders with its
game's `BLOCK_PIXEL_SIZE_AGENT` (7 pixels per block for Classic, 10 for the full game) and
hands its agent `render / 255`; a frame here is that render rounded to uint8 RGB (the renderer
blends textures in floats: every value lies within half a level of the Pixels env's), the
most an 8-bit image (PNG) can carry of it.
The full game's night noise is drawn as its Pixels env draws it (from the state's own `state_rng`),
so a state always renders to the same frame.

The viewer's replays (`env.replay`) draw larger blocks for people; these frames are the model's.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from env.texture_cache import pixel_renderer
from env.variant import Variant

#: Map rows and columns a frame shows above the inventory, the player in the middle (craftax's
#: `OBS_DIM` of each game).
VIEW_CELLS = {Variant.FULL: (9, 11), Variant.CLASSIC: (7, 9)}
#: Pixels per block of each variant's Pixels environment (craftax's `BLOCK_PIXEL_SIZE_AGENT`).
AGENT_BLOCK_SIZES = {Variant.CLASSIC: 7, Variant.FULL: 10}


def frame_shape(variant: Variant) -> tuple[int, int, int]:
    """(height, width, 3) of a variant's frames: its Pixels env's observation shape."""
    rows, columns = VIEW_CELLS[variant]
    block = AGENT_BLOCK_SIZES[variant]
    # Below the map the inventory takes rows of the same blocks: 2 in Classic, 4 in the full game.
    inventory_rows = 2 if variant is Variant.CLASSIC else 4
    return ((rows + inventory_rows) * block, columns * block, 3)


class FrameRenderer:
    """Renders a batch of Craftax states (a leading axis) to uint8 frames with one compiled
    function per batch size. Create one per process and variant, and reuse it."""

    def __init__(self, variant: Variant):
        self.variant = variant
        render = pixel_renderer(variant, AGENT_BLOCK_SIZES[variant])

        def draw(game: Any) -> jax.Array:
            return jnp.clip(jnp.round(render(game)), 0, 255).astype(jnp.uint8)

        self._draw = jax.jit(jax.vmap(draw))

    def render(self, games: Any) -> np.ndarray:
        """uint8 (n, height, width, 3) frames of a batch of Craftax states (numpy or JAX
        leaves with a leading axis)."""
        return np.asarray(jax.device_get(self._draw(games)))


_RENDERERS: dict[Variant, FrameRenderer] = {}


def frame_renderer(variant: Variant) -> FrameRenderer:
    """The process's renderer of a variant (its compiled functions are kept)."""
    if variant not in _RENDERERS:
        _RENDERERS[variant] = FrameRenderer(variant)
    return _RENDERERS[variant]
