"""The agent registry and the cot / few-shot strategies: what each sends to the model."""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path

import pytest
from agent_steps import play_step
from pydantic import BaseModel, Field

from env.dataset import Goal
from env.errors import UserError
from env.variant import Variant
from llm_agents.agents import AGENTS, NoModel, agent_class, build_agent
from llm_agents.agents.strategies.cot import ChainOfThoughtAgent, estimate_tokens
from llm_agents.agents.strategies.expert import ExpertAgent
from llm_agents.agents.strategies.few_shot import FewShotAgent, load_demonstrations
from llm_agents.agents.strategies.guided import GuidedAgent
from llm_agents.agents.strategies.noop import NoopAgent
from llm_agents.agents.strategies.skills import SkillsAgent
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config
from llm_agents.judging.comparison import compare_runs
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.store import RunIdentity, RunResults, append_records, write_results
from prompts import PACKAGE_TEMPLATES_DIR

SNAPSHOTS = Path(__file__).resolve().parent / "snapshots"


class _Position(BaseModel):
    x: int = 10
    y: int = 10


class _Inventory(BaseModel):
    materials: dict[str, int] = Field(default_factory=dict)
    tools: list[str] = Field(default_factory=list)


class _Vitals(BaseModel):
    health: float = 9.0


class Seen(BaseModel):
    """The observation fields outcomes are read from, and a text shown as the observation."""

    text: str
    position: _Position = _Position()
    floor: int | None = None
    inventory: _Inventory = _Inventory()
    achievements: list[str] = Field(default_factory=list)
    vitals: _Vitals = _Vitals()


def text_of(observation: Seen) -> str:
    return observation.text


UPDATE_ENV = "UPDATE_SNAPSHOTS"


def goal(goal_id: str, required: tuple[str, ...], split: str = "easy_train") -> Goal:
    category = "one" if split == "easy_train" and len(required) == 1 else "combo"
    if split != "easy_train":
        category = "new_objects"
    return Goal(
        id=goal_id,
        split=split,  # type: ignore[arg-type]
        category=category,  # type: ignore[arg-type]
        instruction=f"Do {goal_id.lower()}.",
        paraphrases=(),
        required=required,
    )


def check_snapshot(name: str, text: str) -> None:
    path = SNAPSHOTS / name
    if os.environ.get(UPDATE_ENV):
        path.write_text(text, encoding="utf-8")
    assert path.is_file(), f"no snapshot {path}; create it with {UPDATE_ENV}=1"
    assert text == path.read_text(encoding="utf-8"), (
        f"{name} changed; regenerate with {UPDATE_ENV}=1"
    )


def conversation_text(messages: list) -> str:
    return "".join(f"=== {m.role} ===\n{m.content}\n" for m in messages)


# ------------------------------------------------------------------------------------ registry


def test_registry_names_every_strategy_and_whether_it_needs_a_model() -> None:
    assert set(AGENTS) == {"zero-shot", "cot", "few-shot", "expert", "guided", "noop", "skills"}
    assert agent_class("zero-shot") is ZeroShotAgent
    assert agent_class("cot") is ChainOfThoughtAgent
    assert agent_class("few-shot") is FewShotAgent
    assert agent_class("expert") is ExpertAgent
    assert agent_class("guided") is GuidedAgent
    assert agent_class("noop") is NoopAgent
    assert agent_class("skills") is SkillsAgent
    needs_model = {name: agent_class(name).needs_model for name in AGENTS}
    assert needs_model == {
        "zero-shot": True,
        "cot": True,
        "few-shot": True,
        "expert": False,
        "guided": True,
        "noop": False,
        "skills": True,
    }


def test_unknown_agent_is_a_user_error_with_a_suggestion() -> None:
    with pytest.raises(UserError, match="did you mean few-shot"):
        agent_class("fewshot")
    with pytest.raises(UserError, match="agent"):
        build_config({"agent": "genius"})
    with pytest.raises(UserError, match="demos"):
        build_config({"agent": "few-shot"})


def test_build_agent_follows_the_config() -> None:
    config = build_config(
        {"agent": "cot", "variant": "classic", "cot_steps": 2, "choice": "loglik"}
    )
    agent = build_agent(config)
    assert isinstance(agent, ChainOfThoughtAgent)
    assert agent.keep_steps == 2 and agent.choices is not None and len(agent.choices.options) == 17
    expert = build_agent(build_config({"agent": "expert", "variant": "classic"}))
    assert isinstance(expert, ExpertAgent) and expert.fallback_id == 0


def test_no_model_answers_nothing_for_agents_that_decide_alone() -> None:
    outputs = NoModel().generate([[], []])
    assert [(o.text, o.finish_reason) for o in outputs] == [("", "stop"), ("", "stop")]
    assert NoModel().info() == {"backend": "none"}


# ------------------------------------------------------------------------------------ cot


def test_cot_keeps_the_last_k_replies_as_assistant_turns() -> None:
    replies = iter(
        [f"reasoning {i}\nACTION: {a}" for i, a in enumerate(["LEFT", "DO", "UP", "DO"])]
    )
    model = MockModel(outputs=lambda conversation: next(replies))
    agent = ChainOfThoughtAgent(Variant.CLASSIC, renderer=text_of, steps=2)
    agent.start_episode(0, EpisodeStart("collect wood"))
    for observation in ["grass", "tree east", "tree north", "wood 1"]:
        play_step(agent, model, [0], [Seen(text=observation)])
    last = model.requests[-1][0]
    assert [m.role for m in last] == ["system", "user", "assistant", "user", "assistant", "user"]
    assert last[2].content == "reasoning 1\nACTION: DO"
    assert last[4].content == "reasoning 2\nACTION: UP"
    assert "Think step by step" in last[-1].content and "wood 1" in last[-1].content
    assert [m.role for m in model.requests[0][0]] == ["system", "user"]


def test_cot_token_cap_drops_old_replies_and_keeps_the_end_of_a_long_one() -> None:
    agent = ChainOfThoughtAgent(Variant.CLASSIC, renderer=str, steps=3, max_tokens=6)
    agent.start_episode(0, EpisodeStart("x"))
    agent._replies[0] = [(0, "a" * 100), (1, "b" * 20 + "ACTION: DO"), (2, "c" * 8)]
    kept = agent.kept_replies(0)
    assert kept[-1] == (2, "c" * 8)
    assert kept[0][0] == 1 and kept[0][1].endswith("ACTION: DO") and kept[0][1].startswith("...")
    assert sum(estimate_tokens(reply.removeprefix("...")) for _, reply in kept) <= 6
    assert len(kept) == 2  # the oldest reply no longer fits at all


def test_cot_prompt_snapshot() -> None:
    replies = iter(["The tree is east.\nACTION: RIGHT", "Facing it.\nACTION: DO"])
    model = MockModel(outputs=lambda conversation: next(replies))
    agent = ChainOfThoughtAgent(Variant.CLASSIC, renderer=text_of, steps=2)
    agent.start_episode(0, EpisodeStart("Collect wood."))
    for observation in ["A tree is 1 east.", "You face a tree."]:
        play_step(
            agent, model, [0], [Seen(text=observation, position=_Position(x=len(observation)))]
        )
    messages, _ = agent.build_messages(0, Seen(text="You face a tree. Inventory: wood 1."))
    check_snapshot("prompt_cot_classic.txt", conversation_text(messages))


# ------------------------------------------------------------------------------------ few-shot


def make_expert_run(run_dir: Path, renderer: str = "objects", agent: str = "expert") -> Path:
    """An expert run folder: two successful training episodes, one test one and one failure."""
    run_dir.mkdir(parents=True)
    config = build_config({"agent": agent, "variant": "classic", "renderer": renderer})
    episodes = [
        ("one/COLLECT_WOOD/0/0", "COLLECT_WOOD", "one", True, 3),
        ("combo/TABLE_AND_WOOD/0/0", "TABLE_AND_WOOD", "combo", True, 5),
        ("new_objects/EAT_COW/0/0", "EAT_COW", "new_objects", True, 2),
        ("one/COLLECT_DRINK/0/0", "COLLECT_DRINK", "one", False, 4),
    ]
    records, steps = [], []
    for index, (episode_id, goal_id, category, success, length) in enumerate(episodes):
        records.append(
            EpisodeRecord.model_validate(
                {
                    "episode_id": episode_id,
                    "goal_id": goal_id,
                    "instruction": f"Do {goal_id.lower()}.",
                    "instruction_variant": 0,
                    "category": category,
                    "seed": 0,
                    "episode_index": index,
                    "success": success,
                    "steps": length,
                    "termination": "success" if success else "timeout",
                    "episode_return": 1.0,
                }
            )
        )
        for step in range(length):
            steps.append(
                StepRecord(
                    episode_id=episode_id,
                    step=step,
                    observation=f"{goal_id} view {step}",
                    prompt_hash="",
                    raw_output="DO",
                    action_name="DO" if step % 2 else "LEFT",
                    action_id=5 if step % 2 else 1,
                    parse_stage="exact",
                    fallback_used=False,
                    reward=0.0,
                    done=step == length - 1,
                )
            )
    append_records(run_dir / "episodes.jsonl", records)
    append_records(run_dir / "steps.jsonl", steps)
    write_results(
        run_dir / "results.json",
        RunResults(
            config=config.model_dump(mode="json"),
            identity=RunIdentity(settings={}, templates={}),
            schedule=[record.episode_id for record in records],
            finished=len(records),
            status="complete",
            started_at=datetime.now(UTC),
        ),
    )
    return run_dir


def test_few_shot_demonstrations_come_from_other_training_goals(tmp_path: Path) -> None:
    run = make_expert_run(tmp_path / "expert")
    agent = FewShotAgent(Variant.CLASSIC, renderer="objects", demos=run, steps=4)
    agent.start_episode(
        0, EpisodeStart("Collect wood.", goal=goal("COLLECT_WOOD", ("COLLECT_WOOD",)))
    )
    demos = agent.demonstrations(0)
    # COLLECT_WOOD is the evaluated goal, EAT_COW a test goal, COLLECT_DRINK failed.
    assert [d.goal_id for d in demos] == ["TABLE_AND_WOOD"]
    assert [s.step for s in demos[0].steps] == [1, 2, 3, 4]
    agent.start_episode(
        1, EpisodeStart("x", goal=goal("EAT_COW", ("EAT_COW",), split="easy_test_other_params"))
    )
    picked = agent.demonstrations(1)
    assert [d.goal_id for d in picked] == ["COLLECT_WOOD", "TABLE_AND_WOOD"]
    assert sum(len(d.steps) for d in picked) == 4
    assert all(d.goal_id != "EAT_COW" for d in picked)


def test_few_shot_rejects_demonstrations_it_cannot_use(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="renderer"):
        load_demonstrations(
            make_expert_run(tmp_path / "grid", renderer="grid"), "objects", "classic"
        )
    with pytest.raises(UserError, match="not the expert"):
        load_demonstrations(make_expert_run(tmp_path / "llm", agent="cot"), "objects", "classic")
    with pytest.raises(UserError, match=r"no results\.json"):
        load_demonstrations(tmp_path, "objects", "classic")
    with pytest.raises(UserError, match="demonstrations"):
        FewShotAgent(Variant.CLASSIC)
    agent = FewShotAgent(Variant.CLASSIC, demos=make_expert_run(tmp_path / "ok"))
    with pytest.raises(UserError, match="goal record"):
        agent.start_episode(0, EpisodeStart("text only"))


def test_few_shot_prompt_snapshot(tmp_path: Path) -> None:
    run = make_expert_run(tmp_path / "expert")
    agent = FewShotAgent(Variant.CLASSIC, renderer="objects", demos=run, steps=3)
    model = MockModel(outputs=["DO"])
    agent.start_episode(
        0, EpisodeStart("Collect wood.", goal=goal("COLLECT_WOOD", ("COLLECT_WOOD",)))
    )
    agent.render_observation = text_of
    play_step(agent, model, [0], [Seen(text="A tree is 1 east.")])
    messages = model.requests[0][0]
    assert [m.role for m in messages] == ["system", "user"]
    assert "TABLE_AND_WOOD view 4" in messages[1].content
    assert "COLLECT_WOOD view" not in messages[1].content
    check_snapshot("prompt_few_shot_classic.txt", conversation_text(messages))


@pytest.mark.parametrize(
    ("agent", "template"),
    [
        ("zero-shot", "step"),
        ("cot", "step_cot"),
        ("cot", "cot_turn"),
        ("few-shot", "few_shot"),
        ("few-shot", "step"),
    ],
)
def test_a_broken_template_of_any_strategy_stops_the_run_before_anything_is_written(
    agent: str, template: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from llm_agents.cli import EXIT_USER_ERROR, main

    demos = make_expert_run(tmp_path / "expert")
    templates = tmp_path / "templates"
    templates.mkdir()
    (templates / f"{template}.j2").write_text("{{ no_such_variable }}\n")
    out = tmp_path / "run"
    argv = [
        "eval", "--model", "mock:", "--agent", agent, "--demos", str(demos),
        "--variant", "classic", "--categories", "combo", "--max-steps", "2", "--limit", "1",
        "--templates-dir", str(templates), "--output-dir", str(out), "--no-progress",
    ]  # fmt: skip
    assert main(argv) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert f"{template}.j2" in err and "no_such_variable" in err
    assert not out.exists()


def _broken_templates(folder: Path, names: set[str]) -> Path:
    folder.mkdir()
    for name in names:
        (folder / f"{name.removesuffix('.j2')}.j2").write_text("{{ no_such_variable }}\n")
    return folder


def _render_every_prompt(name: str, templates: Path, demos: Path) -> None:
    """Everything an agent renders over two steps, through the paths a run renders it with."""
    settings = {"agent": name, "variant": "classic", "templates_dir": str(templates)}
    agent = build_agent(
        build_config(settings | ({"demos": str(demos)} if name == "few-shot" else {}))
    )
    wood = goal("COLLECT_WOOD", ("COLLECT_WOOD",))
    agent.check_templates("Collect wood.", None, wood)
    if isinstance(agent, ZeroShotAgent):
        agent.render_observation = text_of
        agent.start_episode(0, EpisodeStart("Collect wood.", goal=wood))
        model = MockModel(outputs=["thinking\nACTION: DO"])
        for text in ("grass", "a tree east"):
            play_step(agent, model, [0], [Seen(text=text)])


PACKAGED = {path.stem for path in PACKAGE_TEMPLATES_DIR.glob("*.j2")}


@pytest.mark.parametrize("name", list(AGENTS))
def test_an_agent_renders_no_template_but_those_it_declares(name: str, tmp_path: Path) -> None:
    """The run identity hashes only the declared templates: any other may break unnoticed."""
    declared = {t.removesuffix(".j2") for t in agent_class(name).templates}
    assert declared <= PACKAGED
    broken = _broken_templates(tmp_path / "templates", PACKAGED - declared)
    _render_every_prompt(name, broken, make_expert_run(tmp_path / "expert"))


@pytest.mark.parametrize(
    ("name", "template"),
    [(name, template) for name in AGENTS for template in agent_class(name).templates],
)
def test_every_declared_template_is_rendered(name: str, template: str, tmp_path: Path) -> None:
    broken = _broken_templates(tmp_path / "templates", {template})
    with pytest.raises(UserError, match=rf"/{template.removesuffix('.j2')}\.j2 "):
        _render_every_prompt(name, broken, make_expert_run(tmp_path / "expert"))


# ------------------------------------------------------------------------------------ report


def test_report_compares_every_run_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from llm_agents.cli import EXIT_USER_ERROR, main

    expert = make_expert_run(tmp_path / "expert")
    model_run = make_expert_run(tmp_path / "model", agent="zero-shot")
    other = make_expert_run(tmp_path / "other", agent="cot")
    assert main(["report", str(model_run), "--compare", str(expert), "--compare", str(other)]) == 0
    labels = [line.split("|")[0].strip() for line in capsys.readouterr().out.splitlines()[2:5]]
    assert "(zero-shot" in labels[0]
    assert labels[1].startswith("expert (scripted")
    assert "(cot" in labels[2]
    code = main(["report", str(model_run), "--compare", str(expert), "--success-rule", "official"])
    assert code == EXIT_USER_ERROR
    assert "--success-rule re-scores one run" in capsys.readouterr().err


def test_compare_puts_the_other_run_beside(tmp_path: Path) -> None:
    expert = make_expert_run(tmp_path / "expert")
    model_run = make_expert_run(tmp_path / "model", agent="zero-shot")
    table = compare_runs(model_run, expert)
    lines = table.splitlines()
    assert lines[0].startswith("Run") and "New objects" in lines[0]
    assert lines[2].startswith("hf:smollm2-135m (zero-shot")
    assert lines[3].startswith("expert (scripted, no model)")
    assert "Qwen QwQ-32B (published)" in table
    assert "different datasets" not in table


def test_a_run_of_an_agent_that_asks_no_model_is_not_labelled_with_one(tmp_path: Path) -> None:
    noop = make_expert_run(tmp_path / "noop", agent="noop")
    model_run = make_expert_run(tmp_path / "model", agent="zero-shot")
    lines = compare_runs(model_run, noop).splitlines()
    assert lines[2].startswith("hf:smollm2-135m (zero-shot")
    assert lines[3].startswith("noop (NOOP only, no model)")
