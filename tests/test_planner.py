"""Plan generation, checking, repair, resume and loading (llm_agents/planning/)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import pytest

from env.dataset import Category, Dataset, DatasetSource, Goal, Split
from env.errors import UserError
from env.goals import GOAL_KINDS, BuildLineGoal, LocalizationGoal
from env.variant import Variant
from llm_agents.backends.base import ChatMessage, ChoiceSet, Conversation, ModelOutput
from llm_agents.backends.mock import MockModel
from llm_agents.planning import (
    PlanLimits,
    PlannerConfig,
    check_plan,
    craftax_vocabulary,
    goal_instructions,
    load_plans,
    parse_plan,
    plan_instructions,
    run_planner,
    unknown_words,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
OFFICIAL_PLANS = DATA / "easy_gpt4_action_plans.json"
PROMPTS = Path(__file__).resolve().parents[1] / "prompts"

GOOD = "1. Collect wood from a tree.\n2. Place a crafting table.\n3. Make a wood pickaxe."
REPAIRED = "1. Find a furnace.\n2. Place stone left of it."
BAD_WORDS = "Plan:\n1. Find the smelter.\n2. Deposit a rock beside it."
TOO_MANY = "\n".join(f"{i}. Collect wood." for i in range(1, 8))


def is_repair(conversation: Sequence[ChatMessage]) -> bool:
    return "breaks the rules" in conversation[-1].content


def instruction_of(conversation: Sequence[ChatMessage]) -> str:
    user = conversation[-1].content
    return user.split("Instruction: ", 1)[1].split("\n", 1)[0]


class CountingModel(MockModel):
    """A mock that also counts `generate` calls and can fail chosen instructions."""

    def __init__(self, outputs: Callable[[Sequence[ChatMessage]], str], fail: Iterable[str] = ()):
        super().__init__(outputs=outputs)
        self.calls: list[int] = []
        self.fail = set(fail)

    def generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None = None
    ) -> list[ModelOutput]:
        self.calls.append(len(conversations))
        outputs = super().generate(conversations, choices)
        return [
            ModelOutput(text="", finish_reason="error", error="boom")
            if instruction_of(conversation) in self.fail
            else output
            for conversation, output in zip(conversations, outputs, strict=True)
        ]


def config(tmp_path: Path, **overrides: object) -> PlannerConfig:
    return PlannerConfig.model_validate({"output": tmp_path / "plans.json", **overrides})


# ---------------------------------------------------------------- parsing and checking


def test_parse_plan_reads_every_numbering_style_and_drops_headings() -> None:
    steps, extra = parse_plan("Action Plan:\n1. Find tree.\nStep 2: Collect wood\n3) Place table\n")
    assert steps == ["Find tree.", "Collect wood", "Place table"]
    assert extra == []
    steps, extra = parse_plan("- Collect wood\n- Place table\nGood luck with the task, adventurer!")
    assert steps == ["Collect wood", "Place table"]
    assert extra == ["Good luck with the task, adventurer!"]


def test_valid_plan_has_no_issues_and_normalises_to_numbered_lines() -> None:
    check = check_plan("Plan:\nStep 1: Collect stones.\nStep 2: Placing the furnace nearby.")
    assert check.ok, check.issues
    assert check.text == "1. Collect stones.\n2. Placing the furnace nearby."


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ("", "no_steps"),
        ("I would collect wood and then place a table.", "no_steps"),
        (TOO_MANY, "too_many_steps"),
        ("1. Walk over to the nearest tree and then collect some wood from it", "step_too_long"),
        (BAD_WORDS, "unknown_words"),
    ],
)
def test_check_plan_flags_each_broken_rule(text: str, kind: str) -> None:
    check = check_plan(text)
    assert [issue.kind for issue in check.issues] == [kind]


def test_limits_are_configurable() -> None:
    plan = "1. Collect wood.\n2. Place table.\n3. Make wood pickaxe."
    assert check_plan(plan, PlanLimits(max_steps=3, max_step_words=3)).ok
    assert not check_plan(plan, PlanLimits(max_steps=2)).ok
    assert not check_plan(plan, PlanLimits(max_step_words=2)).ok


def test_unknown_words_accepts_inflections_and_rejects_synonyms() -> None:
    assert unknown_words("Collecting stones, placed tables, wooden swords, go upwards 2x2") == []
    assert unknown_words("Smelt ore at the workbench with the rock") == [
        "smelt",
        "ore",
        "workbench",
        "rock",
    ]


#: A plan in Craftax names for each goal kind, and the variant its difficulty plays.
PLANS_BY_KIND = {
    "achievements": (Variant.CLASSIC, "1. Collect wood.\n2. Place a table.\n3. Avoid the cow."),
    "conditional_placing": (Variant.CLASSIC, "1. Collect 3 iron.\n2. Place 2 crafting tables."),
    "localization_placing": (
        Variant.FULL,
        "1. Find the enchantment table.\n2. Place a furnace 2 blocks left of it.",
    ),
    "build_line": (Variant.CLASSIC, "1. Collect stone.\n2. Place 3 stones in a diagonal line."),
    "build_square": (Variant.CLASSIC, "1. Collect stone.\n2. Lay stones in a solid 3x3 square."),
    "build_star": (
        Variant.FULL,
        "1. Collect stone.\n2. Place stones in a star shape.\n3. Make each cross arm 3 long.",
    ),
}


def test_a_plan_for_every_goal_kind_passes_in_its_variant() -> None:
    assert set(PLANS_BY_KIND) == set(GOAL_KINDS)
    for kind, (variant, plan) in PLANS_BY_KIND.items():
        assert check_plan(plan, variant=variant).issues == [], kind


def test_full_variant_names_are_unknown_to_classic() -> None:
    assert unknown_words("Shoot an arrow at the gnome", Variant.FULL) == []
    assert set(unknown_words("Shoot an arrow at the gnome", Variant.CLASSIC)) >= {"arrow", "gnome"}


@pytest.mark.parametrize("variant", list(Variant))
def test_vocabulary_matches_craftax_enums(variant: Variant) -> None:
    # The planner reads craftax's source without importing it; check that against the real enums.
    import importlib

    module = importlib.import_module(
        "craftax.craftax.constants"
        if variant is Variant.FULL
        else "craftax.craftax_classic.constants"
    )
    vocabulary = craftax_vocabulary(variant)
    for enum_name in ("BlockType", "Action", "Achievement"):
        for member in getattr(module, enum_name):
            if member.name in {"INVALID", "OUT_OF_BOUNDS", "DARKNESS", "NECROMANCER_VULNERABLE"}:
                continue
            words = [w for w in member.name.lower().split("_") if w.isalpha()]
            assert set(words) <= vocabulary, member.name


# ---------------------------------------------------------------- planning


def scripted(conversation: Sequence[ChatMessage]) -> str:
    """Valid for wood, repairable for the furnace, hopeless for the cow."""
    instruction = instruction_of(conversation)
    if is_repair(conversation):
        return REPAIRED if "furnace" in instruction else TOO_MANY
    return {"Collect wood.": GOOD, "Place stone left of the furnace.": BAD_WORDS}.get(
        instruction, TOO_MANY
    )


INSTRUCTIONS = ["Collect wood.", "Place stone left of the furnace.", "Eat a cow.", "Collect wood."]


def test_plans_are_valid_repaired_or_failed(tmp_path: Path) -> None:
    model = CountingModel(scripted)
    summary = plan_instructions(INSTRUCTIONS, model, config(tmp_path))
    assert (summary.instructions, summary.valid, summary.repaired, summary.failed) == (3, 1, 1, 1)
    assert summary.failed_instructions == ["Eat a cow."]
    plans = load_plans(summary.output)
    assert plans["Collect wood."] == GOOD
    assert plans["Place stone left of the furnace."] == REPAIRED
    assert plans["Eat a cow."] == check_plan(TOO_MANY).text  # failed plans stay, normalised
    # One batch of plans, then one batch of repairs for the two flagged plans only.
    assert model.calls == [3, 2]
    repair_prompts = [conv[-1].content for conv, _ in model.requests if is_repair(conv)]
    assert any("smelter" in p and "Find the smelter" in p for p in repair_prompts)


def test_token_totals_leave_computed_unset_where_the_backend_does_not_say(
    tmp_path: Path,
) -> None:
    summary = plan_instructions(INSTRUCTIONS, CountingModel(scripted), config(tmp_path))
    assert summary.prompt_tokens > 0
    assert summary.computed_prompt_tokens is None


def test_drop_failed_and_no_repair(tmp_path: Path) -> None:
    model = CountingModel(scripted)
    summary = plan_instructions(
        INSTRUCTIONS, model, config(tmp_path, repair=False, drop_failed=True)
    )
    assert (summary.valid, summary.repaired, summary.failed) == (1, 0, 2)
    assert model.calls == [3]
    assert set(load_plans(summary.output)) == {"Collect wood."}


def test_requests_are_batched(tmp_path: Path) -> None:
    model = CountingModel(lambda conversation: GOOD)
    texts = [f"Collect wood {i}." for i in range(5)]
    plan_instructions(texts, model, config(tmp_path, requests_per_call=2))
    assert model.calls == [2, 2, 1]


def test_rerun_skips_planned_instructions_and_retries_errors(tmp_path: Path) -> None:
    first = CountingModel(scripted, fail={"Eat a cow."})
    summary = plan_instructions(INSTRUCTIONS, first, config(tmp_path))
    assert summary.errors == 1
    assert "Eat a cow." not in load_plans(summary.output)

    second = CountingModel(scripted)
    summary = plan_instructions([*INSTRUCTIONS, "Drink water."], second, config(tmp_path))
    asked = {instruction_of(conv) for conv, _ in second.requests}
    assert asked == {"Eat a cow.", "Drink water."}
    assert summary.resumed == 2
    assert summary.errors == 0
    assert set(load_plans(summary.output)) == {*INSTRUCTIONS, "Drink water."}


def test_interrupted_run_keeps_finished_batches(tmp_path: Path) -> None:
    def stop_at_third(conversation: Sequence[ChatMessage]) -> str:
        if instruction_of(conversation) == "Collect wood 2.":
            raise KeyboardInterrupt
        return GOOD

    texts = [f"Collect wood {i}." for i in range(4)]
    with pytest.raises(KeyboardInterrupt):
        plan_instructions(
            texts, CountingModel(stop_at_third), config(tmp_path, requests_per_call=2)
        )
    assert set(load_plans(tmp_path / "plans.json")) == {"Collect wood 0.", "Collect wood 1."}

    rest = CountingModel(lambda conversation: GOOD)
    summary = plan_instructions(texts, rest, config(tmp_path, requests_per_call=2))
    assert {instruction_of(conv) for conv, _ in rest.requests} == {
        "Collect wood 2.",
        "Collect wood 3.",
    }
    assert summary.in_file == 4


def test_torn_journal_line_is_redone(tmp_path: Path) -> None:
    summary = plan_instructions(INSTRUCTIONS[:2], CountingModel(scripted), config(tmp_path))
    journal = summary.journal
    data = journal.read_bytes()
    last_record = data.splitlines(keepends=True)[-1]
    journal.write_bytes(data[: len(data) - len(last_record) // 2])  # as if killed mid-write

    again = CountingModel(scripted)
    summary = plan_instructions(INSTRUCTIONS[:2], again, config(tmp_path))
    assert {instruction_of(conv) for conv, _ in again.requests} == {INSTRUCTIONS[1]}
    assert summary.resumed == 1
    assert all(json.loads(line) for line in journal.read_text().splitlines())


def test_changed_settings_refuse_to_resume_unless_restarted(tmp_path: Path) -> None:
    plan_instructions(INSTRUCTIONS, CountingModel(scripted), config(tmp_path))
    with pytest.raises(UserError, match="limits"):
        plan_instructions(
            INSTRUCTIONS, CountingModel(scripted), config(tmp_path, limits=PlanLimits(max_steps=3))
        )
    model = CountingModel(scripted)
    summary = plan_instructions(INSTRUCTIONS, model, config(tmp_path, restart=True))
    assert summary.resumed == 0
    assert model.calls[0] == 3


def test_sidecar_records_model_parameters_and_template_hashes(tmp_path: Path) -> None:
    summary = plan_instructions(INSTRUCTIONS, CountingModel(scripted), config(tmp_path))
    sidecar = json.loads(summary.sidecar.read_text())
    settings = sidecar["settings"]
    assert settings["backend"] == "mock"
    assert settings["generation"]["temperature"] == 0.0
    for name in ("planner.j2", "plan_repair.j2"):
        source = (PROMPTS / name).read_bytes()
        assert settings["templates"][name] == hashlib.sha256(source).hexdigest()
    assert sidecar["summary"]["repaired"] == summary.repaired == 1
    assert settings["limits"] == {"max_steps": 5, "max_step_words": 8}


def test_prompt_names_the_instruction_and_limits(tmp_path: Path) -> None:
    model = CountingModel(scripted)
    plan_instructions(["Collect wood."], model, config(tmp_path, limits=PlanLimits(max_steps=4)))
    (conversation, _), *_ = model.requests
    assert [m.role for m in conversation] == ["system", "user"]
    assert "At most 4 numbered steps" in conversation[0].content
    assert "crafting table" in conversation[0].content
    assert conversation[1].content == "Instruction: Collect wood."


# ---------------------------------------------------------------- dataset


def goal(split: Split, category: Category, instruction: str, required: str) -> Goal:
    return Goal(
        id=required,
        split=split,
        category=category,
        instruction=instruction,
        paraphrases=tuple(f"{instruction} (way {i})" for i in range(5)),
        required=(required,),
    )


def test_run_planner_plans_every_text_of_the_chosen_categories(tmp_path: Path) -> None:
    goals = (
        goal("easy_train", "one", "Collect wood.", "COLLECT_WOOD"),
        goal("easy_test_paraphrased", "paraphrased", "Eat a cow.", "EAT_COW"),
    )
    source = DatasetSource(kind="json", path="test")
    dataset = Dataset(source=source, goals=goals).save_json(tmp_path / "data.json")
    cfg = config(tmp_path, categories=["paraphrased"], dataset=dataset)
    summary = run_planner(cfg, CountingModel(lambda conversation: GOOD))
    assert list(load_plans(summary.output)) == list(goals[1].texts)
    assert json.loads(summary.sidecar.read_text())["instructions_from"]["categories"] == [
        "paraphrased"
    ]
    with pytest.raises(UserError, match="easy_hard"):
        run_planner(
            config(tmp_path, categories=["easy_hard"], dataset=dataset), CountingModel(scripted)
        )


@pytest.mark.parametrize(
    ("names", "difficulty", "categories"),
    [
        (["easy_train"], "easy", ("one", "combo")),
        (["easy_test_paraphrased", "new_objects"], "easy", ("paraphrased", "new_objects")),
        (["medium_train,medium_test_other_params"], "medium", ("train", "new_objects")),
        ("hard_train", "hard", ("train",)),
    ],
)
def test_split_names_are_read_as_their_difficulty_and_categories(
    tmp_path: Path, names: object, difficulty: str, categories: tuple[str, ...]
) -> None:
    # What `--splits` took before plan chose its texts as eval does.
    cfg = config(tmp_path, categories=names)
    assert (cfg.difficulty, cfg.categories) == (difficulty, categories)


@pytest.mark.parametrize(
    "settings",
    [
        {"categories": ["easy_train", "medium_train"]},
        {"categories": ["hard_train"], "difficulty": "medium"},
    ],
)
def test_split_names_of_two_difficulties_are_refused(
    tmp_path: Path, settings: dict[str, object]
) -> None:
    with pytest.raises(UserError, match="one difficulty at a time"):
        config(tmp_path, **settings)


def test_run_planner_plans_medium_and_hard_goals_of_any_kind(tmp_path: Path) -> None:
    line = BuildLineGoal(
        id="INSTRUCTION_STONE_3",
        split="medium_train",
        scenario="medium",
        instruction="Build a line of three stones.",
        paraphrases=("Put three stones in a row.",),
        block="STONE",
        size=3,
        diagonal=False,
    )
    placing = LocalizationGoal(
        id="TABLE_RIGHT_OF_WATER",
        split="hard_train",
        scenario="hard",
        instruction="Place a table two tiles right of water.",
        paraphrases=(),
        place="CRAFTING_TABLE",
        target="WATER",
        side="right",
        distance=2,
    )
    source = DatasetSource(kind="json", path="test")
    dataset = Dataset(source=source, goals=(line, placing)).save_json(tmp_path / "data.json")
    for difficulty in ("medium", "hard"):
        cfg = config(tmp_path, difficulty=difficulty, categories=["train"], dataset=dataset)
        summary = run_planner(cfg, CountingModel(lambda conversation: GOOD))
    # One difficulty a run; the second adds its plans to the first's.
    assert list(load_plans(summary.output)) == [*line.texts, *placing.texts]


def test_goal_instructions_keeps_order_and_drops_repeats() -> None:
    a = goal("easy_train", "one", "Collect wood.", "COLLECT_WOOD")
    assert goal_instructions([a, a]) == list(a.texts)


# ---------------------------------------------------------------- loading


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "does not exist"),
        ("{not json", "not valid JSON"),
        ("[1, 2]", "not a list"),
        ('{"Collect wood.": ["1. Collect wood."]}', "is not a string"),
        ("{}", "holds no plans"),
    ],
)
def test_load_plans_rejects_bad_files(tmp_path: Path, content: str | None, message: str) -> None:
    path = tmp_path / "plans.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(UserError, match=message) as caught:
        load_plans(path)
    assert str(path) in str(caught.value)


@pytest.mark.skipif(not OFFICIAL_PLANS.exists(), reason=f"reference data absent: {OFFICIAL_PLANS}")
def test_official_plan_file_loads_and_mostly_keeps_the_limits() -> None:
    plans = load_plans(OFFICIAL_PLANS)
    assert len(plans) > 3000
    checks = [check_plan(text) for text in plans.values()]
    within_limits = sum(
        not any(issue.kind != "unknown_words" for issue in check.issues) for check in checks
    )
    fully_valid = sum(check.ok for check in checks)
    # GPT-4 kept the step limits but echoed the paraphrases' synonyms (rock, workbench, timber),
    # which the vocabulary check is meant to catch.
    assert within_limits / len(plans) > 0.9
    assert 0.2 < fully_valid / len(plans) < within_limits / len(plans)


def test_compare_plans_measures_coverage_length_and_vocabulary() -> None:
    from benchmarks.compare_plans import plan_stats

    plans = {"a": "1. Collect wood.\n2. Smelt ore.", "unused": GOOD}
    stats = plan_stats(plans, ["a", "b"], PlanLimits(), Variant.FULL)
    assert (stats.instructions, stats.covered, stats.coverage) == (2, 1, 0.5)
    assert (stats.steps_per_plan, stats.words_per_step) == (2.0, 2.0)
    assert stats.oov_rate == pytest.approx(2 / 4)  # smelt, ore
    assert (stats.plans_with_oov, stats.within_limits, stats.valid) == (1.0, 1.0, 0.0)


def test_user_templates_replace_ours_and_are_hashed(tmp_path: Path) -> None:
    folder = tmp_path / "templates"
    folder.mkdir()
    custom = "{% block user %}Plan this: {{ instruction }} in {{ max_steps }} steps{% endblock %}"
    (folder / "planner.j2").write_text(custom)
    model = MockModel(outputs=[GOOD])
    summary = plan_instructions(["Collect wood."], model, config(tmp_path, templates_dir=folder))
    (conversation, _), *_ = model.requests
    assert [(m.role, m.content) for m in conversation] == [
        ("user", "Plan this: Collect wood. in 5 steps")
    ]
    templates = json.loads(summary.sidecar.read_text())["settings"]["templates"]
    assert templates["planner.j2"] == hashlib.sha256(custom.encode()).hexdigest()
