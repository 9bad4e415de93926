"""Read access to the files of an official CrafText source: a directory (a clone or an unpacked
wheel, with its git commit) or a zip (a wheel, or a code host's archive of the repository)."""

from __future__ import annotations

import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol


class SourceFiles(Protocol):
    """Read access to the files of a directory or a wheel, by POSIX path relative to its root."""

    def read(self, relpath: str) -> bytes | None: ...

    def dist_info_metadata(self) -> bytes | None: ...

    def git_commit(self) -> str | None: ...


@dataclass
class DirectoryFiles:
    root: Path

    def read(self, relpath: str) -> bytes | None:
        path = self.root / relpath
        return path.read_bytes() if path.is_file() else None

    def dist_info_metadata(self) -> bytes | None:
        found = sorted(self.root.glob("craftext-*.dist-info/METADATA"))
        return found[0].read_bytes() if found else None

    def git_commit(self) -> str | None:
        git = self.root / ".git"
        if git.is_file():  # a worktree or submodule: `.git` names the real git directory
            pointer = git.read_text().strip().removeprefix("gitdir:").strip()
            git = (self.root / pointer).resolve()
        if not (git / "HEAD").is_file():
            return None
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref:"):
            return head
        ref = head.removeprefix("ref:").strip()
        common = (
            git / (git / "commondir").read_text().strip() if (git / "commondir").is_file() else git
        )
        for base in (git, common):
            if (base / ref).is_file():
                return (base / ref).read_text().strip()
            packed = base / "packed-refs"
            if packed.is_file():
                for line in packed.read_text().splitlines():
                    commit, _, name = line.partition(" ")
                    if name == ref:
                        return commit
        return None


@dataclass
class ZipFiles:
    """A wheel, or a code host's zip archive of a repository (its files under one top folder)."""

    archive: zipfile.ZipFile
    root: str = ""

    def read(self, relpath: str) -> bytes | None:
        try:
            info = self.archive.getinfo(self.root + relpath)
        except KeyError:
            return None
        # Only small source modules are read; a huge member is not a dataset module.
        if info.file_size > _MAX_MODULE_BYTES:
            return None
        return self.archive.read(info)

    def dist_info_metadata(self) -> bytes | None:
        names = sorted(
            name
            for name in self.archive.namelist()
            if re.fullmatch(r"craftext-[^/]+\.dist-info/METADATA", name)
        )
        return self.archive.read(names[0]) if names else None

    def git_commit(self) -> str | None:
        return None


_MAX_MODULE_BYTES = 16 << 20


def join_path(prefix: str, relpath: str) -> str:
    return f"{prefix}/{relpath}" if prefix else relpath
