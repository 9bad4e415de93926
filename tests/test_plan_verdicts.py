"""plan-score's verdicts against the game's rules: hand-labelled plans whose outcome follows from
craftax's rules (a table takes 2 wood, a furnace 1 stone and no table, a crafted table is the
placed one), plans that break their instruction's "do not" and texts met without acting kept out
of the exports, held-out worlds apart from eval's, and exports TRL's own data utilities read."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from env import episode_key
from env.dataset import Dataset, DatasetSource, Goal
from env.goals import BuildLineGoal
from llm_agents.cli import main
from llm_agents.planning.export import dpo_rows, numbered, sft_rows
from llm_agents.planning.records import PlanScore, StepReading
from llm_agents.planning.scoring import HELD_OUT_WORLDS, SELECTION_WORLDS
from llm_agents.run_data.metrics import SuccessRate

TABLE = "Place a crafting table."
FURNACE = "Place a furnace."
NO_PLANT = "Craft a wooden pickaxe but avoid planting anything."
LINE = "Build a line of 2 furnaces."

PLURAL_TREES = "1. Collect trees.\n2. Place crafting table."
ONE_TREE = "1. Collect a tree.\n2. Place crafting table."
CRAFT_THEN_PLACE = "1. Collect wood.\n2. Craft a table.\n3. Place the table."
NOTHING_READ = "Think it over carefully first."
FURNACE_AWAY = (
    "1. Collect wood 3.\n2. Place crafting table.\n3. Craft a wooden pickaxe.\n"
    "4. Collect stone.\n5. Explore.\n6. Explore.\n7. Explore.\n8. Place furnace."
)
PICKAXE = "1. Collect wood 3.\n2. Place crafting table.\n3. Craft a wooden pickaxe."
PICKAXE_THEN_PLANT = PICKAXE + "\n4. Collect sapling.\n5. Plant a sapling."
NO_PICKAXE = "1. Collect wood.\n2. Place crafting table."

TUNE_MISSING = [n for n in ("trl", "datasets", "transformers") if not importlib.util.find_spec(n)]


def _dataset(tmp_path: Path) -> Path:
    goals = (
        Goal(id="table", split="easy_train", category="one", instruction=TABLE, paraphrases=(),
             required=("PLACE_TABLE",)),
        Goal(id="furnace", split="easy_train", category="one", instruction=FURNACE,
             paraphrases=(), required=("PLACE_FURNACE",)),
        Goal(id="no_plant", split="easy_train", category="combo", instruction=NO_PLANT,
             paraphrases=(), required=("MAKE_WOOD_PICKAXE",), forbidden=("PLACE_PLANT",)),
        BuildLineGoal(id="line", scenario="medium", split="medium_train", instruction=LINE,
                      paraphrases=(), block="FURNACE", size=2, diagonal=False),
    )  # fmt: skip
    source = DatasetSource(kind="json", path="test")
    return Dataset(source=source, goals=goals).save_json(tmp_path / "data.json")


def test_selection_and_held_out_worlds_share_no_key_with_eval() -> None:
    def keys(stream: str) -> set[bytes]:
        return {
            episode_key(0, goal, text, world, stream).tobytes()
            for goal in ("table", "furnace")
            for text in range(3)
            for world in range(16)
        }

    eval_keys, selection, held_out = keys(""), keys(SELECTION_WORLDS), keys(HELD_OUT_WORLDS)
    assert len(eval_keys) == len(selection) == len(held_out) == 96
    assert not eval_keys & selection and not eval_keys & held_out and not selection & held_out
    # Eval's keys are those it always had: the stream leaves them alone.
    assert np.array_equal(episode_key(0, "table", 0, 0), episode_key(0, "table", 0, 0, ""))


def _score(text: str, candidate: int, plan: str, hits: int, **extra: object) -> PlanScore:
    return PlanScore(
        instruction=text,
        candidate=candidate,
        plan=plan,
        steps=[StepReading(number=1, text="Collect wood", skills=("collect wood",))],
        goal_id="g",
        split="easy_train",
        success=SuccessRate.of(hits, 4),
        env_steps=0,
        **extra,  # type: ignore[arg-type]
    )


def _prompt(text: str) -> list[dict[str, str]]:
    return [
        {"role": "system", "content": "Write a plan."},
        {"role": "user", "content": f"Instruction: {text}"},
    ]


def test_dpo_pairs_are_capped_per_text_widest_margins_first() -> None:
    scores = [_score(TABLE, i, f"{i + 1}. Collect wood {i + 1}.", hits) for i, hits in
              enumerate([4, 3, 1, 0])]  # fmt: skip
    rows = dpo_rows(scores, 0.25, _prompt, per_text=2)
    assert len(rows) == 2
    margins = [(r["chosen"][0]["content"], r["rejected"][0]["content"]) for r in rows]
    assert margins == [("1. Collect wood 1.", "1. Collect wood 4."),
                       ("1. Collect wood 1.", "1. Collect wood 3.")]  # fmt: skip
    assert len(dpo_rows(scores, 0.25, _prompt, per_text=10)) == 6


def test_an_answer_is_the_plans_steps_as_numbered_lines() -> None:
    assert numbered("Plan:\nStep 1: Collect wood.\nStep 2: Place table.\nGood luck!") == (
        "1. Collect wood.\n2. Place table."
    )


@pytest.mark.skipif(bool(TUNE_MISSING), reason="the tune extra is not installed")
def test_exports_are_read_by_datasets_and_trls_own_data_utilities(tmp_path: Path) -> None:
    import datasets
    from transformers import AutoTokenizer
    from trl.data_utils import apply_chat_template, is_conversational

    from benchmarks.tune_planner import model_folder

    scores = [_score(TABLE, 0, PLURAL_TREES, 4), _score(TABLE, 1, ONE_TREE, 0)]
    files = {
        "sft": sft_rows(scores, 0.5, _prompt),
        "dpo": dpo_rows(scores, 0.25, _prompt, per_text=4),
    }
    tokenizer = AutoTokenizer.from_pretrained(model_folder("hf:smollm2-135m"))
    for kind, rows in files.items():
        path = tmp_path / f"{kind}.jsonl"
        path.write_text("".join(json.dumps(row) + "\n" for row in rows))
        loaded = datasets.load_dataset("json", data_files=str(path), split="train")
        assert len(loaded) == 1
        example = loaded[0]
        assert is_conversational(example)
        text = apply_chat_template(example, tokenizer)
        if kind == "sft":
            assert sorted(example) == ["messages"]
            assert [m["role"] for m in example["messages"]] == ["system", "user", "assistant"]
            assert "Instruction: Place a crafting table." in text["text"]
            assert "1. Collect trees.\n2. Place crafting table." in text["text"]
        else:
            assert sorted(example) == ["chosen", "prompt", "rejected"]
            assert text["prompt"].rstrip().endswith("assistant")
            assert "Collect trees" in text["chosen"] and "Collect a tree" in text["rejected"]
            assert "Instruction:" not in text["chosen"]


@pytest.mark.slow
def test_hand_labelled_plans_get_the_games_verdicts_and_only_sound_plans_are_exported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    candidates = {
        TABLE: [PLURAL_TREES, ONE_TREE, CRAFT_THEN_PLACE, NOTHING_READ],
        FURNACE: [FURNACE_AWAY],
        NO_PLANT: [PICKAXE_THEN_PLANT, PICKAXE, NO_PICKAXE],
        LINE: ["1. Explore."],
    }
    plans = tmp_path / "candidates.json"
    plans.write_text(json.dumps(candidates))
    argv = ["plan-score", str(plans), "--out", str(tmp_path / "out"), "--dataset",
            str(_dataset(tmp_path)), "--variant", "classic", "--no-progress", "--worlds", "2",
            "--held-out-worlds", "1", "--export", "sft", "--export", "dpo"]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    out = tmp_path / "out"
    scores = json.loads((out / "scores.json").read_text())
    by_plan = {(s["instruction"], s["plan"]): s for s in scores["plans"]}

    def rate(text: str, plan: str) -> float:
        return float(by_plan[(text, plan)]["success"]["rate"])

    # A table takes 2 wood: "trees" gathers them, "a tree" one.
    assert rate(TABLE, PLURAL_TREES) == 1.0 and rate(TABLE, ONE_TREE) == 0.0
    assert by_plan[(TABLE, ONE_TREE)]["failures"][0]["step"] == 2
    # A crafted table is the placed one, and the open collect gathers its 2 wood.
    assert rate(TABLE, CRAFT_THEN_PLACE) == 1.0
    crafted = by_plan[(TABLE, CRAFT_THEN_PLACE)]["steps"]
    assert [s["skills"] for s in crafted] == [["collect wood 2"], [], ["place crafting_table"]]
    assert "placed once" in crafted[1]["notes"][0] and "2 wood" in crafted[0]["notes"][0]
    # A furnace takes a stone and no table nearby.
    furnace = by_plan[(FURNACE, FURNACE_AWAY)]
    assert not any("crafting table" in f["reason"] for f in furnace["failures"])
    assert furnace["success"]["successes"] >= 1
    # Planting after the pickaxe meets the goal (the episode ends first) but breaks the text.
    planting = by_plan[(NO_PLANT, PICKAXE_THEN_PLANT)]
    assert planting["success"]["rate"] == 1.0
    assert planting["breaks"] == ["step 5: place plant earns PLACE_PLANT"]
    assert planting["excluded"] == "breaks_instruction"
    assert by_plan[(NO_PLANT, PICKAXE)]["breaks"] == [] and rate(NO_PLANT, PICKAXE) == 1.0
    assert by_plan[(TABLE, NOTHING_READ)]["excluded"] == "empty"
    line = by_plan[(LINE, "1. Explore.")]
    assert line["met_without_acting"] and line["excluded"] == "met_without_acting"
    assert scores["kept_out"] == {
        "breaks_instruction": 1,
        "empty": 1,
        "met_without_acting": 1,
        "texts_met_without_acting": 1,
    }
    assert "kept out of the exports" in printed
    # The best is chosen among sound plans, and reported in held-out worlds too.
    best = json.loads((out / "best.json").read_text())
    assert best[NO_PLANT] == PICKAXE and best[TABLE] == PLURAL_TREES
    train = scores["splits"]["easy_train"]
    assert train["best_held_out"]["episodes"] == 3
    # Exports: no line from a plan that breaks its text, an empty plan or a text met without
    # acting.
    lines = [
        json.loads(line)
        for name in ("sft.jsonl", "dpo.jsonl")
        for line in (out / name).read_text().splitlines()
    ]
    answers = [
        m["content"]
        for row in lines
        for key in ("messages", "chosen", "rejected")
        for m in row.get(key, [])
        if m["role"] == "assistant"
    ]
    assert answers and numbered(PICKAXE) in answers
    assert numbered(PICKAXE_THEN_PLANT) not in answers
    assert numbered(NOTHING_READ) not in answers and "1. Explore." not in answers
    prompts = [m["content"] for row in lines for m in row.get("messages", row.get("prompt", []))]
    assert not any(LINE in p for p in prompts)
