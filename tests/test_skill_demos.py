"""The skills agent's worked skill sequences (`--skill-demos K`): what the expert's planner
chains for training goals, never shown to a text of its own goal (over every text of every
split of the official data), played for real to the goal they demonstrate, recorded in the
run's identity (a resume under other demos is refused, naming the difference)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from test_skills import goal, play, short_env  # noqa: F401  (a fixture)

from env import CrafTextEnv, Variant
from env.dataset import Dataset, load_dataset
from env.errors import UserError
from env.goals import DIFFICULTIES, LocalizationGoal
from llm_agents.agents.grounding import training_examples
from llm_agents.agents.skills.catalogue import read_skill, skill_offer
from llm_agents.agents.skills.demos import planned_skills, skill_demos
from llm_agents.agents.strategies.skills import SkillsAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import prepare_run, run_eval
from llm_agents.run_data.readings import reading_of

CLASSIC, FULL = Variant.CLASSIC, Variant.FULL
#: The variant each difficulty is played on in the official configs.
VARIANTS = {"easy": CLASSIC, "medium": CLASSIC, "hard": FULL}


@pytest.fixture(scope="module")
def official(official_repository: Path) -> Dataset:
    return load_dataset(str(official_repository))


def test_a_demo_is_the_expert_planners_chain_in_the_catalogues_words() -> None:
    offer = skill_offer(CLASSIC, "easy")
    pickaxe = planned_skills(reading_of(goal(("MAKE_WOOD_PICKAXE",))), offer)
    assert pickaxe is not None
    # Wood first (a table's and the tools'), the table, then the tools the planner makes there.
    assert pickaxe[0].startswith("collect wood") and pickaxe[1] == "place crafting_table"
    assert pickaxe[-1] == "craft wood_pickaxe"
    assert all(read_skill(text, offer).text == text for text in pickaxe)
    stone = planned_skills(reading_of(goal(("PLACE_STONE",))), offer)
    assert stone is not None and stone[-2:] == ("collect stone", "place stone")
    # A plant must ripen for hundreds of steps: no skill sequence expresses that plan.
    assert planned_skills(reading_of(goal(("EAT_PLANT",))), offer) is None
    # Nothing the goal forbids is planned, and a goal that cannot avoid it gets no demo.
    assert planned_skills(reading_of(goal(("MAKE_WOOD_PICKAXE",), ("PLACE_TABLE",))), offer) is None
    no_sword = planned_skills(reading_of(goal(("MAKE_WOOD_PICKAXE",), ("MAKE_WOOD_SWORD",))), offer)
    assert no_sword is not None and "craft wood_sword" not in no_sword


def test_a_placing_goals_demo_gathers_then_places_as_the_goal_names_it() -> None:
    localization = LocalizationGoal(
        id="L", scenario="medium", split="medium_train", instruction="Put a table two left of the water.",
        paraphrases=(), place="CRAFTING_TABLE", target="WATER", side="left", distance=2,
    )  # fmt: skip
    skills = planned_skills(reading_of(localization), skill_offer(CLASSIC, "medium"))
    assert skills == ("collect wood 2", "place crafting_table left 2 of water")


@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_no_text_of_any_split_is_shown_a_demo_of_its_own_goal(
    official: Dataset, difficulty: str
) -> None:
    variant = VARIANTS[difficulty]
    demos = skill_demos(training_examples(official, difficulty), variant, difficulty)  # type: ignore[arg-type]
    assert len(demos) >= 20
    everything = SkillsAgent(variant, difficulty, demos=demos, shown_demos=len(demos))  # type: ignore[arg-type]
    four = SkillsAgent(variant, difficulty, demos=demos, shown_demos=4)  # type: ignore[arg-type]
    goals = [g for g in official.goals if g.difficulty == difficulty]
    withheld_somewhere = 0
    for the_goal in goals:
        truth = reading_of(the_goal)
        for text in the_goal.texts:
            shown = everything._demos(text, the_goal)
            own = [d for d in demos if text in d.texts or d.reading == truth]
            assert not any(text in d.texts or d.reading == truth for d in shown)
            # Only its own goal's demos are left out; the rest keep their order.
            assert list(shown) == [d for d in demos if d not in own]
            withheld_somewhere += bool(own)
            first = four._demos(text, the_goal)
            assert len(first) == 4 and first == shown[:4]
            if own and text == the_goal.instruction and the_goal.split.endswith("train"):
                four.start_episode(0, EpisodeStart(text, goal=the_goal))
                request = four._messages(four._episode(0), "(observation)", [])[-1].content
                assert all(f'"{d.instruction}"' in request for d in first)
                assert not any(f'"{d.instruction}"' in request for d in own)
    assert withheld_somewhere


# ----------------------------------------------------------------------------- played for real


@pytest.mark.slow
def test_a_demos_skills_played_in_order_meet_the_goal_it_demonstrates(
    tmp_path: Path,
    short_env: CrafTextEnv,  # noqa: F811
) -> None:
    table = goal(("PLACE_TABLE",))
    skills = planned_skills(reading_of(table), skill_offer(CLASSIC, "easy"))
    assert skills is not None and skills[-1] == "place crafting_table"
    record, _ = play(tmp_path, short_env, table, list(skills), "easy")
    assert record.success
    assert record.skills is not None
    assert [r.skill for r in record.skills] == list(skills)


# ------------------------------------------------------------------------ the run's identity


def _settings(out: Path, dataset: str, **more: Any) -> dict[str, Any]:
    return {
        "agent": "skills", "model": "mock:cycle:collect wood", "dataset": dataset,
        "variant": "classic", "categories": ["new_objects"], "paraphrases": False,
        "max_steps": 2, "limit": 1, "batch_size": 1, "output_dir": str(out), **more,
    }  # fmt: skip


@pytest.mark.slow
def test_a_resume_under_other_demos_or_another_grammar_is_refused(
    tmp_path: Path, official_repository: Path
) -> None:
    out, dataset = tmp_path / "run", str(official_repository)
    config = build_config(_settings(out, dataset, skill_demos=2, choice="guided"))
    run_eval(config, MockModel("cycle:collect wood"))
    identity = json.loads((out / "results.json").read_text())["identity"]
    assert identity["examples"] and identity["grammar"]
    prepare_run(config)  # the same run resumes
    with pytest.raises(UserError, match=r"skill_demos \(2 before, 3 now\)"):
        prepare_run(build_config(_settings(out, dataset, skill_demos=3, choice="guided")))
    with pytest.raises(UserError, match=r"answer grammar \(\w{12} before, none now\)"):
        prepare_run(build_config(_settings(out, dataset, skill_demos=2)))
    # The same settings, but another demo list or grammar than the run recorded.
    results = json.loads((out / "results.json").read_text())
    for field, words in (("examples", "worked-example list"), ("grammar", "answer grammar")):
        changed = json.loads(json.dumps(results))
        changed["identity"][field] = "0" * 64
        (out / "results.json").write_text(json.dumps(changed))
        with pytest.raises(UserError, match=rf"{words} \(000000000000 before"):
            prepare_run(config)
    (out / "results.json").write_text(json.dumps(results))
    prepare_run(config)


def test_more_demos_than_the_split_gives_without_the_goal_is_refused(
    tmp_path: Path, official_repository: Path
) -> None:
    official = load_dataset(str(official_repository))
    most = len(skill_demos(training_examples(official, "easy"), CLASSIC, "easy"))
    # A train text is never shown its own goal's demo: all of them is one too many.
    settings = _settings(tmp_path / "run", str(official_repository), skill_demos=most)
    settings["categories"] = ["one", "combo"]
    del settings["limit"]  # every text of the run is checked
    with pytest.raises(UserError, match=rf"--skill-demos {most}: .* only \d+ of them"):
        prepare_run(build_config(settings))
    assert not (tmp_path / "run").exists()
