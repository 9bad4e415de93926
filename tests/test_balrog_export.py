"""`export --format balrog`: a complete balrog-protocol run as a BALROG submission folder that
reads back into the same numbers; anything else refused with one line, nothing written."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import pytest
import yaml

from env.craftax_names import CLASSIC_ACHIEVEMENTS
from env.open_ended import OPEN_ENDED_ID, OPEN_ENDED_TEXT
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config
from llm_agents.judging.balrog_export import (
    export_balrog,
    read_balrog_submission,
    submission_scores,
)
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import score_run
from llm_agents.run_data.store import RunIdentity, RunResults, append_records, write_results


def _episode(index: int, unlocked: int) -> EpisodeRecord:
    return EpisodeRecord(
        episode_id=f"combo/{OPEN_ENDED_ID}/0/{index}",
        goal_id=OPEN_ENDED_ID,
        instruction=OPEN_ENDED_TEXT,
        instruction_variant=0,
        category="combo",
        seed=100 + index,
        episode_index=index,
        success=False,
        steps=2000 - 7 * index,
        termination="timeout" if index % 2 else "death",
        episode_return=float(unlocked),
        prompt_tokens=10 * index,
        completion_tokens=index,
        achievements=list(CLASSIC_ACHIEVEMENTS[:unlocked]),
    )


def _balrog_run(path: Path, *, status: str = "complete", **settings: object) -> Path:
    config = build_config({"protocol": "balrog", "model": "hf:some/model", **settings})
    # Written in an order other than the schedule's, as parallel episodes finish.
    episodes = [_episode(i, n) for i, n in enumerate((3, 9, 0, 14, 5, 5, 22, 1, 8, 11))]
    finished = episodes[::-1] if status == "complete" else episodes[::-1][:7]
    path.mkdir(parents=True)
    append_records(path / "episodes.jsonl", finished)
    results = RunResults(
        config=config.model_dump(mode="json"),
        identity=RunIdentity(settings={}, templates={}),
        schedule=[e.episode_id for e in episodes],
        finished=len(finished),
        status=status,  # type: ignore[arg-type]
        started_at=datetime(2026, 1, 2, tzinfo=UTC),
        finished_at=datetime(2026, 1, 3, tzinfo=UTC) if status == "complete" else None,
    )
    write_results(path / "results.json", results)
    return path


def test_an_exported_run_reads_back_into_the_same_numbers(tmp_path: Path) -> None:
    run = _balrog_run(tmp_path / "run")
    out = export_balrog(run, tmp_path / "submission")
    files = sorted((out / "crafter" / "default").iterdir())
    assert [f.name for f in files] == [f"default_run_{i:02d}.json" for i in range(10)]
    first = json.loads(files[0].read_text())
    assert list(first["achievements"]) == sorted(first["achievements"])
    assert len(first["achievements"]) == 22
    assert (first["task"], first["num_steps"], first["seed"]) == ("default", 2000, 100)
    assert first["score"] == 3 and first["progression"] == 3 / 22
    back = read_balrog_submission(out)
    ours = score_run([_episode(i, n) for i, n in enumerate((3, 9, 0, 14, 5, 5, 22, 1, 8, 11))])
    assert back.episodes_played == 10
    assert back.progression_percentage == pytest.approx(ours.overall.progression, abs=1e-9)
    assert back.standard_error == pytest.approx(ours.overall.progression_stderr, abs=1e-9)
    assert back.final_score == back.progression_percentage
    assert submission_scores(back) == pytest.approx(
        (back.progression_percentage, back.standard_error), abs=1e-9
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["environments"]["crafter"]["episodes_played"] == 10
    assert summary["client"]["model_id"] == "hf:some/model"
    metadata = yaml.safe_load((out / "metadata.yaml").read_text())
    assert (metadata["name"], metadata["date"]) == ("hf:some/model", "2026-01-03")
    expert = export_balrog(_balrog_run(tmp_path / "expert", agent="expert"), tmp_path / "e")
    assert yaml.safe_load((expert / "metadata.yaml").read_text())["name"].startswith("expert")
    assert json.loads((expert / "summary.json").read_text())["client"]["model_id"] is None


@pytest.mark.parametrize(
    ("make", "why"),
    [
        (lambda p: _balrog_run(p, status="partial"), "it is partial (7 of 10 episodes)"),
        (lambda p: _balrog_run(p, protocol="default"), "played under --protocol default"),
    ],
)
def test_a_run_that_is_not_a_complete_balrog_run_is_refused_with_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: object, why: str
) -> None:
    run = make(tmp_path / "run")  # type: ignore[operator]
    out = tmp_path / "submission"
    assert main(["export", "--format", "balrog", str(run), str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err and "not a complete balrog-protocol run" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_an_overridden_protocol_or_a_used_folder_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cheap = build_config({"protocol": "balrog", "max_steps": 300})
    assert cheap.protocol_overrides == ("max_steps",)
    run = _balrog_run(tmp_path / "cheap", max_steps=300)
    assert main(["export", "--format", "balrog", str(run), str(tmp_path / "a")]) == 2
    assert "overrode the balrog protocol's max_steps" in capsys.readouterr().err
    good = _balrog_run(tmp_path / "good")
    used = tmp_path / "used"
    used.mkdir()
    (used / "x").write_text("mine")
    assert main(["export", "--format", "balrog", str(good), str(used)]) == 2
    assert "not an empty directory" in capsys.readouterr().err
    assert [p.name for p in used.iterdir()] == ["x"]
    assert main(["export", "--format", "balrog", str(good), str(tmp_path / "ok")]) == 0


def test_an_open_ended_run_is_reported_beside_balrogs_published_rows(
    tmp_path: Path, shared_data: Path
) -> None:
    from llm_agents.judging.published import BALROG_PUBLISHED
    from llm_agents.judging.report import report_run

    text = report_run(_balrog_run(tmp_path / "run"))
    ours = score_run([_episode(i, n) for i, n in enumerate((3, 9, 0, 14, 5, 5, 22, 1, 8, 11))])
    balrog = text.split("BALROG's Crafter leaderboard")[1]
    line = next(row for row in balrog.splitlines() if row.startswith("hf:some/model (this run)"))
    assert f"{ours.overall.progression:.1f} ± {ours.overall.progression_stderr:.1f}" in line
    cells = {
        row.split("|")[0].strip(): row.split("|")[1].strip()
        for row in balrog.splitlines()
        if "|" in row
    }
    assert cells["Llama-3.2-1B-it (BALROG, published)"] == "12.7 ± 1.9"
    assert "overridden" not in balrog
    # The rows are BALROG's leaderboard entries, rounded.
    data = json.loads((shared_data / "balrog_crafter_episodes.json").read_text())
    board = {
        (s.get("leaderboard") or s["published"]["leaderboard"])["name"]: (
            s.get("leaderboard") or s["published"]["leaderboard"]
        )["crafter"]
        for s in data["submissions"] + data["summary_only_submissions"]
        if s["track"] == "LLM"
    }
    names = {
        "Grok-4": "Grok-4",
        "Gemini-2.5-Pro": "Gemini-2.5-Pro-Exp-03-25",
        "GPT-4o": "GPT-4o-2024-05-13",
        "Qwen2.5-7B-it": "Qwen-2.5-7B-it",
        "Llama-3.2-1B-it": "Llama-3.2-1B-it",
    }
    for name, progression, error in BALROG_PUBLISHED:
        published, published_error, episodes = board[names[name]]
        assert (round(published, 1), round(published_error, 1), episodes) == (
            progression,
            error,
            10,
        )
