"""Craftax's drawn textures, kept in the user cache so that a new environment does not draw them again.

Craftax draws its textures the first time an installation renders a frame and saves them beside
the installed package. Full Craftax's take minutes of CPU on a small machine, and every new
virtualenv (a fresh clone, a CI job, a Ray runtime environment) starts without them.
`share_texture_caches` copies each file between the installation and
`<cache_root>/craftax-textures/<craftax and jax versions>/`, whichever side lacks it, before
craftax's renderer is imported.
"""

import bz2
import functools
import importlib.metadata
import importlib.util
from pathlib import Path

from env.downloads import atomic_write_bytes, cache_root

#: The texture files craftax writes, relative to the installed `craftax` package.
TEXTURE_FILES = (
    Path("craftax/assets/texture_cache.pbz2"),
    Path("craftax_classic/assets/texture_cache_classic.pbz2"),
)


def kept_textures_dir() -> Path:
    """Where the user cache keeps the texture files of the installed craftax and jax."""
    versions = (
        f"craftax-{importlib.metadata.version('craftax')}-jax-{importlib.metadata.version('jax')}"
    )
    return cache_root() / "craftax-textures" / versions


@functools.cache
def share_texture_caches() -> None:
    """Share the installed craftax's texture files with the user cache (`share_texture_files`),
    once per process."""
    spec = importlib.util.find_spec("craftax")
    if spec is not None and spec.submodule_search_locations:
        share_texture_files(Path(next(iter(spec.submodule_search_locations))), kept_textures_dir())


def share_texture_files(package: Path, kept: Path) -> None:
    """Copy each of `TEXTURE_FILES` under `package` to `kept`, or back, whichever side lacks it.
    A side that cannot be written is left as it is: craftax then draws, as without this."""
    for relative in TEXTURE_FILES:
        installed, copy = package / relative, kept / relative.name
        try:
            if copy.is_file() and not installed.is_file():
                atomic_write_bytes(installed, copy.read_bytes())
            elif installed.is_file() and not copy.is_file():
                drawn = installed.read_bytes()
                if _is_whole(drawn):
                    atomic_write_bytes(copy, drawn)
        except OSError:
            continue


def _is_whole(data: bytes) -> bool:
    """Craftax writes its file in place: one another process is still writing ends early."""
    try:
        bz2.decompress(data)
    except (EOFError, ValueError, OSError):
        return False
    return True
