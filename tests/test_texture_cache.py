"""Craftax's texture files shared between an installation and the user cache
(`env/texture_cache.py`): a new virtualenv reuses the textures an older one drew."""

import bz2
import os
from pathlib import Path

import pytest

from env.texture_cache import TEXTURE_FILES, kept_textures_dir, share_texture_files

FULL, CLASSIC = TEXTURE_FILES


def write_textures(path: Path, payload: bytes) -> bytes:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = bz2.compress(payload)
    path.write_bytes(data)
    return data


def test_an_installation_without_textures_gets_the_kept_ones(tmp_path: Path) -> None:
    package, kept = tmp_path / "site" / "craftax", tmp_path / "cache"
    full = write_textures(kept / FULL.name, b"full textures")
    share_texture_files(package, kept)
    assert (package / FULL).read_bytes() == full
    # Nothing kept for Classic: the installation's craftax draws those itself.
    assert not (package / CLASSIC).exists()
    assert [p.name for p in (package / FULL).parent.iterdir()] == [FULL.name]


def test_textures_an_installation_drew_are_kept_for_the_next(tmp_path: Path) -> None:
    package, kept = tmp_path / "site" / "craftax", tmp_path / "cache"
    classic = write_textures(package / CLASSIC, b"classic textures" * 100)
    share_texture_files(package, kept)
    assert (kept / CLASSIC.name).read_bytes() == classic
    assert sorted(p.name for p in kept.iterdir()) == [CLASSIC.name]
    # A second installation gets them; the first is left as it was.
    other = tmp_path / "other-site" / "craftax"
    share_texture_files(other, kept)
    assert (other / CLASSIC).read_bytes() == classic == (package / CLASSIC).read_bytes()


def test_a_file_still_being_written_is_not_kept(tmp_path: Path) -> None:
    package, kept = tmp_path / "site" / "craftax", tmp_path / "cache"
    whole = write_textures(package / FULL, os.urandom(50_000))
    (package / FULL).write_bytes(whole[: len(whole) // 2])
    share_texture_files(package, kept)
    assert not (kept / FULL.name).exists()
    (package / FULL).write_bytes(whole)
    share_texture_files(package, kept)
    assert (kept / FULL.name).read_bytes() == whole


def test_kept_textures_are_never_overwritten(tmp_path: Path) -> None:
    package, kept = tmp_path / "site" / "craftax", tmp_path / "cache"
    mine = write_textures(kept / FULL.name, b"kept")
    write_textures(package / FULL, b"installed")
    share_texture_files(package, kept)
    assert (kept / FULL.name).read_bytes() == mine


def test_an_installation_that_cannot_be_written_is_left_as_it_is(tmp_path: Path) -> None:
    package, kept = tmp_path / "site" / "craftax", tmp_path / "cache"
    write_textures(kept / FULL.name, b"kept")
    classic = write_textures(kept / CLASSIC.name, b"classic")
    # Where full Craftax's textures go is a file, not a folder: no copy can be made there.
    (package / FULL).parent.parent.mkdir(parents=True)
    (package / FULL).parent.write_text("")
    share_texture_files(package, kept)
    assert (package / FULL).parent.is_file()
    # The other file is still shared.
    assert (package / CLASSIC).read_bytes() == classic


def test_kept_textures_are_keyed_by_the_installed_versions(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.metadata

    monkeypatch.setenv("CRAFTEXT_LLM_CACHE", str(tmp_path))
    craftax, jax = importlib.metadata.version("craftax"), importlib.metadata.version("jax")
    assert kept_textures_dir() == tmp_path / "craftax-textures" / f"craftax-{craftax}-jax-{jax}"
