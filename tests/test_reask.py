"""`card --verify --reask K`: each chosen step's prompt rebuilt from a greedy run's records and its
model asked again. Answers it gives again count as the same; an answer edited in the records
(one that still parses to the recorded action, so the replay passes) is named; runs it cannot
ask again are refused in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from llm_agents.agents import NoModel
from llm_agents.backends import get_model
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.run_view import read_run
from llm_agents.evaluation.runner import run_eval
from llm_agents.judging.reask import reask

# Answers picked by the prompt's hash: the same prompt always gets the same answer, as a greedy
# model's would.
SCRIPT = "mock:hash:ACTION: DO|ACTION: LEFT|I go RIGHT|ACTION: UP|ACTION: DO|hmm|DOWN"


def _run(out: Path, **settings: Any) -> Path:
    config = build_config(
        {
            "categories": ["combo"],
            "max_steps": 12,
            "batch_size": 3,
            "limit": 3,
            "output_dir": str(out),
            **settings,
        }
    )
    if config.agent == "expert":
        run_eval(config, NoModel())
    else:
        with get_model(config.model, config.generation) as model:
            run_eval(config, model)
    return out


@pytest.fixture(scope="module")
def greedy_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = _run(tmp_path_factory.mktemp("runs") / "greedy", protocol="default", model=SCRIPT)
    assert main(["card", str(run), "--no-progress"]) == 0
    return run


def _steps(run: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (run / "steps.jsonl").read_text().splitlines()]


def _verify(run: Path, *extra: str) -> int:
    return main(["card", "--verify", str(run / "card.json"), str(run), "--no-progress", *extra])


def test_the_model_gives_every_recorded_answer_again(greedy_run: Path, capsys: Any) -> None:
    capsys.readouterr()
    assert _verify(greedy_run, "--reask", "5", "--reask-seed", "3") == 0
    out = capsys.readouterr().out
    assert "matches" in out
    assert "5 of 5 answers are the recorded ones" in out
    # Every answered step, asked again in one go: the choice covers the whole run.
    answered = len(_steps(greedy_run))
    found = reask(read_run(greedy_run), 10_000)
    assert (found.asked, found.same, found.not_rebuilt) == (answered, answered, [])


def test_an_answer_edited_in_the_records_is_named(
    greedy_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = tmp_path / "edited"
    shutil.copytree(greedy_run, run)
    steps = _steps(run)
    # Written otherwise but read as the same action: the replay and the re-parse accept it.
    edited = next(s for s in steps if s["raw_output"] == "ACTION: LEFT")
    edited["raw_output"] = "I move LEFT"
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    capsys.readouterr()
    assert _verify(run, "--reask", "10000") == 0
    out = capsys.readouterr().out
    assert "matches" in out
    step = f"episode {edited['episode_id']} step {edited['step']}"
    assert f"differs: {step}: recorded 'I move LEFT', now 'ACTION: LEFT'" in out
    found = reask(read_run(run), 10_000)
    assert found.same < found.asked + len(found.not_rebuilt) == len(steps)


def _one_error(capsys: Any) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    return lines[0]


def test_runs_that_cannot_be_asked_again_are_refused_in_one_line(
    greedy_run: Path, tmp_path: Path, capsys: Any
) -> None:
    sampled = _run(tmp_path / "sampled", protocol="paper", model=SCRIPT)
    expert = _run(tmp_path / "expert", protocol="default", agent="expert")
    for run in (sampled, expert):
        assert main(["card", str(run), "--no-progress"]) == 0
    capsys.readouterr()
    before = {path: path.stat().st_mtime_ns for path in tmp_path.rglob("*")}

    assert _verify(sampled, "--reask", "3") == 2
    assert "needs a greedy run" in (line := _one_error(capsys)) and "temperature 0.7" in line
    assert _verify(expert, "--reask", "3") == 2
    assert "asked none" in _one_error(capsys)
    assert _verify(greedy_run, "--reask", "0") == 2
    assert "at least 1" in _one_error(capsys)
    assert main(["card", str(greedy_run), "--reask", "3"]) == 2
    assert "--verify" in _one_error(capsys)

    assert {path: path.stat().st_mtime_ns for path in tmp_path.rglob("*")} == before


@pytest.mark.parametrize(
    "spec", ["openai:m@https://user:***@example.invalid/v1", "hf:/no/such/model/folder"]
)
def test_a_model_not_at_hand_is_refused(greedy_run: Path, tmp_path: Path, spec: str) -> None:
    from env.errors import UserError

    run = tmp_path / "moved"
    shutil.copytree(greedy_run, run)
    results = json.loads((run / "results.json").read_text())
    results["config"]["model"] = spec
    (run / "results.json").write_text(json.dumps(results))
    with pytest.raises(UserError, match="is not at hand here"):
        reask(read_run(run), 2)
