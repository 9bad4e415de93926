"""The skills agent: its catalogue per variant and difficulty, the skill parser, prerequisites and
`--choice` options on hand-built observations, its records, what an episode got wrong, and
scripted runs on the mock backend (a right sequence meets EASY and Medium goals, a missing
prerequisite fails with its reason, garbage ends as a failure with its reason)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from env.dataset import Dataset, DatasetSource, Goal
from env.goals import AnyGoal, BuildLineGoal, BuildSquareGoal, LocalizationGoal
from llm_agents.agents.expert.navigation import ExpertEpisode
from llm_agents.agents.skills.catalogue import Build, Collect, Place, parse_skill, skill_offer
from llm_agents.agents.skills.runner import SkillRun, valid_now
from llm_agents.agents.strategies.skills import GIVE_UP, SkillsAgent
from llm_agents.agents.types import EpisodeStart, StepPrompt
from llm_agents.backends.base import ChatMessage, ChoiceSet, ModelOutput
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.dispatch import Dispatcher
from llm_agents.evaluation.runner import run_eval
from llm_agents.judging.report import format_table
from llm_agents.judging.skill_errors import model_calls_saved, skill_error
from llm_agents.run_data.metrics import action_counts
from llm_agents.run_data.records import EpisodeRecord, SkillRecord
from llm_agents.run_data.store import read_episodes, read_results, read_steps
from llm_agents.viewer.pages import build_view
from textualizer.observation import Inventory, Observation, Position, Vitals

CLASSIC, FULL = Variant.CLASSIC, Variant.FULL

# ----------------------------------------------------------------------------- the catalogue


def test_each_difficulty_offers_the_placing_skills_its_goals_need() -> None:
    easy, medium, hard = (skill_offer(CLASSIC, d) for d in ("easy", "medium", "hard"))
    assert (easy.place_at, easy.shapes) == (False, ())
    assert (medium.place_at, medium.shapes) == (True, ("line", "square"))
    assert hard.shapes == ("line", "square", "star")
    assert parse_skill("build line stone 3", easy).reason == (
        "nothing is built on easy: no build skill is offered"
    )
    assert parse_skill("place stone right 2 of tree", easy).skill is None
    assert parse_skill("place stone right 2 of tree", medium).skill == Place(
        block="stone", side="right", distance=2, reference="tree"
    )
    assert parse_skill("build star stone 3 diagonal", medium).skill is None
    assert parse_skill("build star stone 3 diagonal", hard).skill is not None


def test_what_the_variant_lacks_is_not_offered() -> None:
    classic, full = skill_offer(CLASSIC, "hard"), skill_offer(FULL, "hard")
    assert "fountain" not in classic.blocks and "fountain" in full.blocks
    assert "gnome_warrior" not in classic.creatures and "gnome_warrior" in full.creatures
    refused = parse_skill("go to fountain", classic)
    assert refused.skill is None and "unknown block 'fountain'" in (refused.reason or "")
    assert parse_skill("go to fountain", full).skill is not None
    assert parse_skill("place stone left 1 of fountain", full).skill is not None
    assert any("gnome_warrior" in form for form in full.forms())
    assert not any("gnome_warrior" in form for form in classic.forms())


def test_the_parser_reads_the_answer_field_lines_and_aliases() -> None:
    offer = skill_offer(CLASSIC, "medium")
    think = "<think>SKILL: eat</think>I need wood first.\nSKILL: collect wood 3"
    assert parse_skill(think, offer).skill == Collect(material="wood", count=3)
    assert parse_skill(think, offer).stage == "field"
    assert parse_skill("Place Table", offer).skill == Place(block="crafting_table")
    last_line = parse_skill("Let me think.\nbuild line stone 3 diagonal", offer)
    assert (last_line.skill, last_line.stage) == (
        Build(shape="line", block="stone", size=3, diagonal=True),
        "exact",
    )
    assert parse_skill("craft wood pickaxe", offer).skill is not None
    # Qwen2.5-Coder-0.5B copies the history's line format after the field.
    copied = parse_skill("SKILL: place stone: failed (needs 1 stone (have 0)), 0 steps", offer)
    assert (copied.skill, copied.stage) == (Place(block="stone"), "field")
    assert parse_skill("collect wood, then a table", offer).skill == Collect(material="wood")


@pytest.mark.parametrize(
    ("answer", "side", "distance", "reference"),
    [
        ("SKILL: place stone 4 blocks to the left of the coal.", "left", 4, "coal"),
        ("place stone two blocks above the iron", "up", 2, "iron"),
        ("place stone 2 blocks to the right of a tree", "right", 2, "tree"),
        ("place stone one block to the left of the existing furnace", "left", 1, "furnace"),
        ("place stone 3 below the water", "down", 3, "water"),
        ("place stone 4 blocks to the left side of the water", "left", 4, "water"),
    ],
)
def test_a_localization_written_as_prose_is_read_as_the_catalogue_form(
    answer: str, side: str, distance: int, reference: str
) -> None:
    parsed = parse_skill(answer, skill_offer(CLASSIC, "medium"))
    assert parsed.skill == Place(block="stone", side=side, distance=distance, reference=reference)


@pytest.mark.parametrize(
    ("answer", "reason"),
    [
        ("SKILL: dance", "unknown skill 'dance'"),
        ("collect gold", "unknown material 'gold'"),
        ("collect wood 12", "n must be a whole number from 1 to 9"),
        ("craft laser", "unknown item 'laser'"),
        ("place stone sideways of tree", "write place <block> <side> <distance> of <reference>"),
        ("place stone 5 NW", "write place <block> <side> <distance> of <reference>"),
        ("place stone 2 blocks left or right of tree", "write place <block> <side>"),
        ("", "empty answer"),
    ],
)
def test_an_answer_outside_the_catalogue_is_invalid_with_why(answer: str, reason: str) -> None:
    parsed = parse_skill(answer, skill_offer(CLASSIC, "medium"))
    assert (parsed.skill, parsed.stage) == (None, "invalid")
    assert reason in (parsed.reason or "")


def test_the_parser_never_raises_on_garbage() -> None:
    offer = skill_offer(FULL, "hard")
    for text in ["\x00\x01", "SKILL:", "{}" * 500, "place", "build line", "go", "ü" * 99]:
        assert parse_skill(text, offer).stage == "invalid"


# ----------------------------------------------------------------------------- prerequisites


def observation(
    materials: dict[str, int] | None = None, tools: tuple[str, ...] = ()
) -> Observation:
    """Grass all round, a tree two cells east and water two cells north."""
    blocks: dict[str, list[tuple[int, int]]] = {"grass": [], "tree": [], "water": []}
    for dx in range(-4, 5):
        for dy in range(-3, 4):
            blocks[
                "tree" if (dx, dy) == (2, 0) else "water" if (dx, dy) == (0, 2) else "grass"
            ].append((dx, dy))
    return Observation(
        variant=CLASSIC, step=0, position=Position(x=20, y=20), floor=None, facing="right",
        facing_block="grass",
        vitals=Vitals(health=9, food=9, drink=9, energy=9, mana=None, max_health=9, max_food=9,
                      max_mana=None, hunger=0, thirst=0, fatigue=0, recover=0),
        attributes=None, sleeping=False, resting=False, daylight=1.0, night=False,
        inventory=Inventory(materials=materials or {}, tools=list(tools), enchantments={}),
        spells=[], achievements=[], view_size=(9, 7), blocks=blocks, items={}, mobs=[], unlit=[],
    )  # fmt: skip


def why_not(text: str, obs: Observation, difficulty: str = "medium") -> str | None:
    skill = parse_skill(text, skill_offer(CLASSIC, difficulty)).skill
    assert skill is not None, text
    episode = ExpertEpisode((), ())
    episode.world.update(obs)
    return SkillRun(skill, episode, obs, 10).why_not()


def test_prerequisites_are_not_solved_for_the_model() -> None:
    bare = observation()
    assert why_not("craft wood_pickaxe", bare) == "craft wood_pickaxe needs 1 wood (have 0)"
    assert "no crafting table" in (why_not("craft wood_pickaxe", observation({"wood": 1})) or "")
    assert why_not("collect stone", bare) == "collect stone needs a wood_pickaxe (craft it first)"
    assert why_not("collect diamond", bare) == (
        "collect diamond needs an iron_pickaxe (craft it first)"
    )
    assert why_not("collect stone", observation(tools=("wood_pickaxe",))) is None
    assert why_not("place table", observation({"wood": 1})) == (
        "place crafting_table needs 2 wood (have 1)"
    )
    assert why_not("build line stone 3", observation({"stone": 2})) == (
        "build line stone 3 needs 3 stone (have 2)"
    )
    assert why_not("place stone up 1 of coal", observation({"stone": 1})) == (
        "no coal seen yet (find one first)"
    )
    assert why_not("sleep", bare) == "energy is full: sleep is refused until it drops"
    assert why_not("collect wood 9", observation({"wood": 1})) == (
        "the inventory holds at most 9 wood"
    )


def test_choice_offers_the_skills_valid_now() -> None:
    obs = observation({"wood": 3})
    episode = ExpertEpisode((), ())
    episode.world.update(obs)
    options = valid_now(skill_offer(CLASSIC, "medium"), episode, obs)
    assert {"collect wood", "place crafting_table", "go to tree", "drink", "noop"} <= set(options)
    assert "place crafting_table right 2 of tree" in options
    assert "build line crafting_table 2" not in options  # 4 wood for 2 tables
    assert not {"collect stone", "craft wood_pickaxe", "place stone", "sleep"} & set(options)
    assert "place crafting_table right 2 of tree" not in valid_now(
        skill_offer(CLASSIC, "easy"), episode, obs
    )


def test_a_choice_request_carries_the_skills_valid_now_and_lists_them() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", choice_rule="loglik")
    agent.start_episode(0, EpisodeStart("Place a crafting table."))
    prompt = agent.prepare(0, observation({"wood": 3}))
    assert prompt.choices is not None and prompt.choices.rule == "loglik"
    assert "place crafting_table" in prompt.choices.options
    assert "craft wood_pickaxe" not in prompt.choices.options
    assert "- place crafting_table" in prompt.messages[-1].content
    decision = agent.decide(prompt, ModelOutput(text="place crafting_table"))
    assert decision.skills[-1].skill == "place crafting_table"
    assert decision.name in ("LEFT", "RIGHT", "UP", "DOWN", "PLACE_TABLE")


def decide_steps(
    agent: SkillsAgent, answers: list[str], steps: int, still: Observation | None = None
) -> tuple[int, list[str]]:
    """Play `steps` steps of one episode on a still observation (by default no wood, no stone),
    the model answering `answers` in turn, then `noop`: (model calls, actions)."""
    agent.start_episode(0, EpisodeStart("Place stone."))
    calls, actions = 0, []
    for step in range(steps):
        prompt = agent.prepare(0, (still or observation()).model_copy(update={"step": step}))
        answer = answers[calls] if calls < len(answers) else "noop"
        calls += bool(prompt.messages)
        actions.append(agent.decide(prompt, ModelOutput(text=answer)).name)
    return calls, actions


def test_a_model_repeating_a_skill_that_cannot_start_is_stopped_with_the_reason() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", stuck_after=3)
    calls, actions = decide_steps(agent, ["place stone"] * 20, 20)
    assert calls == 3 and actions == ["NOOP"] * 20
    *first, last = agent._episode(0).history
    assert [(r.skill, r.outcome, r.prerequisite) for r in first] == [
        ("place stone", "failed", True)
    ] * 2
    assert last.reason == (
        "place stone needs 1 stone (have 0); chosen 3 times with no step taken since: no more "
        "skills are asked"
    )


def test_a_model_repeating_a_skill_with_nothing_to_do_is_stopped() -> None:
    beside_tree = observation()
    blocks = {"tree": [(1, 0)], "grass": [xy for xy in beside_tree.blocks["grass"] if xy != (1, 0)]}
    beside_tree = beside_tree.model_copy(update={"blocks": blocks})
    agent = SkillsAgent(CLASSIC, difficulty="easy", stuck_after=3)
    calls, actions = decide_steps(agent, ["go to tree"] * 10, 10, beside_tree)
    assert calls == 3 and actions == ["NOOP"] * 10
    history = agent._episode(0).history
    assert [(r.outcome, r.steps) for r in history] == [("succeeded", 0)] * 3
    assert history[-1].reason == "chosen 3 times with no step taken since: no more skills are asked"


@pytest.mark.parametrize(
    ("answers", "calls"),
    [
        # Two failing skills in turn, or an invalid answer between: no step taken all along.
        (["craft wood_pickaxe", "collect iron"] * 5, 5),
        (["place stone", "place stone", "dance", "place stone"], 4),
    ],
)
def test_other_decisions_that_take_no_step_do_not_reset_the_count(
    answers: list[str], calls: int
) -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", stuck_after=3)
    assert decide_steps(agent, answers, 12)[0] == calls
    assert agent._episode(0).stopped


@pytest.mark.parametrize(
    "answers",
    [
        # A skill that runs: the player moves towards the tree, the state changes.
        ["place stone", "place stone", "collect wood", "place stone", "place stone"],
        # `noop` takes its step: time passes.
        ["place stone", "place stone", "noop", "place stone", "place stone"],
        # Two failures, then something else: the model recovered.
        ["place stone", "place stone", "collect wood"],
    ],
)
def test_a_model_that_takes_a_step_between_its_failures_is_not_cut(answers: list[str]) -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", skill_steps=2, stuck_after=3)
    calls, _ = decide_steps(agent, answers, 12)
    assert not agent._episode(0).stopped
    assert calls > len(answers)  # asked on after the last of them


def test_the_next_request_says_the_last_skill_failed_and_why() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy")
    agent.start_episode(0, EpisodeStart("Place stone."))
    first = agent.prepare(0, observation())
    assert "failed" not in first.messages[-1].content
    agent.decide(first, ModelOutput(text="place stone"))
    request = agent.prepare(0, observation().model_copy(update={"step": 1})).messages[-1].content
    assert (
        "Your last skill failed: place stone needs 1 stone (have 0). Choose a skill that gets "
        "what is missing, not place stone again."
    ) in request


def test_stuck_after_0_never_stops_asking() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", stuck_after=0)
    assert decide_steps(agent, ["place stone"] * 12, 12)[0] == 12


def test_the_dispatcher_asks_each_prompt_with_its_own_options() -> None:
    model = MockModel(outputs=["collect wood", "drink"])
    dispatcher = Dispatcher(model, None)
    own = [ChoiceSet(options=(name, "noop"), rule="loglik") for name in ("collect wood", "drink")]
    prompts = [
        StepPrompt(slot=slot, observation=None, messages=[ChatMessage(role="user", content="?")],
                   text="", choices=choices)
        for slot, choices in enumerate(own)
    ]  # fmt: skip
    dispatcher.submit(prompts)
    answers: list[Any] = []
    while dispatcher.in_flight:
        answers += dispatcher.wait()
    dispatcher.close()
    assert [choices for _, choices in model.requests] in (own, own[::-1])
    assert {prompt.slot: output.text for prompt, output in answers} == {
        0: "collect wood",
        1: "drink",
    }


# ----------------------------------------------------------------------------- records


def skill_record(index: int, skill: str | None, outcome: str, **extra: Any) -> SkillRecord:
    return SkillRecord(
        index=index, step=index, skill=skill, label=skill or "invalid", outcome=outcome,
        parse_stage="exact" if skill else "invalid", prompt="the request", answer=skill or "?",
        **extra,
    )  # fmt: skip


def episode(
    skills: list[SkillRecord], achievements: tuple[str, ...] = (), **extra: Any
) -> EpisodeRecord:
    fields: dict[str, Any] = {
        "episode_id": "e", "goal_id": "g", "instruction": "text", "instruction_variant": 0,
        "category": "one", "seed": 0, "episode_index": 0, "success": False, "steps": 250,
        "termination": "timeout", "episode_return": 0.0, "achievements": list(achievements),
        "model_calls": len(skills), "skills": skills,
    } | extra  # fmt: skip
    return EpisodeRecord(**fields)


def test_skill_records_round_trip_through_json() -> None:
    record = episode(
        [
            skill_record(
                0, "craft wood_pickaxe", "failed", reason="needs 1 wood", prerequisite=True
            ),
            skill_record(1, None, "invalid", reason="not a skill"),
        ]
    )
    assert EpisodeRecord.model_validate_json(record.model_dump_json()) == record


def goal(required: tuple[str, ...], forbidden: tuple[str, ...] = ()) -> Goal:
    return Goal(
        id="_".join(required), split="easy_train",
        category="one" if len(required) == 1 and not forbidden else "combo", instruction="text",
        paraphrases=(), required=required, forbidden=forbidden,
    )  # fmt: skip


def test_what_a_failed_episode_got_wrong() -> None:
    pickaxe = goal(("MAKE_WOOD_PICKAXE",), ("COLLECT_SAPLING",))
    craft_early = skill_record(0, "craft wood_pickaxe", "failed", prerequisite=True)
    craft_late = skill_record(2, "craft wood_pickaxe", "out_of_steps")
    wood = skill_record(1, "collect wood", "succeeded")

    def error(skills: list[SkillRecord], **extra: Any) -> str | None:
        return skill_error(episode(skills, **extra), pickaxe, CLASSIC, "easy")

    assert error([craft_early, wood, craft_late], achievements=("COLLECT_SAPLING",)) == (
        "forbidden_unlocked"
    )
    gave_up = skill_record(
        0, None, "invalid", reason="x; 3 invalid answers in a row: no more skills are asked"
    )
    assert error([gave_up]) == "invalid_answers"
    stuck = skill_record(
        2, "craft wood_pickaxe", "failed", prerequisite=True,
        reason="needs 1 wood (have 0); chosen 3 times with no step taken since: no more skills "
        "are asked",
    )  # fmt: skip
    assert error([craft_early, craft_early, stuck]) == "stuck_repeating"
    # The steps after the stop asked nothing: 250 steps, the last decision at step 2.
    assert model_calls_saved(episode([craft_early, craft_early, stuck])) == 247
    assert model_calls_saved(episode([craft_early, wood, craft_late])) == 0
    assert error([wood, skill_record(1, "eat", "succeeded")]) == "goal_misread"
    assert error([craft_early]) == "missing_prerequisite"
    assert error([craft_early, wood, craft_late]) == "wrong_order"
    assert error([wood, craft_late]) == "out_of_steps"
    assert error([wood, craft_late], termination="death") == "died"
    won = episode([wood], success=True, termination="success")
    assert skill_error(won, pickaxe, CLASSIC, "easy") is None
    line = BuildLineGoal(
        id="l", scenario="medium", split="medium_train", instruction="t", paraphrases=(), block="STONE", size=3,
        diagonal=True,
    )  # fmt: skip
    wrong_shape = episode([skill_record(0, "build line stone 3", "succeeded")])
    right_shape = episode([skill_record(0, "build line stone 3 diagonal", "out_of_steps")])
    assert skill_error(wrong_shape, line, CLASSIC, "medium") == "goal_misread"
    assert skill_error(right_shape, line, CLASSIC, "medium") == "out_of_steps"


# ----------------------------------------------------------------------------- scripted runs

MAX_STEPS = 30


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=CLASSIC, max_steps=MAX_STEPS))


def play(
    tmp_path: Path,
    env: CrafTextEnv,
    the_goal: AnyGoal,
    answers: list[str],
    difficulty: str,
    variant: str = "classic",
) -> tuple[EpisodeRecord, Path]:
    """The one episode of a skills run on `the_goal`, the model answering `answers` in turn."""
    path = Dataset(
        source=DatasetSource(kind="json", path="hand-built"), goals=(the_goal,)
    ).save_json(tmp_path / "goals.json")
    out = tmp_path / "run"
    settings = {
        "agent": "skills", "model": "mock:", "dataset": str(path), "variant": variant,
        "difficulty": difficulty, "categories": ["one" if difficulty == "easy" else "train"],
        "paraphrases": False, "max_steps": env.config.max_steps, "batch_size": 1,
        "output_dir": str(out),
    }  # fmt: skip
    run_eval(build_config(settings), MockModel(outputs=answers, cycle=False), env=env)
    (record,) = read_episodes(out / "episodes.jsonl")
    return record, out


@pytest.mark.slow
def test_a_right_sequence_of_skills_meets_an_easy_goal_in_few_calls(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    table = goal(("PLACE_TABLE",))
    record, out = play(tmp_path, short_env, table, ["SKILL: collect wood 2", "place table"], "easy")
    assert record.success and record.skills is not None
    assert (record.skills[0].skill, record.skills[0].outcome) == ("collect wood 2", "succeeded")
    assert record.skills[1].skill == "place crafting_table"
    assert record.model_calls == 2 < record.steps
    assert record.skills[1].step == record.skills[0].step + record.skills[0].steps
    counts = action_counts(read_steps(out / "steps.jsonl"))[record.episode_id]
    assert dict(counts) == {"collect wood": 1, "place crafting_table": 1}
    results = read_results(out / "results.json")
    assert results.summary is not None and results.summary.model_calls_per_episode == 2
    assert "Model calls per episode: 2.0." in format_table(results.summary, "mock")
    (out / "steps.jsonl").unlink()  # no replays: the pages alone
    build_view(out, progress=False)
    page = (out / "report" / "episodes" / "episode-00000.html").read_text()
    assert 'id="episode-skills"' in page and "collect wood 2" in page
    assert 'id="model-calls"' in (out / "report" / "index.html").read_text()


@pytest.mark.slow
def test_a_right_sequence_of_skills_meets_a_medium_localization_goal(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    above_tree = LocalizationGoal(
        id="INSTRUCTION_PLACE_CRAFTING_TABLE_TREE_2_1", scenario="medium", split="medium_train",
        instruction="Place the crafting table one block to the top of the tree.", paraphrases=(),
        place="CRAFTING_TABLE", target="TREE", side="up", distance=1,
    )  # fmt: skip
    answers = ["collect wood 2", "place crafting_table up 1 of tree"]
    record, _ = play(tmp_path, short_env, above_tree, answers, "medium")
    assert record.success and record.model_calls == 2


@pytest.mark.slow
def test_a_missing_prerequisite_and_garbage_end_as_a_recorded_failure(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    pickaxe = goal(("MAKE_WOOD_PICKAXE",))
    answers = ["craft wood_pickaxe", *["I like turtles"] * GIVE_UP, "collect wood"]
    record, _ = play(tmp_path, short_env, pickaxe, answers, "easy")
    assert not record.success and record.termination == "timeout"
    assert record.skills is not None and record.model_calls == 1 + GIVE_UP  # then asked nothing
    first, *invalid = record.skills
    assert (first.outcome, first.reason, first.prerequisite) == (
        "failed",
        "craft wood_pickaxe needs 1 wood (have 0)",
        True,
    )
    assert [s.outcome for s in invalid] == ["invalid"] * GIVE_UP
    assert "no more skills are asked" in (invalid[-1].reason or "")
    assert record.invalid_actions == GIVE_UP
    assert skill_error(record, pickaxe, CLASSIC, "easy") == "invalid_answers"


@pytest.mark.slow
def test_a_model_stuck_on_a_skill_it_cannot_start_ends_early_as_a_recorded_failure(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    stone = goal(("PLACE_STONE",))
    record, _ = play(tmp_path, short_env, stone, ["place stone"] * MAX_STEPS, "easy")
    assert not record.success and record.steps == MAX_STEPS
    assert record.skills is not None and record.model_calls == 3  # the default stuck_after
    assert [s.skill for s in record.skills] == ["place stone"] * 3
    assert "no more skills are asked" in (record.skills[-1].reason or "")
    assert skill_error(record, stone, CLASSIC, "easy") == "stuck_repeating"
    assert model_calls_saved(record) == MAX_STEPS - 3


@pytest.mark.slow
def test_a_hard_goal_on_full_craftax_plays_the_full_catalogue(tmp_path: Path) -> None:
    env = shared_env(EnvConfig(variant=FULL, max_steps=6))
    square = BuildSquareGoal(
        id="INSTRUCTION_CRAFTING_TABLE_3", scenario="hard", split="hard_train",
        instruction="A square of tables.", paraphrases=(), block="CRAFTING_TABLE", size=3,
    )  # fmt: skip
    answers = ["build square crafting_table 3", "go to fountain"]
    record, _ = play(tmp_path, env, square, answers, "hard", variant="full")
    assert record.skills is not None and not record.success
    first, second = record.skills
    assert (first.outcome, first.reason) == (
        "failed",
        "build square crafting_table 3 needs 18 wood (have 0)",
    )
    assert (second.skill, second.outcome) == ("go to fountain", "unfinished")
