"""A run's numbers can be trusted: backend failures are recorded and never scored, a directory
is resumed only by the same run (by content), and the summary covers exactly the schedule."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from llm_agents.backends.base import ChatMessage, ModelOutput
from llm_agents.backends.mock import MockModel
from llm_agents.cli import EXIT_BACKEND_FAILURE, EXIT_USER_ERROR, main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import BackendFailure, run_eval
from llm_agents.run_data.store import read_episodes, read_results

MAX_STEPS = 6
SCRIPT = "mock:hash:ACTION: LEFT|I will go RIGHT|<action>DO</action>|zzz"


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))


def config(out: Path, **overrides: Any) -> Any:
    settings = {
        "model": SCRIPT,
        "variant": "classic",
        "categories": ["combo", "new_objects"],
        "max_steps": MAX_STEPS,
        "batch_size": 3,
        "limit": 6,
        "output_dir": str(out),
    }
    return build_config(settings | overrides)


class FailingFor(MockModel):
    """The hash mock, except that every answer for the chosen instructions fails."""

    def __init__(self, instructions: Sequence[str]):
        super().__init__(SCRIPT.removeprefix("mock:"))
        self.failing = set(instructions)

    def _answer(self, conversation: Sequence[ChatMessage], choices: Any) -> ModelOutput:
        answer = super()._answer(conversation, choices)
        if any(text in conversation[-1].content for text in self.failing):
            return ModelOutput(text="", finish_reason="error", error="HTTP 503: overloaded")
        return answer


def canonical(run_dir: Path) -> list[dict[str, Any]]:
    return sorted(
        (e.model_dump() for e in read_episodes(run_dir / "episodes.jsonl")),
        key=lambda e: e["episode_id"],
    )


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_failed_answers_are_recorded_not_scored_and_replayed_on_resume(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    reference = tmp_path / "reference"
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(reference), model, env=short_env)
    episodes = canonical(reference)
    broken = episodes[1]["instruction"]

    flaky = tmp_path / "flaky"
    run_eval(config(flaky), FailingFor([broken]), env=short_env)

    results = read_results(flaky / "results.json")
    assert results.status == "partial" and results.finished == len(episodes) - 1
    assert results.backend_errors.failed_calls == 1
    assert results.backend_errors.aborted_episodes == [episodes[1]["episode_id"]]
    assert results.backend_errors.last_error == "HTTP 503: overloaded"
    assert results.summary is not None and results.summary.overall.episodes == len(episodes) - 1
    assert broken not in {e["instruction"] for e in canonical(flaky)}
    steps = [json.loads(line) for line in (flaky / "steps.jsonl").read_text().splitlines()]
    failed = [s for s in steps if s["finish_reason"] == "error"]
    assert [s["error"] for s in failed] == ["HTTP 503: overloaded"]
    assert all(s["error"] is None and s["cached"] is False for s in steps if s not in failed)

    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(flaky), model, env=short_env)
    assert read_results(flaky / "results.json").status == "complete"
    assert canonical(flaky) == episodes
    steps = [json.loads(line) for line in (flaky / "steps.jsonl").read_text().splitlines()]
    assert not [s for s in steps if s["finish_reason"] == "error"]
    assert len(steps) == sum(e["steps"] for e in episodes)


def test_the_circuit_breaker_stops_the_run_and_keeps_what_finished(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    script = "list:" + "|".join(["NOOP"] * (MAX_STEPS + 1))
    with pytest.raises(BackendFailure, match="3 failed model answers in a row"):
        run_eval(
            config(tmp_path, model=f"mock:{script}", max_consecutive_failures=3, batch_size=1),
            MockModel(script),
            env=short_env,
        )
    results = read_results(tmp_path / "results.json")
    assert results.status == "failed"
    assert results.failure is not None and "mock script exhausted" in results.failure
    assert results.finished == 1 and results.backend_errors.failed_calls == 3
    assert len(read_episodes(tmp_path / "episodes.jsonl")) == 1


def test_a_backend_that_keeps_failing_exits_non_zero_with_one_line(
    tmp_path: Path, capsys: Any
) -> None:
    argv = [
        "eval", "--model", "mock:list:NOOP", "--variant", "classic", "--categories", "combo",
        "--max-steps", str(MAX_STEPS), "--limit", "2", "--batch-size", "1",
        "--max-consecutive-failures", "2", "--output-dir", str(tmp_path), "--no-progress",
    ]  # fmt: skip
    assert main(argv) == EXIT_BACKEND_FAILURE
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "2 failed model answers in a row" in errors[0]
    assert read_results(tmp_path / "results.json").status == "failed"


def test_a_changed_template_is_refused_on_resume_and_nothing_changes(
    tmp_path: Path, short_env: CrafTextEnv, capsys: Any
) -> None:
    templates = tmp_path / "templates"
    templates.mkdir()
    from prompts import template_source

    (templates / "step.j2").write_text(template_source("step"))
    out = tmp_path / "run"
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(out, templates_dir=str(templates), limit=2), model, env=short_env)
    (templates / "step.j2").write_text(template_source("step") + "\nThink first.\n")
    before = snapshot(out)

    def argv(max_steps: int) -> list[str]:
        return [
            "eval", "--model", SCRIPT, "--variant", "classic", "--categories", "combo", "new_objects",
            "--max-steps", str(max_steps), "--batch-size", "3", "--limit", "2",
            "--templates-dir", str(templates), "--output-dir", str(out), "--no-progress",
        ]  # fmt: skip

    assert main(argv(MAX_STEPS)) == EXIT_USER_ERROR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "template step.j2 (its content changed)" in err[0]
    assert snapshot(out) == before

    assert main(argv(3)) == EXIT_USER_ERROR
    assert "max_steps (6 before, 3 now)" in capsys.readouterr().err
    assert snapshot(out) == before

    # A template this agent never renders may change: the run resumes and finishes.
    (templates / "step.j2").write_text(template_source("step"))
    (templates / "ground.j2").write_text(template_source("ground") + "\nAnswer in French.\n")
    assert main(argv(MAX_STEPS)) == 0
    assert read_results(out / "results.json").status == "complete"


def test_a_smaller_limit_on_a_finished_run_summarises_only_its_schedule(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(tmp_path, limit=4), model, env=short_env)
        outcome = run_eval(config(tmp_path, limit=2), model, env=short_env)
    results = outcome.results
    assert results.config["limit"] == 2
    assert (results.scheduled, results.finished, results.status) == (2, 2, "complete")
    assert results.summary is not None and results.summary.overall.episodes == 2
    assert len(read_episodes(tmp_path / "episodes.jsonl")) == 4


def test_a_resumed_run_counts_the_time_its_sittings_played_not_its_stops(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    run = tmp_path / "run"
    run_eval(config(run), FailingFor(["never asked"]), env=short_env)
    results = read_results(run / "results.json")
    assert results.status == "complete" and results.played_seconds is not None
    first_sitting = results.played_seconds
    assert 0 < first_sitting < 600

    # The run stopped an hour ago with its last episode unfinished, then resumes.
    episodes = (run / "episodes.jsonl").read_text().splitlines()
    (run / "episodes.jsonl").write_text("\n".join(episodes[:-1]) + "\n")
    raw = json.loads((run / "results.json").read_text())
    raw["started_at"] = "2026-01-01T00:00:00Z"
    raw["status"], raw["finished_at"] = "partial", None
    (run / "results.json").write_text(json.dumps(raw))
    with MockModel(SCRIPT.removeprefix("mock:")) as model:
        run_eval(config(run), model, env=short_env)

    resumed = read_results(run / "results.json")
    assert resumed.status == "complete" and resumed.finished_at is not None
    assert resumed.played_seconds is not None
    assert first_sitting < resumed.played_seconds < 1200
    assert (resumed.finished_at - resumed.started_at).total_seconds() > 3600
