"""JAX's persistent compilation cache, on by default.

Compiling full Craftax takes ~30 s on a small CPU; with the cache a second process loads the
compiled step in a second or two.
"""

import os
from pathlib import Path

import jax

from env.downloads import cache_root

#: A bound on the cache's size, far above what every variant's compiled steps take (a few
#: hundred MB). Any bound turns on the cache's file lock: without one JAX writes an entry in place
#: with no lock, so a second process compiling the same function (test workers, Ray workers) can
#: read a half-written executable, and deserializing it crashes that process.
MAX_CACHE_BYTES = 8 * 1024**3

_enabled_dir: Path | None = None


def enable_compilation_cache(directory: Path | None = None) -> Path:
    """Point JAX's persistent cache at `directory` (default: `JAX_COMPILATION_CACHE_DIR`, else
    `<cache_root>/jax`; the directory already enabled, when there is one). Idempotent."""
    global _enabled_dir
    if directory is None:
        if _enabled_dir is not None:
            # An env made after the caller chose a directory keeps that choice.
            return _enabled_dir
        from_env = os.environ.get("JAX_COMPILATION_CACHE_DIR")
        directory = Path(from_env) if from_env else cache_root() / "jax"
    if _enabled_dir == directory:
        return directory
    directory.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Every compile, the small eager ones too: on a GPU each of those takes a noticeable part of
    # a second, and a second process should compile nothing at all.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", MAX_CACHE_BYTES)
    _enabled_dir = directory
    return directory
