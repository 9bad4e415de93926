"""Medium and Hard goals played end to end on the mock backend: the runner hands the env each
goal's checker encoding, and episodes are recorded and reported by goal set and scenario class."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from env.dataset import Dataset, DatasetSource, load_dataset
from env.errors import UserError
from env.goal_status import do_nothing_successes
from env.jax_cache import enable_compilation_cache
from env.official_source import parse_directory
from llm_agents.agents import NoModel
from llm_agents.backends import get_model
from llm_agents.cli import main
from llm_agents.evaluation.config import EvalConfig, build_config
from llm_agents.evaluation.runner import prepare_run, run_eval
from llm_agents.judging.report import report_run
from llm_agents.run_data.store import read_episodes, read_results
from llm_agents.viewer import build_view

#: A straight line of 2 furnaces: the official checker looks for a window without any furnace
#: (env.scenario_checker), so a fresh world meets it on the first step.
MET_AT_ONCE = "INSTRUCTION_FURNACE_2"
#: Spend 4 iron with 3 furnaces standing: out of reach in a few steps.
OUT_OF_REACH = "INSTRUCTION_PLACE_IRON_FURNACE_4_3"


@pytest.fixture(scope="module")
def medium_dataset(official_repository: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    official = parse_directory(official_repository)
    picked = tuple(
        goal
        for goal in official.goals
        if goal.split == "medium_train" and goal.id in (MET_AT_ONCE, OUT_OF_REACH)
    )
    assert len(picked) == 2
    path = tmp_path_factory.mktemp("medium") / "medium.json"
    Dataset(source=DatasetSource(kind="json", path=str(path)), goals=picked).save_json(path)
    return path


def medium_config(out: Path, dataset: Path, **overrides: object) -> EvalConfig:
    settings: dict[str, object] = {
        "model": "mock:hash:ACTION: NOOP|ACTION: LEFT",
        "difficulty": "medium",
        "categories": ["train"],
        "variant": "classic",
        "paraphrases": False,
        "max_steps": 3,
        "batch_size": 2,
        "dataset": str(dataset),
        "output_dir": str(out),
        "probe": False,
    }
    return build_config(settings | overrides)


def test_a_medium_run_scores_each_goal_with_its_own_checker(
    medium_dataset: Path, tmp_path: Path
) -> None:
    config = medium_config(tmp_path / "run", medium_dataset)
    with get_model(config.model, config.generation) as model:
        run_eval(config, model)
    episodes = {e.goal_id: e for e in read_episodes(tmp_path / "run" / "episodes.jsonl")}

    met, missed = episodes[MET_AT_ONCE], episodes[OUT_OF_REACH]
    assert (met.success, met.steps, met.termination) == (True, 1, "success")
    assert (missed.success, missed.steps, missed.termination) == (False, 3, "timeout")
    assert (met.category, met.scenario_class) == ("train", "Build")
    assert (missed.category, missed.scenario_class) == ("train", "Conditional")
    assert met.episode_id == f"train/{MET_AT_ONCE}/0/0"

    table = report_run(tmp_path / "run")
    assert "By scenario class (medium):" in table
    assert "PPO-T (published)" in table


def test_the_difficulty_is_part_of_the_runs_identity(medium_dataset: Path, tmp_path: Path) -> None:
    medium = prepare_run(medium_config(tmp_path / "run", medium_dataset))
    assert medium.identity.settings["difficulty"] == "medium"
    # The official order: line goals come before conditional placing in medium_train.
    assert [spec.episode_id for spec in medium.schedule] == [
        f"train/{MET_AT_ONCE}/0/0",
        f"train/{OUT_OF_REACH}/0/0",
    ]


def test_a_goal_the_variant_cannot_score_is_refused_before_anything_is_written(
    official_repository: Path, tmp_path: Path
) -> None:
    official = parse_directory(official_repository)
    # Hard goals name full-Craftax blocks (enchantment tables) that Classic lacks.
    data = tmp_path / "hard.json"
    official.save_json(data)
    config = medium_config(tmp_path / "run", data, difficulty="hard", variant="classic")
    with pytest.raises(
        UserError, match="needs block ENCHANTMENT_TABLE_ICE, which classic Craftax lacks"
    ):
        prepare_run(config)
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_the_do_nothing_agent_meets_what_the_do_nothing_worlds_say_and_report_leaves_it_out(
    medium_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 31: the `noop` agent's run and the cached do-nothing worlds agree (same worlds, same
    checkers), and `report --goal-status` shows the table without the goal met by doing
    nothing, beside the do-nothing row."""
    config = medium_config(tmp_path / "run", medium_dataset, agent="noop")
    run_eval(config, NoModel())
    played = {e.goal_id: e.success for e in read_episodes(tmp_path / "run" / "episodes.jsonl")}
    assert played == {MET_AT_ONCE: True, OUT_OF_REACH: False}
    results = read_results(tmp_path / "run" / "results.json")
    assert {i: a.counts for i, a in results.actions.items()} == {
        f"train/{MET_AT_ONCE}/0/0": {"NOOP": 1},
        f"train/{OUT_OF_REACH}/0/0": {"NOOP": 3},
    }
    assert results.summary is not None and results.summary.actions is not None
    assert results.summary.actions.commonest_share == 1.0

    cache = tmp_path / "cache"
    goals = list(load_dataset(medium_dataset).goals)
    worlds = do_nothing_successes(
        goals, config.env_config(), worlds=1, seed=config.seed, cache_dir=cache
    )
    assert worlds == {f"medium_train/{MET_AT_ONCE}": 1, f"medium_train/{OUT_OF_REACH}": 0}
    # Played once: the second answer is the cached one, whatever playing would give.
    [cached] = cache.iterdir()
    data = json.loads(cached.read_text())
    data["successes"][f"medium_train/{OUT_OF_REACH}"] = 7
    cached.write_text(json.dumps(data))
    again = do_nothing_successes(
        goals, config.env_config(), worlds=1, seed=config.seed, cache_dir=cache
    )
    assert again[f"medium_train/{OUT_OF_REACH}"] == 7

    monkeypatch_cache = pytest.MonkeyPatch()
    jax_cache = str(enable_compilation_cache())

    def own_project_cache() -> None:
        # A project cache of its own for the do-nothing worlds, but JAX's compiles stay where
        # they are: a fresh JAX cache would compile the env again (about 20 s).
        monkeypatch_cache.setenv("CRAFTEXT_LLM_CACHE", str(tmp_path / "project-cache"))
        monkeypatch_cache.setenv("JAX_COMPILATION_CACHE_DIR", jax_cache)

    own_project_cache()
    try:
        capsys.readouterr()
        assert (
            main(["report", str(tmp_path / "run"), "--goal-status", "--do-nothing-worlds", "1"])
            == 0
        )
    finally:
        monkeypatch_cache.undo()
    text = capsys.readouterr().out
    section = text[text.index("Trivial and impossible goals") :]
    rows = {line.split("|")[0].strip(): line for line in section.splitlines() if "|" in line}
    assert "0.00" in rows["this run, without the 1 goals below"].split("|")[1]
    assert (
        rows["do nothing (NOOP only, 1 worlds per goal)"].split("|")[1].strip().startswith("0.50")
    )
    assert f"medium_train/{MET_AT_ONCE}: met by doing nothing (1/1 worlds)" in section
    assert "Actions (4 steps, share of each, commonest first): NOOP 1.00." in text
    assert "WARNING: one action (NOOP) takes 100%" in text
    assert "one action over 80% of the steps in 2 of 2 episodes" in text

    # The HTML report shows the same tables, in their own block. (Its episode pages are left
    # without their goals: what they show of a placing goal is not this test's business.)
    own_project_cache()
    monkeypatch_cache.setattr("llm_agents.viewer.run._goals", lambda *_: {})
    try:
        outcome = build_view(tmp_path / "run", progress=False, goal_status=True, worlds=1)
    finally:
        monkeypatch_cache.undo()
    page = outcome.index.read_text()
    block = page[page.index('<div id="goal-status">') :]
    assert "do nothing (NOOP only, 1 worlds per goal)" in block
    assert f"medium_train/{MET_AT_ONCE}: met by doing nothing (1/1 worlds)" in block
    assert 'id="dominant-action"' in page


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--goal-status", "--do-nothing-worlds", "0"], "at least 1"),
        (["--goal-status", "--compare", "."], "leave out --compare"),
    ],
)
def test_goal_status_bad_input_is_one_line_exit_2(
    tmp_path: Path, flags: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "results.json").write_text("{}")
    assert main(["report", str(tmp_path), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
