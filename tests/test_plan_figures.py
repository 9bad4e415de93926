"""benchmarks/plan_figures.py: the texts a before/after comparison plans for."""

from __future__ import annotations

from pathlib import Path

from benchmarks.plan_figures import one_text_per_goal, restricted
from env.dataset import load_dataset
from env.goals import Dataset, DatasetSource, Goal


def _dataset(tmp_path: Path) -> str:
    def goal(split: str, category: str, texts: tuple[str, ...]) -> Goal:
        return Goal(
            id=f"{split}-{texts[0]}",
            split=split,
            category=category,
            instruction=texts[0],
            paraphrases=texts[1:],
            required=("COLLECT_WOOD",),
        )

    goals = (
        goal("easy_train", "one", ("Collect wood.", "Chop a tree.")),
        # A paraphrased goal keeps its train instruction: only its paraphrases are new.
        goal("easy_test_paraphrased", "paraphrased", ("Collect wood.", "Fell some timber.")),
        goal("easy_test_other_params", "new_objects", ("Gather logs.", "Get lumber.")),
    )
    path = Dataset(source=DatasetSource(kind="json", path="t"), goals=goals).save_json(
        tmp_path / "data.json"
    )
    return str(path)


def test_one_text_per_goal_plans_each_splits_own_text(tmp_path: Path) -> None:
    dataset = _dataset(tmp_path)
    written = one_text_per_goal(dataset).save_json(tmp_path / "one.json")
    texts = [(g.split, g.texts) for g in load_dataset(str(written)).goals]
    assert texts == [
        ("easy_train", ("Collect wood.",)),
        ("easy_test_paraphrased", ("Fell some timber.",)),
        ("easy_test_other_params", ("Gather logs.",)),
    ]


def test_restrict_keeps_the_plans_of_the_datasets_texts(tmp_path: Path) -> None:
    one = str(one_text_per_goal(_dataset(tmp_path)).save_json(tmp_path / "one.json"))
    plans = {"Collect wood.": "1. a", "Chop a tree.": "1. b", "Fell some timber.": ["1. c"]}
    assert restricted(plans, one) == {"Collect wood.": "1. a", "Fell some timber.": ["1. c"]}
