"""Grounding Medium and Hard goals: the parser of typed placing goals, kind and parameter scores,
`craftext-llm ground --difficulty medium` end to end (report by scenario class, bad input) and
the `guided` agent playing a grounded Medium goal, on the mock backend and the official data."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path

import pytest

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from env.dataset import Dataset, DatasetSource
from env.dataset import Goal as AchievementsGoal
from env.goals import DIFFICULTY_KINDS, GOAL_KINDS, SPLITS, AnyGoal, Goal, LocalizationGoal
from env.official_source import parse_directory
from llm_agents.agents.grounding import grounding_messages, parse_grounding, reading_json
from llm_agents.backends.base import ChatMessage
from llm_agents.backends.mock import MockModel
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import build_config, build_settings
from llm_agents.evaluation.grounding_run import (
    GroundConfig,
    execute_grounding,
    prepare_grounding,
    read_ground_results,
    read_groundings,
    summarize_records,
)
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.grounding_metrics import (
    KIND_CONFUSION,
    Confusion,
    Scored,
    confusions,
    score,
)
from llm_agents.run_data.readings import (
    READING_CLASSES,
    AchievementsReading,
    BuildLineReading,
    BuildSquareReading,
    ConditionalPlacingReading,
    LocalizationReading,
    reading_of,
)
from llm_agents.run_data.store import read_episodes, read_steps

CLASSIC = Variant.CLASSIC
STONE_LEFT_OF_FURNACE = LocalizationReading(
    place="STONE", target="FURNACE", side="left", distance=1
)


def test_every_goal_kind_is_read_with_the_goals_own_parameters() -> None:
    assert set(READING_CLASSES) == set(GOAL_KINDS)
    goal = LocalizationGoal(
        id="G", scenario="medium", split="medium_train", instruction="put it", paraphrases=(),
        place="STONE", target="FURNACE", side="left", distance=1,
    )  # fmt: skip
    assert reading_of(goal) == STONE_LEFT_OF_FURNACE
    # The kind's validators are the goal's: a reading sorts achievements as a goal does.
    names = ("COLLECT_WOOD", "PLACE_TABLE")
    assert AchievementsReading(required=names[::-1]).required == Goal(
        id="A", split="easy_train", category="combo", instruction="x", paraphrases=(),
        required=names[::-1],
    ).required == names  # fmt: skip


def test_a_right_medium_answer_is_read_as_its_typed_goal_and_scores_exact() -> None:
    answer = '{"kind": "localization_placing", "place": "stone", "target": "Furnace", "side": "LEFT", "distance": 1}'  # fmt: skip
    grounding = parse_grounding(answer, CLASSIC, "medium")
    assert grounding.outcome == "valid" and grounding.reading == STONE_LEFT_OF_FURNACE
    result = score([Scored("medium_train", "train", STONE_LEFT_OF_FURNACE, grounding)])
    assert result.exact.rate == 1.0 and result.kind is not None and result.kind.rate == 1.0
    assert {key: rate.rate for key, rate in result.parameters.items()} == {
        f"localization_placing.{field}": 1.0 for field in ("place", "target", "side", "distance")
    }
    assert result.fields == {}  # no achievements goal among them


def test_a_wrong_side_and_distance_is_the_right_kind_with_those_fields_wrong() -> None:
    answer = '{"kind": "localization_placing", "place": "STONE", "target": "FURNACE", "side": "right", "distance": 2}'  # fmt: skip
    items = [
        Scored(
            "medium_train",
            "train",
            STONE_LEFT_OF_FURNACE,
            parse_grounding(answer, CLASSIC, "medium"),
            "Localization",
        )
    ]
    result = score(items)
    assert result.exact.successes == 0 and result.kind is not None and result.kind.rate == 1.0
    read_right = {key.split(".")[1]: rate.successes for key, rate in result.parameters.items()}
    assert read_right == {"place": 1, "target": 1, "side": 0, "distance": 0}
    assert confusions(items) == {
        ("localization_placing side misread", "left as right"): 1,
        ("localization_placing distance misread", "1 as 2"): 1,
    }


def test_a_goal_read_as_another_kind_is_a_kind_confusion_and_scores_no_parameter() -> None:
    truth = BuildSquareReading(block="STONE", size=3)
    answer = '{"kind": "build_line", "block": "STONE", "size": 3, "diagonal": false}'
    items = [Scored("medium_train", "train", truth, parse_grounding(answer, CLASSIC, "medium"))]
    result = score(items)
    assert result.kind is not None and result.kind.successes == 0 and result.parameters == {}
    assert confusions(items) == {(KIND_CONFUSION, "build_square as build_line"): 1}


@pytest.mark.parametrize(
    ("answer", "stage", "reason"),
    [
        ("I would build something.", "none", "no JSON object"),
        ('```json\n{"kind": "build_line", "block": "OBSIDIAN", "size": 2, "diagonal": true}\n```', "fenced", "unknown block: 'OBSIDIAN' in block"),
        ('Here: {"kind": "conditional_placing", "collect": "ruby", "collect_count": 1, "place": "STONE", "place_count": 1}', "embedded", "unknown item: 'ruby' in collect"),
        ('{"kind": "localization_placing", "place": "STONE", "target": "TREE", "side": "north", "distance": 1}', "json", "unknown side: 'north'"),
        ('{"kind": "localization_placing", "place": "STONE", "target": "TREE", "side": "up"}', "json", "localization_placing lacks distance"),
        ('{"kind": "localization_placing", "place": "STONE", "target": "TREE", "side": "up", "distance": 1, "colour": "red"}', "json", "unexpected keys colour"),
        ('{"kind": "build_square", "block": "STONE", "size": "3"}', "json", "size is not a whole number"),
        ('{"kind": "build_line", "block": "STONE", "size": 3, "diagonal": 1}', "json", "diagonal is not true or false"),
        ('{"kind": "localization_placing", "place": "STONE", "target": "TREE", "side": "up", "distance": -1}', "json", "greater than or equal to 0"),
        ('{"kind": "build_star", "block": "STONE", "size": 3, "cross": "straight"}', "json", "unknown kind: 'build_star'"),
        ('{"kind": "achievements", "required": ["BUILD_CASTLE"]}', "json", "unknown achievement"),
    ],
)  # fmt: skip
def test_a_garbage_medium_answer_is_invalid_with_its_stage_and_reason(
    answer: str, stage: str, reason: str
) -> None:
    grounding = parse_grounding(answer, CLASSIC, "medium")
    assert grounding.outcome == "invalid" and grounding.reading is None
    assert grounding.stage == stage and reason in (grounding.reason or "")


def test_easy_reads_only_achievements_goals_and_hard_only_its_own_kinds() -> None:
    line = '{"kind": "build_line", "block": "STONE", "size": 3, "diagonal": false}'
    assert parse_grounding(line, CLASSIC, "easy").outcome == "invalid"
    assert parse_grounding(line, Variant.FULL, "hard").reading == BuildLineReading(
        block="STONE", size=3, diagonal=False
    )
    achievements = '{"required": ["COLLECT_WOOD"]}'
    assert parse_grounding(achievements, CLASSIC, "medium").reading == AchievementsReading(
        required=("COLLECT_WOOD",)
    )
    assert "unknown kind" in (parse_grounding(achievements, Variant.FULL, "hard").reason or "")
    # Full Craftax's blocks exist only there.
    fire = '{"kind": "build_square", "block": "ENCHANTMENT_TABLE_FIRE", "size": 3}'
    assert parse_grounding(fire, Variant.FULL, "hard").outcome == "valid"
    assert "unknown block" in (parse_grounding(fire, CLASSIC, "medium").reason or "")


def test_the_prompt_offers_the_difficultys_kinds_and_the_variants_names() -> None:
    def system(variant: Variant, difficulty: str) -> str:
        messages = grounding_messages("Do it.", variant, difficulty=difficulty)  # type: ignore[arg-type]
        return messages[0].content

    easy, medium, hard = (
        system(CLASSIC, "easy"),
        system(CLASSIC, "medium"),
        system(Variant.FULL, "hard"),
    )
    assert '"kind"' not in easy and "CRAFTING_TABLE" not in easy  # EASY's prompt: achievements only
    assert all(kind in medium for kind in ("localization_placing", "build_square", "achievements"))
    assert "build_star" not in medium and "build_star" in hard
    assert '"kind": "achievements"' not in hard
    assert all(block in medium for block in CLASSIC.block_names)
    assert "ENCHANTMENT_TABLE_FIRE" in hard and "ENCHANTMENT_TABLE_FIRE" not in medium
    assert "sapphire" in hard and "sapphire" not in medium


def test_the_prompt_shows_each_kind_with_exactly_its_declared_parameters() -> None:
    # ground.j2 spells each kind's JSON out for the model: it must name the fields the kind's
    # parameters declare (env.goals), no more and no fewer.
    shown: dict[str, set[str]] = {}
    for variant, difficulty in ((CLASSIC, "medium"), (Variant.FULL, "hard")):
        prompt = grounding_messages("Do it.", variant, difficulty=difficulty)[0].content  # type: ignore[arg-type]
        for line in prompt.splitlines():
            if line.strip().startswith('{"kind": "'):
                kind = line.split('"')[3]
                shown[kind] = set(re.findall(r'"(\w+)":', line))
    assert set(shown) == set(GOAL_KINDS)
    for kind, fields in shown.items():
        assert fields == set(READING_CLASSES[kind].model_fields), kind  # type: ignore[index]


# ----------------------------------------------------------------------------- official goals


@pytest.fixture(scope="module")
def official(official_repository: Path) -> Dataset:
    return parse_directory(official_repository)


def test_every_official_medium_and_hard_goal_survives_its_own_json(official: Dataset) -> None:
    later = [goal for goal in official.goals if goal.difficulty != "easy"]
    assert {goal.kind for goal in later} >= {"localization_placing", "build_star"}
    for goal in later:
        variant = CLASSIC if goal.difficulty == "medium" else Variant.FULL
        truth = reading_of(goal)
        assert parse_grounding(reading_json(truth), variant, goal.difficulty).reading == truth


def test_medium_worked_examples_show_every_kind_answered_as_the_prompt_asks(
    official: Dataset,
) -> None:
    from llm_agents.agents.grounding import training_examples

    examples = training_examples(official, "medium")
    assert len(examples) == len(official.split("medium_train"))
    truths = {goal.instruction: reading_of(goal) for goal in official.split("medium_train")}
    first = examples[:5]
    assert {truths[e.instruction].kind for e in first} == set(DIFFICULTY_KINDS["medium"])
    for example in examples:
        # Every answer names its kind, achievements goals too, as Medium's prompt shows them.
        assert json.loads(example.answer)["kind"] == truths[example.instruction].kind
        read = parse_grounding(example.answer, CLASSIC, "medium").reading
        assert read == truths[example.instruction]


def test_no_text_of_any_split_is_shown_its_own_answer_at_any_number_of_shots(
    official: Dataset,
) -> None:
    from llm_agents.agents.grounding import examples_for, training_examples

    with_answer_elsewhere = 0
    for difficulty in ("easy", "medium", "hard"):
        examples = training_examples(official, difficulty)  # type: ignore[arg-type]
        answers = {example.answer for example in examples}
        variant = CLASSIC if difficulty != "hard" else Variant.FULL
        for goal in (g for g in official.goals if g.difficulty == difficulty):
            truth = reading_of(goal)
            own = reading_json(truth, difficulty)  # type: ignore[arg-type]
            for text in goal.texts:
                # Every example a text can be shown, at any number of shots: the first n of
                # these are what n shots show.
                shown = examples_for(text, truth, examples, len(examples))
                assert own not in {example.answer for example in shown}, (difficulty, text)
                if own in answers and text not in {t for e in examples for t in e.texts}:
                    # A goal training states in other words: the request itself, at the most
                    # shots a run may ask for, holds no turn answering with it.
                    with_answer_elsewhere += 1
                    messages = grounding_messages(
                        text, variant, difficulty=difficulty, examples=examples, shots=16,
                        answer=truth,
                    )  # fmt: skip
                    assert len(messages) == 2 + 2 * 16 and own not in {
                        m.content for m in messages if m.role == "assistant"
                    }
    # The official test splits repeat training goals in other words (EASY and Medium alike).
    assert with_answer_elsewhere > 50


def test_examples_are_never_chosen_blind_to_the_answer() -> None:
    from llm_agents.agents.grounding import training_examples

    dataset = Dataset(
        source=DatasetSource(kind="json", path="goals"),
        goals=(
            AchievementsGoal(id="W", split="easy_train", category="one",
                             instruction="Collect wood.", paraphrases=(), required=("COLLECT_WOOD",)),
        ),
    )  # fmt: skip
    with pytest.raises(ValueError, match="pass answer"):
        grounding_messages(
            "Chop a tree.", CLASSIC, examples=training_examples(dataset, "easy"), shots=1
        )


def pick(official: Dataset, split: str, kind: str) -> AnyGoal:
    return next(goal for goal in official.goals if goal.split == split and goal.kind == kind)


@pytest.fixture(scope="module")
def medium_goals(official: Dataset) -> tuple[AnyGoal, ...]:
    """A goal of every Medium kind from the train split, and one from each test split."""
    return (
        pick(official, "medium_train", "achievements"),
        pick(official, "medium_train", "conditional_placing"),
        pick(official, "medium_train", "localization_placing"),
        pick(official, "medium_train", "build_line"),
        pick(official, "medium_test_paraphrased", "build_square"),
        pick(official, "medium_test_other_params", "conditional_placing"),
    )


@pytest.fixture(scope="module")
def medium_file(
    medium_goals: tuple[AnyGoal, ...], tmp_path_factory: pytest.TempPathFactory
) -> Path:
    path = tmp_path_factory.mktemp("medium") / "medium.json"
    return Dataset(source=DatasetSource(kind="json", path="medium goals"), goals=medium_goals).save_json(path)  # fmt: skip


def misread(goal: AnyGoal) -> str:
    """The answers of the end-to-end run: right, except the localization goal's side, the square
    read as a line and the other-parameters goal answered with garbage."""
    truth = reading_of(goal)
    if isinstance(truth, LocalizationReading):
        side = "right" if truth.side != "right" else "left"
        return reading_json(truth.model_copy(update={"side": side}))
    if isinstance(truth, BuildSquareReading):
        return reading_json(BuildLineReading(block=truth.block, size=truth.size, diagonal=False))
    if goal.split == "medium_test_other_params":
        return "a conditional goal, I think"
    return reading_json(truth)


def test_cli_ground_medium_scores_by_split_and_scenario_class_and_reports_them(
    medium_goals: tuple[AnyGoal, ...],
    medium_file: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    answers = tmp_path / "answers.json"
    # The run asks in dataset order, one text per goal without paraphrases.
    answers.write_text(json.dumps([misread(goal) for goal in medium_goals]))
    out = tmp_path / "run"
    args = ["ground", "--difficulty", "medium", "--model", f"mock:file:{answers}",
            "--dataset", str(medium_file), "--variant", "classic", "--no-paraphrases",
            "--output-dir", str(out), "--no-progress"]  # fmt: skip
    assert main(args) == 0

    results = read_ground_results(out / "results.json")
    assert results.identity.settings["difficulty"] == "medium"
    # No --categories: every Medium split.
    assert results.config["categories"] == ["train", "paraphrased", "new_objects"]
    rows = {r.goal_id: r for r in read_groundings(out)}
    assert {r.scenario_class for r in rows.values()} == {
        "Achievements", "Conditional", "Localization", "Build"
    }  # fmt: skip
    summary = results.summary
    assert summary is not None and summary.overall.texts == 6
    assert (summary.overall.exact.successes, summary.overall.invalid) == (3, 1)
    assert summary.overall.kind is not None and summary.overall.kind.successes == 4
    build, local = summary.by_scenario_class["Build"], summary.by_scenario_class["Localization"]
    assert (build.texts, build.exact.successes) == (2, 1)
    assert local.kind is not None and (local.kind.rate, local.exact.rate) == (1.0, 0.0)
    assert local.parameters["localization_placing.side"].successes == 0
    assert local.parameters["localization_placing.place"].successes == 1
    assert set(summary.by_split) == {s for s in SPLITS if s.startswith("medium")}
    kinds = {(c.kind, c.subject) for c in summary.confusions}
    assert (KIND_CONFUSION, "build_square as build_line") in kinds

    capsys.readouterr()
    assert main(["report", str(out)]) == 0
    report = capsys.readouterr().out
    assert "By scenario class (medium):" in report
    for label in ("Achievements", "Conditional", "Localization", "Build", "localization_placing.side"):  # fmt: skip
        assert label in report
    assert "goal kind misread: build_square as build_line" in report


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--difficulty", "extreme"], "difficulty"),
        (["--difficulty", "medium", "--categories", "combo"], "not one of medium's"),
        (["--difficulty", "hard"], "no hard_train goals"),
    ],
)
def test_cli_ground_medium_bad_input_is_one_line_exit_2_nothing_written(
    medium_file: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    out = tmp_path / "run"
    args = ["ground", "--model", "mock:", "--dataset", str(medium_file), "--variant", "classic",
            "--output-dir", str(out), "--no-progress", *extra]  # fmt: skip
    try:
        code = main(args)
    except SystemExit as exit_:  # argparse refuses a difficulty it has no choice for
        code = exit_.code
    assert code == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert not out.exists()


# ----------------------------------------------------------------------------- guided on Medium

MAX_STEPS = 25


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=CLASSIC, max_steps=MAX_STEPS))


def played(
    tmp_path: Path, name: str, dataset: Path, env: CrafTextEnv, agent: str, answer: str = ""
) -> tuple[list[str], bool | None]:
    """The actions of the one episode of a Medium run, and whether its goal was read right."""
    settings = {
        "agent": agent, "model": "mock:", "dataset": str(dataset), "variant": "classic",
        "difficulty": "medium", "categories": ["train"], "paraphrases": False,
        "max_steps": MAX_STEPS, "batch_size": 1, "output_dir": str(tmp_path / name),
    }  # fmt: skip
    model = MockModel(outputs=lambda conversation: answer)
    run_eval(build_config(settings), model, env=env)
    (episode,) = read_episodes(tmp_path / name / "episodes.jsonl")
    steps = tmp_path / name / "steps.jsonl"
    # An episode that never started took no step, so its run may have no steps file.
    actions = [step.action_name for step in read_steps(steps)] if steps.exists() else []
    return actions, episode.grounding_correct


def one_goal(path: Path, goal: AnyGoal) -> Path:
    return Dataset(source=DatasetSource(kind="json", path=str(path)), goals=(goal,)).save_json(path)


def test_guided_plays_the_medium_goal_it_grounded(
    official: Dataset, tmp_path: Path, short_env: CrafTextEnv
) -> None:
    goal = pick(official, "medium_train", "conditional_placing")
    assert isinstance(reading_of(goal), ConditionalPlacingReading)
    record = one_goal(tmp_path / "record.json", goal)
    # The same goal (same id, same text, so the same world) asking for plants instead.
    other_block = "PLANT" if goal.place != "PLANT" else "CRAFTING_TABLE"  # type: ignore[union-attr]
    changed = goal.model_copy(update={"place": other_block, "place_count": 1})
    misread_record = one_goal(tmp_path / "misread.json", changed)

    expert, _ = played(tmp_path, "expert", record, short_env, "expert")
    right, right_read = played(
        tmp_path, "right", record, short_env, "guided", reading_json(reading_of(goal))
    )
    wrong, wrong_read = played(
        tmp_path, "wrong", record, short_env, "guided", reading_json(reading_of(changed))
    )
    expert_on_misread, _ = played(tmp_path, "expert2", misread_record, short_env, "expert")

    assert (right_read, wrong_read) == (True, False)
    assert right == expert  # the grounded goal, read right, is the record's
    assert wrong == expert_on_misread  # misread: the expert plays what was read
    assert wrong != right


def test_guided_medium_garbage_leaves_the_episode_unstarted(
    official: Dataset, tmp_path: Path, short_env: CrafTextEnv
) -> None:
    record = one_goal(tmp_path / "record.json", pick(official, "medium_train", "build_line"))
    actions, read_right = played(tmp_path, "run", record, short_env, "guided", '{"kind": "tower"}')
    (episode,) = read_episodes(tmp_path / "run" / "episodes.jsonl")
    assert (actions, read_right, episode.termination) == ([], False, "not_started")
    assert episode.grounding is not None and "unknown kind" in (episode.grounding.reason or "")


def test_choice_options_are_the_runs_typed_goals_read_by_the_same_parser(
    medium_goals: tuple[AnyGoal, ...], medium_file: Path, tmp_path: Path
) -> None:
    settings = {
        "model": "mock:", "dataset": str(medium_file), "variant": "classic",
        "difficulty": "medium", "paraphrases": False, "choice": "loglik",
        "output_dir": str(tmp_path / "run"),
    }  # fmt: skip
    texts = {goal.instruction: reading_json(reading_of(goal), "medium") for goal in medium_goals}
    model = MockModel(outputs=lambda conversation: texts[instruction_of(conversation)])
    results = execute_grounding(prepare_grounding(build_settings(GroundConfig, settings)), model)
    options = model.requests[0][1]
    assert options is not None and set(options.options) == set(texts.values())
    assert results.summary is not None and results.summary.overall.exact.rate == 1.0
    # The options are written as Medium's prompt and worked examples write a goal: an
    # achievements goal names its kind.
    (achievements,) = [o for o in options.options if '"achievements"' in o]
    assert json.loads(achievements)["kind"] == "achievements"
    example = next(goal for goal in medium_goals if goal.kind == "achievements")
    from llm_agents.agents.grounding import grounding_examples

    assert grounding_examples([example])[0].answer == achievements


def test_an_easy_run_written_before_goal_kinds_still_reads_and_scores_the_same(
    tmp_path: Path,
) -> None:
    # A groundings line and a confusion as they were written while only EASY goals were typed.
    line = {
        "key": "easy_train/G/0", "goal_id": "G", "split": "easy_train", "category": "combo",
        "instruction_variant": 0, "instruction": "Make a table, no saplings.",
        "truth": {"scenario": "easy", "required": ["PLACE_TABLE"], "forbidden": ["COLLECT_SAPLING"]},
        "grounding": {"outcome": "valid", "stage": "json", "raw": "{}", "reading": {
            "scenario": "easy", "required": ["PLACE_TABLE", "COLLECT_SAPLING"], "forbidden": []}},
        "correct": False,
    }  # fmt: skip
    (tmp_path / "groundings.jsonl").write_text(json.dumps(line) + "\n")
    (record,) = read_groundings(tmp_path)
    assert record.truth == AchievementsReading(
        required=("PLACE_TABLE",), forbidden=("COLLECT_SAPLING",)
    )
    assert record.scenario_class == "Achievements"
    summary = summarize_records([record])
    assert summary is not None and summary.overall.exact.successes == 0
    assert [(c.kind, c.subject) for c in summary.confusions] == [
        ("forbidden read as required", "COLLECT_SAPLING")
    ]
    old = Confusion.model_validate(
        {"kind": "required missed", "achievement": "EAT_COW", "count": 2}
    )
    assert old.subject == "EAT_COW"


def instruction_of(conversation: Sequence[ChatMessage]) -> str:
    return conversation[-1].content.removeprefix("Instruction: ").strip()
