"""The field's achievement scores: BALROG's own records recomputed to its published summaries,
and the formulas on hand-checkable cases."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from env.craftax_names import CLASSIC_ACHIEVEMENTS, FULL_ACHIEVEMENTS
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import score_episodes, score_run


@pytest.fixture(scope="module")
def balrog(shared_data: Path) -> dict[str, Any]:
    path = shared_data / "balrog_crafter_episodes.json"
    if not path.is_file():
        pytest.skip(f"BALROG reference records {path} are absent")
    data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return data


def _unlocked(episode: dict[str, Any]) -> list[str]:
    return [name for name, count in episode["achievements"].items() if count > 0]


def test_progression_and_error_equal_balrogs_published_summaries(balrog: dict[str, Any]) -> None:
    submissions = balrog["submissions"]
    assert len(submissions) == 18
    for submission in submissions:
        scores = score_episodes([_unlocked(e) for e in submission["episodes"]])
        published = submission["published"]
        for summary in (published["crafter_summary"], published["summary_json_crafter"]):
            assert scores.progression == pytest.approx(
                summary["progression_percentage"], abs=1e-9
            ), submission["submission"]
            assert scores.progression_stderr == pytest.approx(
                summary["standard_error"], abs=1e-9
            ), submission["submission"]
            assert scores.episodes == summary["episodes_played"]
        board = published["leaderboard"]["crafter"]
        assert (scores.progression, scores.progression_stderr) == pytest.approx(
            (board[0], board[1]), abs=1e-9
        )


def test_crafter_score_is_the_formulas_value_on_balrogs_records(balrog: dict[str, Any]) -> None:
    names = balrog["source"]["achievements"]
    for submission in balrog["submissions"]:
        episodes = submission["episodes"]
        scores = score_episodes([_unlocked(e) for e in episodes])
        # The formula written out here, on BALROG's spelling and key order.
        rates = [
            100 * sum(e["achievements"][n] > 0 for e in episodes) / len(episodes) for n in names
        ]
        expected = math.exp(sum(math.log(1 + s) for s in rates) / len(rates)) - 1
        assert scores.crafter_score == pytest.approx(expected, rel=1e-12)
        by_name = {name.lower(): rate for name, rate in scores.unlock_percent.items()}
        assert by_name == dict(zip(names, rates, strict=True))
        expected_lm = sum(math.log2(1 + p) for p in rates) / len(rates)
        assert scores.craftaxlm_score == pytest.approx(expected_lm, rel=1e-12)


def test_scores_on_hand_checked_cases() -> None:
    nothing = score_episodes([[], []])
    assert (nothing.crafter_score, nothing.craftaxlm_score, nothing.progression) == (0, 0, 0)
    everything = score_episodes([CLASSIC_ACHIEVEMENTS])
    assert everything.crafter_score == pytest.approx(100)
    assert everything.craftaxlm_score == pytest.approx(math.log2(101))
    assert (everything.progression, everything.progression_stderr) == (100, 0)
    # Two episodes: 11 of 22 and 0 -> shares 0.5 and 0: mean 25%, population std 0.25 -> SE
    # 0.25 / sqrt(2), x100.
    half = score_episodes([CLASSIC_ACHIEVEMENTS[:11], ["collect_wood_not_a_name"]])
    assert half.progression == pytest.approx(25)
    assert half.progression_stderr == pytest.approx(25 / math.sqrt(2))
    assert half.unlock_percent["COLLECT_WOOD"] == 50
    assert half.unlock_percent["COLLECT_DIAMOND"] == 0
    # Full Craftax: the same 11 are a sixth of its 67-long list.
    full = score_episodes([CLASSIC_ACHIEVEMENTS[:11]], "full")
    assert len(full.unlock_percent) == len(FULL_ACHIEVEMENTS) == 67
    assert full.progression == pytest.approx(100 * 11 / 67)
    assert "67" in full.label and "22" in score_episodes([[]]).label


def _episode(episode_id: str, category: str, achievements: list[str]) -> EpisodeRecord:
    return EpisodeRecord(
        episode_id=episode_id,
        goal_id="g",
        instruction="i",
        instruction_variant=0,
        category=category,  # type: ignore[arg-type]
        seed=0,
        episode_index=0,
        success=False,
        steps=3,
        termination="timeout",
        episode_return=0.0,
        achievements=achievements,
    )


def test_a_run_is_scored_overall_per_category_and_per_episode() -> None:
    episodes = [
        _episode("a", "one", ["COLLECT_WOOD", "PLACE_TABLE"]),
        _episode("b", "combo", []),
        _episode("c", "one", ["COLLECT_WOOD"]),
    ]
    scores = score_run(episodes, "classic")
    assert list(scores.by_category) == ["one", "combo"]
    assert scores.by_category["one"].unlock_percent["COLLECT_WOOD"] == 100
    assert scores.by_category["one"].unlock_percent["PLACE_TABLE"] == 50
    assert scores.overall.progression == pytest.approx(100 * 3 / 22 / 3)
    assert scores.by_episode["a"].unlocked == 2
    assert scores.by_episode["a"].progression == pytest.approx(100 * 2 / 22)
    assert scores.by_episode["b"].crafter_score == 0


def _run_dir(path: Path, episodes: list[EpisodeRecord], variant: str) -> Path:
    from datetime import UTC, datetime

    from llm_agents.run_data.store import RunIdentity, RunResults, append_records, write_results

    path.mkdir(parents=True)
    append_records(path / "episodes.jsonl", episodes)
    results = RunResults(
        config={"model": "hf:m", "variant": variant},
        identity=RunIdentity(settings={}, templates={}),
        schedule=[e.episode_id for e in episodes],
        finished=len(episodes),
        status="complete",
        started_at=datetime(2025, 1, 1, tzinfo=UTC),
    )
    write_results(path / "results.json", results)
    return path


def test_report_and_compare_compute_the_scores_from_the_records(tmp_path: Path) -> None:
    from llm_agents.judging.comparison import compare_runs
    from llm_agents.judging.report import report_run

    episodes = [
        _episode("a", "one", ["COLLECT_WOOD", "PLACE_TABLE"]),
        _episode("b", "one", ["COLLECT_WOOD"]),
    ]
    # No stored scores (a run recorded before they were kept): the report computes them.
    classic = _run_dir(tmp_path / "classic", episodes, "classic")
    text = report_run(classic)
    expected = score_run(episodes, "classic").overall
    assert f"{expected.progression:.1f} ± {expected.progression_stderr:.1f}" in text
    # Shares 2/22 and 1/22: mean 1.5/22 = 6.8%; population std 0.5/22, over sqrt(2): 1.6%.
    assert "6.8 ± 1.6" in text
    assert "collect_wood | 100%" in text and "place_table  | 50%" in text
    assert "Crafter's 22 achievements" in text
    full = _run_dir(tmp_path / "full", episodes, "full")
    assert "full Craftax's 67 achievements" in report_run(full)
    compared = compare_runs(classic, full)
    cells = [[c.strip() for c in line.split("|")] for line in compared.splitlines()]
    rows = {row[1]: row for row in cells if len(row) == 6 and row[1] in ("classic", "full")}
    assert rows["classic"][2] == "6.8 ± 1.6"
    assert rows["full"][2].startswith(f"{100 * 3 / 134:.1f} ±")
