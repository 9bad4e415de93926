"""Episode frames as files: a compact sprite sheet for the HTML pages, a GIF or MP4 to share."""

from __future__ import annotations

import io
import math
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from env.errors import UserError

#: Largest side of the sheet: the largest a WebP or JPEG may have, and comfortable for browsers.
_MAX_SIDE = 16383
#: Playback speed of exported animations (GIF delays are whole hundredths of a second).
FRAMES_PER_SECOND = 5


@dataclass(frozen=True)
class SpriteSheet:
    """An episode's distinct frames tiled into one 256-colour PNG image."""

    png: bytes
    """The sheet as a PNG file."""
    frame_width: int
    frame_height: int
    columns: int
    """Frames per row of the sheet."""
    index: list[int]
    """For each frame of the episode, the tile of the sheet that draws it."""

    @property
    def size_bytes(self) -> int:
        return len(self.png)


def sprite_sheet(frames: np.ndarray) -> SpriteSheet:
    """Tile `frames` (uint8, (n, height, width, 3)) into a sheet, each distinct frame once.

    Steps that change nothing on screen (a blocked move, an unparseable answer) repeat the
    previous frame, so each distinct frame is stored once. The sheet is reduced to 256 colours
    (as a GIF would be): on Craftax frames a sixth of the true-colour PNG and a fifth of
    lossless WebP, for a difference the eye does not see.
    """
    from PIL import Image

    count, height, width, _ = frames.shape
    slots: dict[bytes, int] = {}
    distinct: list[np.ndarray] = []
    index = []
    for frame in frames:
        slot = slots.setdefault(frame.tobytes(), len(distinct))
        if slot == len(distinct):
            distinct.append(frame)
        index.append(slot)
    square = math.ceil(math.sqrt(len(distinct) * height / width))
    columns = max(1, min(len(distinct), _MAX_SIDE // width, square))
    rows = -(-len(distinct) // columns)
    if rows * height > _MAX_SIDE:
        raise ValueError(f"{count} frames of {width}x{height} do not fit one sheet")
    sheet = np.zeros((rows * height, columns * width, 3), np.uint8)
    for slot, frame in enumerate(distinct):
        row, column = divmod(slot, columns)
        sheet[row * height : (row + 1) * height, column * width : (column + 1) * width] = frame
    # The palette comes from at most 16 of the frames, spread over the episode (the colours drift
    # with daylight), and is then applied to all: 3x faster than choosing it from every frame,
    # for an error of under one level in 255. Maximum coverage keeps a sheet of at most 256
    # colours exact (fast octree does not); no dithering: it would speckle the pixel art and
    # defeat the PNG compression.
    stride = max(1, len(distinct) // 16)
    sample = Image.fromarray(np.concatenate(distinct[::stride])).quantize(
        256, method=Image.Quantize.MAXCOVERAGE, dither=Image.Dither.NONE
    )
    buffer = io.BytesIO()
    Image.fromarray(sheet).quantize(palette=sample, dither=Image.Dither.NONE).save(buffer, "PNG")
    return SpriteSheet(
        png=buffer.getvalue(), frame_width=width, frame_height=height, columns=columns, index=index
    )


#: Exported frames are enlarged (by a whole factor) to at least this height.
_EXPORT_MIN_HEIGHT = 280


def export_animation(frames: np.ndarray, path: Path) -> Path:
    """Write `frames` as an animated GIF, or as an MP4 when `path` ends in `.mp4` (needs ffmpeg).

    Frames are enlarged by a whole factor without smoothing, so the pixel art stays sharp.
    """
    scale = max(1, -(-_EXPORT_MIN_HEIGHT // frames.shape[1]))
    frames = frames.repeat(scale, axis=1).repeat(scale, axis=2)
    suffix = path.suffix.lower()
    try:
        if suffix == ".mp4":
            _write_mp4(frames, path)
        elif suffix == ".gif":
            _write_gif(frames, path)
        else:
            raise UserError(f"cannot export {path.name}: give a .gif or .mp4 file name")
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror}") from exc
    return path


def _write_gif(frames: np.ndarray, path: Path) -> None:
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(
        path,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=round(1000 / FRAMES_PER_SECOND),
        loop=0,
        # Pillow merges identical consecutive frames into one longer frame: every step still
        # lasts the same time.
        optimize=False,
    )


def _write_mp4(frames: np.ndarray, path: Path) -> None:
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise UserError(
            "ffmpeg is not installed, so no MP4 can be written: give a .gif file name, "
            "or install ffmpeg (apt-get install ffmpeg)"
        )
    _, height, width, _ = frames.shape
    command = [
        ffmpeg,
        "-loglevel",
        "error",
        "-y",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{width}x{height}",
        "-r",
        str(FRAMES_PER_SECOND),
        "-i",
        "-",
        # yuv420p needs even sides; players expect it.
        "-vf",
        "pad=ceil(iw/2)*2:ceil(ih/2)*2",
        "-pix_fmt",
        "yuv420p",
        "-c:v",
        "libx264",
        str(path),
    ]
    completed = subprocess.run(command, input=frames.tobytes(), capture_output=True, check=False)
    if completed.returncode != 0:
        detail = completed.stderr.decode(errors="replace").strip().splitlines()
        raise UserError(f"ffmpeg could not write {path}: {detail[-1] if detail else 'failed'}")
