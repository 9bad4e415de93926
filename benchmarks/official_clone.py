"""The official CrafText repository at 1c518ae for the benchmarks: unpacked once from the
reference archive in `../shared/data`, when the checkout has one beside it."""

from __future__ import annotations

import zipfile
from pathlib import Path

OFFICIAL_ARCHIVE = (
    Path(__file__).resolve().parents[2] / "shared" / "data" / "craftext_official_1c518ae.zip"
)


def official_clone(out: Path) -> str | None:
    """The unpacked repository's root, under `out/official` (unpacked on first use); None when
    there is no reference archive (the CLI's default data is used then)."""
    if not OFFICIAL_ARCHIVE.exists():
        return None
    target = out / "official"
    if not target.exists():
        with zipfile.ZipFile(OFFICIAL_ARCHIVE) as archive:
            archive.extractall(target)
    [root] = [p for p in target.iterdir() if p.is_dir()]
    return str(root)
