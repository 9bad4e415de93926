"""`plan-score` and `plan --candidates`: plan steps read into skills, plans played in the real
env and scored by the real checkers, the files they write, and every bad input refused with one
line, exit 2 and nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from env.dataset import Dataset, DatasetSource, Goal
from env.variant import Variant
from llm_agents.agents.skills.catalogue import skill_offer
from llm_agents.cli import main
from llm_agents.planning.checks import PlanLimits
from llm_agents.planning.export import numbered
from llm_agents.planning.loop import planner_messages
from llm_agents.planning.steps import read_plan, read_step

EASY = skill_offer(Variant.CLASSIC, "easy")
MEDIUM = skill_offer(Variant.CLASSIC, "medium")

TABLE = "Build a crafting table."
PICKAXE = "Make a wooden pickaxe."
COMPLETE_TABLE = "1. Collect wood 4.\n2. Place crafting table."
NO_WOOD_TABLE = "1. Approach tree.\n2. Place crafting table."
NO_PICKAXE = "1. Collect some stone.\n2. Place crafting table."


@pytest.mark.parametrize(
    ("step", "skills"),
    [
        ("Approach furnace", ("go to furnace",)),
        ("Collect some wood", ("collect wood",)),
        ("Navigate to smelter", ("go to furnace",)),
        ("Deposit rock on ground", ("place stone",)),
        ("Chop tree for wood", ("collect wood",)),
        ("Gather coal and iron", ("collect coal", "collect iron")),
        ("Craft two furnaces", ("place furnace", "place furnace")),
        ("Collect four stones", ("collect stone 4",)),
        ("Make a wooden pickaxe at the workbench", ("craft wood_pickaxe",)),
        ("Move to tree, gather wood.", ("go to tree", "collect wood")),
        ("Plant a sapling", ("place plant",)),
        ("Kill the zombie", ("attack zombie",)),
        ("Drink water", ("drink",)),
        ("Eat the beef", ("eat",)),
        ("Collect trees", ("collect wood 2",)),
        ("Craft a table", ("place crafting_table",)),
        ("collect wood_pickaxe", None),
    ],
)
def test_a_step_in_the_datasets_words_reads_as_catalogue_skills(
    step: str, skills: tuple[str, ...] | None
) -> None:
    if skills is None:
        with pytest.raises(ValueError, match="names no material"):
            read_step(step, EASY)
    else:
        assert read_step(step, EASY)[0] == skills


@pytest.mark.parametrize(
    ("step", "reason"),
    [
        ("Move left", "names no block"),
        ("Craft a pickaxe", "which pickaxe"),
        ("Smelt iron in furnace", "no action"),
        ("Place coal in furnace", "names no block to place"),
        ("Eat the plant", "eat hunts a cow"),
        ("Eat flora.", "eat hunts a cow"),
    ],
)
def test_a_step_naming_nothing_the_catalogue_knows_is_unread_with_its_reason(
    step: str, reason: str
) -> None:
    [reading] = read_plan([step], EASY)
    assert reading.skills == ()
    assert reading.unread is not None and reason in reading.unread


def test_a_partly_read_step_keeps_what_it_read_and_says_what_it_did_not() -> None:
    [reading] = read_plan(["Find and kill a cow"], EASY)
    assert reading.skills == ("attack cow",)
    assert reading.unread is not None and "find" in reading.unread


def test_placing_at_a_side_of_a_block_reads_only_where_the_difficulty_offers_it() -> None:
    step = "Place stone one block to the left of the furnace"
    assert read_step(step, MEDIUM)[0] == ("place stone left 1 of furnace",)
    assert read_step(step, EASY)[0] == ("place stone",)


# ---------------------------------------------------------------- the command


def _dataset(tmp_path: Path) -> Path:
    goals = (
        Goal(
            id="table",
            split="easy_train",
            category="one",
            instruction=TABLE,
            paraphrases=("Set up a workbench.",),
            required=("PLACE_TABLE",),
        ),
        Goal(
            id="pickaxe",
            split="easy_test_paraphrased",
            category="paraphrased",
            instruction=PICKAXE,
            paraphrases=(),
            required=("MAKE_WOOD_PICKAXE",),
        ),
    )
    source = DatasetSource(kind="json", path="test")
    return Dataset(source=source, goals=goals).save_json(tmp_path / "data.json")


def _write(path: Path, data: object) -> Path:
    path.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return path


def _score(tmp_path: Path, plans: Path, *extra: str, out: str = "out") -> int:
    return main(
        [
            "plan-score",
            str(plans),
            "--out",
            str(tmp_path / out),
            "--dataset",
            str(_dataset(tmp_path)),
            "--variant",
            "classic",
            "--no-progress",
            *extra,
        ]
    )


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "is not valid JSON"),
        ([TABLE], "must be one non-empty JSON object"),
        ({}, "must be one non-empty JSON object"),
        ({TABLE: 3}, "neither shape"),
        ({TABLE: "1. x", PICKAXE: ["1. y"]}, "neither shape"),
        ({TABLE: []}, "neither shape"),
    ],
)
def test_a_plans_file_of_neither_shape_is_refused_with_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: object, message: str
) -> None:
    plans = _write(tmp_path / "plans.json", content)
    assert _score(tmp_path, plans, "--worlds", "1") == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_texts_the_dataset_lacks_are_listed_and_counted_and_skipped_only_on_request(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plans = _write(
        tmp_path / "plans.json", {TABLE: NO_WOOD_TABLE, "Fly.": "1. Fly.", "Swim.": "1. Swim."}
    )
    assert _score(tmp_path, plans, "--worlds", "1") == 2
    err = capsys.readouterr().err
    assert "2 of 3 texts" in err and "'Fly.'" in err and "'Swim.'" in err
    assert err.count("\n") == 1
    assert not (tmp_path / "out").exists()
    assert _score(tmp_path, plans, "--worlds", "1", "--skip-unknown-texts") == 0
    scored = json.loads((tmp_path / "out" / "scores.json").read_text())["plans"]
    assert [s["instruction"] for s in scored] == [TABLE]


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (("--worlds", "0"), "--worlds"),
        (("--held-out-worlds", "-1"), "--held-out-worlds"),
        (("--export", "dpo", "--pairs-per-text", "0"), "--pairs-per-text"),
        (("--export", "dpo"), "no scored text has two"),
        (("--export", "sft", "--threshold", "1.5"), "--threshold"),
        (("--splits", "hard_nowhere"), "no split hard_nowhere"),
    ],
)
def test_bad_settings_are_refused_with_one_line_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: tuple[str, ...], message: str
) -> None:
    plans = _write(tmp_path / "plans.json", {TABLE: COMPLETE_TABLE})
    assert _score(tmp_path, plans, *flags) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_plans_are_scored_by_playing_them_and_the_best_exported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    candidates = {
        TABLE: [NO_PICKAXE, COMPLETE_TABLE, NO_WOOD_TABLE],
        "Set up a workbench.": [NO_WOOD_TABLE],
    }
    plans = _write(tmp_path / "candidates.json", candidates)
    flags = ("--worlds", "2", "--held-out-worlds", "1", "--export", "dpo", "--export", "sft")
    assert _score(tmp_path, plans, *flags) == 0
    out = tmp_path / "out"
    scores = json.loads((out / "scores.json").read_text())
    by_plan = {(s["instruction"], s["plan"]): s for s in scores["plans"]}
    complete = by_plan[(TABLE, COMPLETE_TABLE)]
    no_pickaxe = by_plan[(TABLE, NO_PICKAXE)]
    no_wood = by_plan[(TABLE, NO_WOOD_TABLE)]
    # The complete plan places a table in both worlds; the others fail at a stated step.
    assert complete["success"]["successes"] == 2
    assert complete["success"]["episodes"] == 2
    assert no_pickaxe["success"]["successes"] == 0
    [failure] = no_pickaxe["failures"]
    assert failure["step"] == 1 and "wood_pickaxe" in failure["reason"]
    assert no_wood["success"]["successes"] == 0
    assert no_wood["failures"][0]["step"] == 2 and "wood" in no_wood["failures"][0]["reason"]
    assert [s["skills"] for s in complete["steps"]] == [
        ["collect wood 4"],
        ["place crafting_table"],
    ]
    assert scores["splits"]["easy_train"]["texts"] == 2
    assert scores["splits"]["easy_train"]["best"]["successes"] == 2
    assert scores["splits"]["easy_train"]["first"]["successes"] == 0
    assert json.loads((out / "best.json").read_text()) == {
        TABLE: COMPLETE_TABLE,
        "Set up a workbench.": NO_WOOD_TABLE,
    }
    # The first and the best candidate of each text, once more in a held-out world.
    assert scores["splits"]["easy_train"]["best_held_out"]["episodes"] == 2
    assert complete["held_out"]["episodes"] == 1 and no_pickaxe["held_out"]["episodes"] == 1
    assert no_wood["held_out"] is None
    prompt = [
        {"role": m.role, "content": m.content}
        for m in planner_messages(TABLE, None, Variant.CLASSIC)
    ]

    def said(plan: str) -> list[dict[str, str]]:
        return [{"role": "assistant", "content": numbered(plan)}]

    dpo = [json.loads(line) for line in (out / "dpo.jsonl").read_text().splitlines()]
    assert sorted(dpo[0]) == ["chosen", "prompt", "rejected"]
    pairs = {(row["chosen"][0]["content"], row["rejected"][0]["content"]) for row in dpo}
    assert pairs == {
        (numbered(COMPLETE_TABLE), numbered(NO_WOOD_TABLE)),
        (numbered(COMPLETE_TABLE), numbered(NO_PICKAXE)),
    }
    assert all(row["prompt"] == prompt for row in dpo)
    sft = [json.loads(line) for line in (out / "sft.jsonl").read_text().splitlines()]
    assert sft == [{"messages": prompt + said(COMPLETE_TABLE)}]
    capsys.readouterr()
    # A rerun plays nothing: every episode is in the journal.
    assert _score(tmp_path, plans, *flags) == 0
    assert "11 episodes (11 resumed)" in capsys.readouterr().out
    assert json.loads((out / "scores.json").read_text()) == scores
    # Other worlds are other settings: refused unless restarted.
    assert _score(tmp_path, plans, "--worlds", "3") == 2


# ---------------------------------------------------------------- plan --candidates


def _plan(tmp_path: Path, model: str, *extra: str) -> int:
    return main(
        [
            "plan",
            "--model",
            model,
            "--dataset",
            str(_dataset(tmp_path)),
            "--difficulty",
            "easy",
            "--categories",
            "one",
            "--output",
            str(tmp_path / "plans" / "candidates.json"),
            "--no-progress",
            *extra,
        ]
    )


def test_candidates_are_sampled_distinct_with_duplicates_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Two texts, answered in turn from a cycle of three: sample 0 gets A, B; 1 gets A, A;
    # 2 gets B, A.
    model = "mock:cycle:1. Collect wood.|1. Place table.|1. Collect wood."
    flags = ("--candidates", "3", "--temperature", "0.7", "--sampling-seed", "5")
    assert _plan(tmp_path, model, *flags) == 0
    assert "3 samples each, 2 duplicates not kept" in capsys.readouterr().out
    written = json.loads((tmp_path / "plans" / "candidates.json").read_text())
    assert written == {
        TABLE: ["1. Collect wood.", "1. Place table."],
        "Set up a workbench.": ["1. Place table.", "1. Collect wood."],
    }
    sidecar = json.loads((tmp_path / "plans" / "candidates.meta.json").read_text())
    assert sidecar["settings"]["candidates"] == 3
    assert sidecar["settings"]["generation"]["temperature"] == 0.7
    assert sidecar["settings"]["generation"]["sampling_seed"] == 5
    journal = (tmp_path / "plans" / "candidates.journal.jsonl").read_text().splitlines()[1:]
    assert sorted(json.loads(line)["seed"] for line in journal) == [5, 5, 6, 6, 7, 7]


def test_exports_ask_the_prompt_the_plans_were_asked_with(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    templates = tmp_path / "templates"
    templates.mkdir()
    (templates / "planner.j2").write_text(
        "{% block system %}Plan in at most {{ max_steps }} steps.{% endblock %}\n"
        "{% block user %}Instruction: {{ instruction }}{% endblock %}\n"
    )
    model = "mock:cycle:" + COMPLETE_TABLE
    flags = ("--templates-dir", str(templates), "--max-steps", "9")
    assert _plan(tmp_path, model, *flags) == 0
    plans = tmp_path / "plans" / "candidates.json"
    assert _score(tmp_path, plans, "--worlds", "2", "--export", "sft") == 0
    sft = [json.loads(line) for line in (tmp_path / "out" / "sft.jsonl").read_text().splitlines()]
    asked = [
        {"role": m.role, "content": m.content}
        for m in planner_messages(TABLE, PlanLimits(max_steps=9), Variant.CLASSIC, templates)
    ]
    assert asked[0]["content"] == "Plan in at most 9 steps."
    assert sft[0]["messages"][:-1] == asked
    # Another template in that folder now: the export would pair the plans with a prompt that
    # never produced them, refused before anything is played.
    (templates / "planner.j2").write_text(
        "{% block system %}Plan briefly.{% endblock %}\n"
        "{% block user %}Instruction: {{ instruction }}{% endblock %}\n"
    )
    capsys.readouterr()
    assert _score(tmp_path, plans, "--export", "sft", out="again") == 2
    err = capsys.readouterr().err
    assert "planner.j2" in err and err.count("\n") == 1
    assert not (tmp_path / "again").exists()


@pytest.mark.parametrize(
    ("model", "flags", "message"),
    [
        ("mock:hash:1. Collect wood.|1. Place table.", ("--temperature", "0.7"), "cannot sample"),
        ("mock:cycle:1. Collect wood.|1. Place table.", (), "temperature 0"),
    ],
)
def test_candidates_from_a_backend_that_cannot_sample_are_refused(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    model: str,
    flags: tuple[str, ...],
    message: str,
) -> None:
    assert _plan(tmp_path, model, "--candidates", "4", *flags) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "plans").exists()
