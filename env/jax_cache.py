"""JAX's persistent compilation cache, on by default.

Compiling full Craftax takes ~30 s on a small CPU; with the cache a second process loads the
compiled step in a second or two.
"""

import contextlib
import os
from pathlib import Path

import jax

from env.downloads import cache_root

#: A bound on the cache's size, far above what every variant's compiled steps take (a few
#: hundred MB). Any bound turns on the cache's file lock: without one JAX writes an entry in place
#: with no lock, so a second process compiling the same function (test workers, Ray workers) can
#: read a half-written executable, and deserializing it crashes that process.
MAX_CACHE_BYTES = 8 * 1024**3

# How JAX's cache names an entry's files (jax/_src/lru_cache.py): the compiled executable, and
# the last time it was read or written (nanoseconds, 8 bytes little-endian), which orders eviction.
_ENTRY_SUFFIX = "-cache"
_ACCESS_TIME_SUFFIX = "-atime"

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
    _date_undated_entries(directory)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Every compile, the small eager ones too: on a GPU each of those takes a noticeable part of
    # a second, and a second process should compile nothing at all.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", MAX_CACHE_BYTES)
    _enabled_dir = directory
    return directory


def _date_undated_entries(directory: Path) -> None:
    """Give every entry without an access-time file one, from the entry's modification time.
    A bounded cache reads every entry's access time before each write, and one missing makes
    every later write fail: entries written while the cache was unbounded (by earlier versions,
    or by JAX with only `JAX_COMPILATION_CACHE_DIR` set) have none, nor has an entry whose
    writer was killed between its two files."""
    for entry in directory.glob(f"*{_ENTRY_SUFFIX}"):
        dated = entry.with_name(entry.name.removesuffix(_ENTRY_SUFFIX) + _ACCESS_TIME_SUFFIX)
        # OSError: another process removed the entry, or the folder is read-only.
        if not dated.exists():
            with contextlib.suppress(OSError):
                dated.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
