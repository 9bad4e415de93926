"""Craftax's pixel renderer, given the textures of the one block size it draws, kept per size in
the user cache.

Craftax's renderer takes its textures from `load_all_textures()`, which draws every size craftax
knows the first time an installation renders and keeps them in one bz2 pickle beside the
installed package: for the full game 300 MB of arrays, 279 MB of them the 64-pixel textures of
craftax's play window, which nothing here draws. On a 2-core machine drawing them took about
half a minute of CPU (25 s of it the 64-pixel night-noise texture, built one pixel at a time),
compressing them longer, and every later process spent seconds decompressing them again before
its first frame. `pixel_renderer` hands craftax's renderer the textures of its own block size
instead: drawn by craftax's own `load_all_textures_given_size`, once per machine, and kept as a
plain pickle in `<cache_root>/craftax-textures/<craftax and jax versions>/` (7 MB for the full
game at 10 pixels, read back in a fraction of a second).
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import importlib.metadata
import pickle
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from env.downloads import atomic_write_bytes, cache_root
from env.variant import Variant

#: The craftax package of each variant's game (its `constants` and `renderer` modules).
CRAFTAX_PACKAGES = {Variant.FULL: "craftax.craftax", Variant.CLASSIC: "craftax.craftax_classic"}

# Building a renderer swaps a module attribute of craftax for a moment: one build at a time.
_BUILDING = threading.Lock()


def kept_textures_dir() -> Path:
    """Where the user cache keeps the textures of the installed craftax and jax."""
    versions = (
        f"craftax-{importlib.metadata.version('craftax')}-jax-{importlib.metadata.version('jax')}"
    )
    return cache_root() / "craftax-textures" / versions


def kept_textures_path(variant: Variant, block_size: int) -> Path:
    """The file that keeps a variant's textures at `block_size` pixels per block."""
    return kept_textures_dir() / f"{CRAFTAX_PACKAGES[variant].replace('.', '-')}-{block_size}.pkl"


@functools.cache
def textures(variant: Variant, block_size: int) -> dict[str, Any]:
    """Craftax's textures of a variant at `block_size` (what its `load_all_textures()` holds at
    that size): the kept copy, else drawn by craftax and kept. A kept file that cannot be read
    (another version's, cut short) is drawn again; a cache that cannot be written is left as it
    is. Once per process."""
    path = kept_textures_path(variant, block_size)
    try:
        kept: dict[str, Any] = pickle.loads(path.read_bytes())
        return kept
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
        pass
    constants = importlib.import_module(f"{CRAFTAX_PACKAGES[variant]}.constants")
    drawn: dict[str, Any] = constants.load_all_textures_given_size(block_size)
    with contextlib.suppress(OSError):
        atomic_write_bytes(path, pickle.dumps(drawn, protocol=pickle.HIGHEST_PROTOCOL))
    return drawn


def pixel_renderer(
    variant: Variant, block_size: int, *, night_noise: bool = True
) -> Callable[[Any], Any]:
    """Craftax's `make_craftax_pixel_renderer(block_size)` of the variant's game, drawing with
    `textures(variant, block_size)`. `night_noise=False` (the full game only: Classic's renderer
    has no such option) draws night as an even darkening instead of random static."""
    if not night_noise and variant is not Variant.FULL:
        raise ValueError("only the full game's renderer can draw night without its noise")
    drawn = textures(variant, block_size)
    renderer: Any = importlib.import_module(f"{CRAFTAX_PACKAGES[variant]}.renderer")
    options = {} if variant is Variant.CLASSIC else {"do_night_noise": night_noise}
    # The renderer reads its textures from `load_all_textures()` once, when it is made.
    with _BUILDING:
        craftax_loader = renderer.load_all_textures
        renderer.load_all_textures = lambda: {block_size: drawn}
        try:
            render: Callable[[Any], Any] = renderer.make_craftax_pixel_renderer(
                block_size, **options
            )
        finally:
            renderer.load_all_textures = craftax_loader
    return render
