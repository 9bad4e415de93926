"""Craftax's textures of one block size, drawn by craftax once and kept in the user cache
(`env/texture_cache.py`); the renderer built on them. That its frames are craftax's own is
checked against the Pixels env's observations in tests/test_observation_images.py."""

import functools
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from env import Variant
from env.texture_cache import kept_textures_dir, kept_textures_path, pixel_renderer, textures

# Classic at its Pixels env's size: the quickest textures to draw.
VARIANT, SIZE = Variant.CLASSIC, 7


def draw(variant: Variant = VARIANT, size: int = SIZE) -> dict[str, Any]:
    """`textures` without its once-per-process cache."""
    drawn: dict[str, Any] = textures.__wrapped__(variant, size)
    return drawn


@functools.cache
def craftax_drawing() -> dict[str, Any]:
    """What craftax's own `load_all_textures()` holds at `SIZE`."""
    from craftax.craftax_classic.constants import load_all_textures_given_size

    drawing: dict[str, Any] = load_all_textures_given_size(SIZE)
    return drawing


def assert_same_textures(got: dict[str, Any], expected: dict[str, Any]) -> None:
    assert got.keys() == expected.keys()
    for name, value in expected.items():
        for mine, theirs in zip(
            value if isinstance(value, list) else [value],
            got[name] if isinstance(got[name], list) else [got[name]],
            strict=True,
        ):
            assert np.asarray(mine).dtype == np.asarray(theirs).dtype, name
            assert np.array_equal(np.asarray(mine), np.asarray(theirs)), name


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("CRAFTEXT_LLM_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_textures_are_craftaxs_drawn_once_then_read_from_the_user_cache(cache: Path) -> None:
    drawn = draw()
    kept = kept_textures_path(VARIANT, SIZE)
    assert kept.is_relative_to(cache) and kept.is_file()
    assert_same_textures(drawn, craftax_drawing())
    assert_same_textures(pickle.loads(kept.read_bytes()), drawn)
    # A later process reads the kept file instead of drawing: what the file holds is returned.
    kept.write_bytes(pickle.dumps({"kept": np.arange(3)}))
    assert list(draw()) == ["kept"]
    # Each size is kept apart.
    assert not kept_textures_path(VARIANT, 16).exists()
    assert kept_textures_path(Variant.FULL, SIZE) != kept


def test_a_kept_file_cut_short_is_drawn_again(cache: Path) -> None:
    draw()
    kept = kept_textures_path(VARIANT, SIZE)
    whole = kept.read_bytes()
    kept.write_bytes(whole[: len(whole) // 2])
    assert_same_textures(draw(), craftax_drawing())
    assert kept.read_bytes() == whole


def test_a_cache_that_cannot_be_written_still_gets_textures(cache: Path) -> None:
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text("a file where the cache folder would be")
    assert_same_textures(draw(), craftax_drawing())
    assert cache.read_text() == "a file where the cache folder would be"


def test_kept_textures_are_keyed_by_the_installed_versions(cache: Path) -> None:
    import importlib.metadata

    craftax, jax = importlib.metadata.version("craftax"), importlib.metadata.version("jax")
    assert kept_textures_dir() == cache / "craftax-textures" / f"craftax-{craftax}-jax-{jax}"


def test_the_renderer_leaves_craftaxs_own_texture_loader_in_place(cache: Path) -> None:
    from craftax.craftax_classic import renderer

    loader = renderer.load_all_textures
    pixel_renderer(VARIANT, SIZE)
    assert renderer.load_all_textures is loader
    with pytest.raises(ValueError, match="only the full game"):
        pixel_renderer(VARIANT, SIZE, night_noise=False)
