"""Reading the official CrafText dataset modules without importing or executing them: the entry
points (`parse_wheel`, `parse_archive`, `parse_directory`, `parsing_notes`) over the rooms that do
the work.

The EASY modules build each goal's target through calls such as
`create_target_state(required=[Achievement.X, ...], forbidden=[...])` inside dict literals that
also hold the instruction and its paraphrases; splits are module-level dicts built from such
literals, `**other_module.name` spreads and `|` merges. `env.official_files` reads a source's
files, `env.official_ast` evaluates exactly that subset of Python with `ast` (the modules import
JAX at module level, so importing them is not an option), `env.official_tables` holds the official
names and quirks, and `env.official_goals` builds the typed `Dataset` records (`env.goals`).
`env.dataset.load_dataset` is the entry point.
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

from env.downloads import sha256_file
from env.errors import UserError
from env.goals import AnyGoal, Dataset, DatasetSource, SourceKind, checked_dataset
from env.official_ast import SourceTree
from env.official_files import DirectoryFiles, SourceFiles, ZipFiles, join_path
from env.official_goals import split_goals
from env.official_tables import (
    SCENARIOS_PACKAGE,
    SCENARIOS_PREFIXES,
    SPLIT_BINDINGS,
    SPLIT_MODULE_FILES,
)


def parse_wheel(wheel: Path) -> Dataset:
    try:
        with zipfile.ZipFile(wheel) as archive:
            dataset = _parse_tree(ZipFiles(archive), kind="wheel", label=wheel)
    except zipfile.BadZipFile:
        raise UserError(f"{wheel} is not a valid wheel (zip) file") from None
    return checked_dataset(
        dataset.source.model_copy(update={"sha256": sha256_file(wheel)}), dataset.goals
    )


def parse_archive(archive: Path, url: str, commit: str) -> Dataset:
    """Parse a code host's zip archive of the official repository at `commit`, downloaded from
    `url`. The parsed modules' digest equals that of a clone of the same commit."""
    try:
        with zipfile.ZipFile(archive) as opened:
            tops = {name.split("/", 1)[0] for name in opened.namelist()}
            root = f"{tops.pop()}/" if len(tops) == 1 else ""
            dataset = _parse_tree(ZipFiles(opened, root), kind="archive", label=url)
    except zipfile.BadZipFile:
        raise UserError(f"{url} is not a valid zip archive") from None
    return checked_dataset(
        dataset.source.model_copy(update={"path": url, "version": commit}), dataset.goals
    )


def _open_tree(files: SourceFiles, label: str | Path) -> SourceTree:
    prefix = next(
        (
            candidate
            for candidate in SCENARIOS_PREFIXES
            if any(
                files.read(join_path(candidate, name)) is not None for name in SPLIT_MODULE_FILES
            )
        ),
        None,
    )
    if prefix is None:
        raise UserError(
            f"no CrafText dataset modules in {label}: expected "
            f"craftext/dataset/scenarious/SMALL/instructions.py (a clone of the official CrafText "
            "repository or an unpacked craftext wheel)"
        )
    return SourceTree(files, prefix, label)


def _parse_tree(files: SourceFiles, kind: SourceKind, label: str | Path) -> Dataset:
    tree = _open_tree(files, label)
    goals: list[AnyGoal] = []
    for split, (module_name, variables) in SPLIT_BINDINGS.items():
        goals.extend(split_goals(tree, split, module_name, variables))
    metadata = files.dist_info_metadata()
    version_match = re.search(rb"^Version:\s*(\S+)", metadata or b"", flags=re.MULTILINE)
    version = version_match.group(1).decode() if version_match else files.git_commit()
    source = DatasetSource(kind=kind, path=str(label), version=version, sha256=tree.digest())
    return checked_dataset(source, goals)


def parse_directory(path: Path) -> Dataset:
    """Parse a clone of the official repository or an unpacked `craftext` wheel."""
    return _parse_tree(DirectoryFiles(path), kind="directory", label=path)


def parsing_notes(path: Path) -> list[str]:
    """Where the dataset modules of a clone or unpacked wheel replace a goal by another of the
    same key (a repeated key in a dict literal, or a later `**spread`): the official loader,
    like this parser, keeps the key's first position and the last value."""
    tree = _open_tree(DirectoryFiles(path), path)
    for module_name, variables in SPLIT_BINDINGS.values():
        module = tree.module(f"{SCENARIOS_PACKAGE}.{module_name}", str(path))
        for variable in variables:
            if variable in module.bindings:
                module.lookup(variable, module.display)
    return list(dict.fromkeys(tree.notes))
