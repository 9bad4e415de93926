"""`craftext-llm plan` end to end on the mock backend, and `eval --plans` adding plans to prompts."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from env import EnvConfig, Variant, shared_env
from env.dataset import load_dataset
from llm_agents.backends.mock import MockModel
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.store import read_episodes

PLAN = "1. Find a tree\n2. Collect wood\n3. Place a table"


def test_plan_command_writes_plans_sidecar_and_resumes(tmp_path: Path, capsys: Any) -> None:
    output = tmp_path / "plans.json"
    argv = [
        "plan", "--model", f"mock:cycle:{PLAN}", "--output", str(output),
        "--difficulty", "easy", "--categories", "paraphrased", "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    plans = json.loads(output.read_text())
    texts = {t for goal in load_dataset(None).split("easy_test_paraphrased") for t in goal.texts}
    assert set(plans) == texts
    assert all(plan == PLAN for plan in plans.values())
    sidecar = json.loads(output.with_suffix(".meta.json").read_text())
    assert "mock" in json.dumps(sidecar)
    first = capsys.readouterr().out
    assert f"{len(texts)} instructions: {len(texts)} valid" in first

    assert main(argv) == 0
    assert f"{len(texts)} resumed" in capsys.readouterr().out


@pytest.mark.parametrize("names", [["new_objects"], ["easy_test_other_params"]])
def test_plan_command_keeps_splits_as_a_deprecated_spelling(
    tmp_path: Path, capsys: Any, names: list[str]
) -> None:
    # `--splits` took dataset split names before plan spoke eval's vocabulary.
    output = tmp_path / "plans.json"
    argv = [
        "plan", "--model", f"mock:cycle:{PLAN}", "--output", str(output),
        "--splits", *names, "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    texts = {t for goal in load_dataset(None).split("easy_test_other_params") for t in goal.texts}
    assert set(json.loads(output.read_text())) == texts
    assert "--splits is deprecated; use --categories" in capsys.readouterr().err


def test_plan_command_rejects_an_unknown_split(tmp_path: Path, capsys: Any) -> None:
    argv = [
        "plan",
        "--model",
        "mock:noop",
        "--output",
        str(tmp_path / "p.json"),
        "--splits",
        "hardest",
    ]
    assert main(argv) == EXIT_USER_ERROR
    assert "hardest" in capsys.readouterr().err


@pytest.mark.slow
def test_eval_with_plans_puts_each_plan_in_its_prompt_and_reports_the_missing(
    tmp_path: Path,
) -> None:
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=3))
    config = build_config(
        {
            "model": "mock:noop",
            "variant": "classic",
            "splits": ["combo"],
            "max_steps": 3,
            "batch_size": 2,
            "limit": 2,
            "output_dir": str(tmp_path / "run"),
        }
    )
    planned = load_dataset(None).instructions(["combo"])[0].text
    plans_file = tmp_path / "plans.json"
    plans_file.write_text(json.dumps({planned: PLAN}))
    config.plans = str(plans_file)
    model = MockModel(outputs=["ACTION: NOOP"])
    outcome = run_eval(config, model, env=env)

    episodes = {e.instruction: e for e in read_episodes(tmp_path / "run" / "episodes.jsonl")}
    assert episodes[planned].plan_given
    assert sum(e.plan_given for e in episodes.values()) == 1
    for messages, _ in model.requests:
        user = messages[-1].content
        assert (PLAN in user) == (planned in user)
    total = len(load_dataset(None).instructions(["combo"]))
    assert len(outcome.missing_plans) == total - 1
    assert planned not in outcome.missing_plans
