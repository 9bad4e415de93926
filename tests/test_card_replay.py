"""Cards proved by replaying the run: a real expert run under the paper protocol (Classic),
tampered as a forger would (a failed episode made a consistent success, or a success through a
game-over field the replay does not produce; a winning episode's actions replaced; a failed
episode dropped from every record, or recorded twice; a world key removed or taken from another
episode; a split digest or a setting edited), is refused by `card` and by `card --verify`,
naming the episode or the field; the card's figures are the replay's and it names the settings
its records cannot show; the leaderboard ranks only replayed runs' cards."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from llm_agents.agents import NoModel
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval


@pytest.fixture(scope="module")
def expert_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "expert"
    # The ninth episode of the schedule is EAT_PLANT_NO_EAT_COW, which no player meets in 250
    # steps (a sapling ripens far later): the tamperings need a failure as well as winners.
    config = build_config(
        {"protocol": "paper", "agent": "expert", "limit": 9, "output_dir": str(out)}
    )
    run_eval(config, NoModel())
    return out


def _copy(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / run.name
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("card.*"))
    return copy


def _lines(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _write(path: Path, rows: list[dict[str, Any]]) -> None:
    path.write_text("".join(json.dumps(row) + "\n" for row in rows))


def _episode(run: Path, success: bool) -> dict[str, Any]:
    chosen = [e for e in _lines(run / "episodes.jsonl") if e["success"] is success]
    assert chosen, f"the expert run has no {'winning' if success else 'failed'} episode"
    return chosen[0]


def _one_error(capsys: Any) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    return lines[0]


def _failed_made_success(run: Path) -> str:
    from env.dataset import load_dataset

    episodes = _lines(run / "episodes.jsonl")
    target = next(e for e in episodes if not e["success"])
    goal = next(
        g for g in load_dataset(None).goals if g.id == target["goal_id"] and g.difficulty == "easy"
    )
    # Consistent: success, its termination, and the goal's missing achievements unlocked.
    target.update(success=True, termination="success")
    target["achievements"] += [a for a in goal.required if a not in target["achievements"]]
    _write(run / "episodes.jsonl", episodes)
    return str(target["episode_id"])


def _winner_made_noop(run: Path) -> str:
    winner = _episode(run, True)["episode_id"]
    steps = _lines(run / "steps.jsonl")
    for step in steps:
        if step["episode_id"] == winner:
            step.update(action_id=0, action_name="NOOP")
    _write(run / "steps.jsonl", steps)
    return str(winner)


def _failed_dropped(run: Path) -> str:
    dropped = _episode(run, False)["episode_id"]
    for name in ("episodes.jsonl", "steps.jsonl"):
        _write(run / name, [r for r in _lines(run / name) if r["episode_id"] != dropped])
    results = json.loads((run / "results.json").read_text())
    results["schedule"] = [e for e in results["schedule"] if e != dropped]
    results["scheduled"] -= 1
    results["finished"] -= 1
    results["actions"].pop(dropped, None)
    (run / "results.json").write_text(json.dumps(results))
    return str(dropped)


def _failed_met_in_new_world(run: Path) -> str:
    # The official rule's re-score reads this field: the failure would count as a success.
    episodes = _lines(run / "episodes.jsonl")
    target = next(e for e in episodes if not e["success"] and not e.get("goal_in_new_world"))
    target["goal_in_new_world"] = target["termination"]
    _write(run / "episodes.jsonl", episodes)
    return str(target["episode_id"])


def _failed_recorded_twice(run: Path) -> str:
    episodes = _lines(run / "episodes.jsonl")
    target = _episode(run, False)
    _write(run / "episodes.jsonl", [*episodes, target])
    return str(target["episode_id"])


def _world_key_removed(run: Path) -> str:
    episodes = _lines(run / "episodes.jsonl")
    episodes[0]["reset_key"] = None
    _write(run / "episodes.jsonl", episodes)
    return str(episodes[0]["episode_id"])


def _world_key_of_another(run: Path) -> str:
    episodes = _lines(run / "episodes.jsonl")
    episodes[0]["reset_key"] = episodes[1]["reset_key"]
    _write(run / "episodes.jsonl", episodes)
    return str(episodes[0]["episode_id"])


TAMPERINGS = {
    "failed made a consistent success": (_failed_made_success, "termination: recorded success"),
    "winner's actions made NOOP": (_winner_made_noop, "termination: recorded success"),
    "failed episode dropped everywhere": (_failed_dropped, "missing from episodes.jsonl"),
    "failed made a success through a game-over field": (
        _failed_met_in_new_world,
        "goal_in_new_world: recorded",
    ),
    "failed episode recorded twice": (_failed_recorded_twice, "recorded 2 times"),
    "world key removed": (_world_key_removed, "reset_key: recorded None"),
    "world key of another episode": (_world_key_of_another, "reset_key: recorded"),
}


def test_the_untouched_run_replays_and_its_card_says_so(
    expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(expert_run, tmp_path)
    assert main(["card", str(run), "--no-progress"]) == 0
    card = json.loads((run / "card.json").read_text())
    assert card["schema_version"] == 3
    assert card["replay"]["episodes"] == card["figures"]["episodes"] == 9
    assert card["replay"]["answers"] == 0  # the expert's actions are not parsed answers
    assert "Replayed**: 9 episodes" in (run / "card.md").read_text()
    # What the records cannot show is said: how the actions were chosen, and a step cap or a
    # success rule that no episode's end tested.
    unshown = card["protocol"]["unshown"]
    for setting in ("generation.temperature", "generation.max_tokens", "history_length"):
        assert any(line.startswith(f"{setting} = ") for line in unshown), unshown
    episodes = _lines(run / "episodes.jsonl")
    capped = any(e["termination"] == "timeout" and e["steps"] == 250 for e in episodes)
    assert any(line.startswith("max_steps = 250: ") for line in unshown) is not capped
    tested = any(e.get("goal_at_game_over") or e.get("goal_in_new_world") for e in episodes)
    assert any(line.startswith("success_rule = official: ") for line in unshown) is not tested
    assert "Not shown by the records" in (run / "card.md").read_text()
    capsys.readouterr()
    assert main(["card", "--verify", str(run / "card.json"), str(run), "--no-progress"]) == 0
    assert "its records replay" in capsys.readouterr().out


@pytest.mark.parametrize("tampering", list(TAMPERINGS))
def test_a_tampered_run_gets_no_card_and_fails_verification_naming_the_episode(
    expert_run: Path, tmp_path: Path, capsys: Any, tampering: str
) -> None:
    tamper, field = TAMPERINGS[tampering]
    # A card written before the tampering, then checked against the tampered records.
    honest = _copy(expert_run, tmp_path)
    assert main(["card", str(honest), "--no-progress"]) == 0
    capsys.readouterr()
    episode = tamper(honest)
    card = honest / "card.json"
    assert main(["card", "--verify", str(card), str(honest), "--no-progress"]) == 1
    line = _one_error(capsys)
    assert f"episode {episode}: " in line and field in line

    # A card asked of the tampered records: refused, nothing written.
    forged = tmp_path / "forged"
    shutil.copytree(honest, forged, ignore=shutil.ignore_patterns("card.*"))
    before = sorted(p.name for p in forged.iterdir())
    assert main(["card", str(forged), "--no-progress"]) == 1
    line = _one_error(capsys)
    assert "do not replay" in line and f"episode {episode}: " in line and field in line
    assert sorted(p.name for p in forged.iterdir()) == before


def test_the_step_log_is_checked_in_step_order_whatever_its_line_order(
    expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    # Read line by line into compact arrays: the lines' order is the play's, which interleaves
    # the episodes in flight; reversed, every episode's steps still replay.
    run = _copy(expert_run, tmp_path)
    _write(run / "steps.jsonl", _lines(run / "steps.jsonl")[::-1])
    assert main(["card", str(run), "--no-progress"]) == 0
    assert json.loads((run / "card.json").read_text())["replay"]["episodes"] == 9


def test_a_step_logged_twice_is_named(expert_run: Path, tmp_path: Path, capsys: Any) -> None:
    run = _copy(expert_run, tmp_path)
    steps = _lines(run / "steps.jsonl")
    episode = steps[0]["episode_id"]
    count = sum(step["episode_id"] == episode for step in steps)
    _write(run / "steps.jsonl", [*steps, steps[0]])
    assert main(["card", str(run), "--no-progress"]) == 1
    line = _one_error(capsys)
    assert f"episode {episode}: steps: recorded {count}, the step log holds {count + 1}" in line
    assert not (run / "card.json").exists()


def test_an_extra_episode_is_refused(expert_run: Path, tmp_path: Path, capsys: Any) -> None:
    run = _copy(expert_run, tmp_path)
    episodes = _lines(run / "episodes.jsonl")
    extra = {**episodes[0], "episode_id": "combo/NOT_A_GOAL/0/0", "episode_index": 99}
    _write(run / "episodes.jsonl", [*episodes, extra])
    assert main(["card", str(run), "--no-progress"]) == 1
    assert "episode combo/NOT_A_GOAL/0/0: not an episode of the run's protocol" in _one_error(
        capsys
    )
    assert not (run / "card.json").exists()


def test_an_undeclared_departure_is_refused(expert_run: Path, tmp_path: Path, capsys: Any) -> None:
    run = _copy(expert_run, tmp_path)
    results = json.loads((run / "results.json").read_text())
    results["config"]["episodes_per_instruction"] = 2
    (run / "results.json").write_text(json.dumps(results))
    assert main(["card", str(run), "--no-progress"]) == 2
    assert "records no such departure" in _one_error(capsys)
    assert not (run / "card.json").exists()


def test_a_split_digest_not_the_datasets_is_refused(
    expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    # The comparison with the paper reads these digests: edited to the official one, a run on
    # other data would pass for a run on the official data.
    run = _copy(expert_run, tmp_path)
    results = json.loads((run / "results.json").read_text())
    results["dataset"]["split_sha256"]["easy_train"] = "0" * 64
    (run / "results.json").write_text(json.dumps(results))
    assert main(["card", str(run), "--no-progress"]) == 1
    line = _one_error(capsys)
    assert "results.json: dataset.split_sha256[easy_train]: recorded '0000" in line
    assert not (run / "card.json").exists()


def test_a_setting_left_out_of_the_record_counts_as_its_default(
    expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    # The paper samples at 0.7; a record without the setting played the default, 0.
    run = _copy(expert_run, tmp_path)
    results = json.loads((run / "results.json").read_text())
    del results["config"]["generation"]["temperature"]
    (run / "results.json").write_text(json.dumps(results))
    assert main(["card", str(run), "--no-progress"]) == 2
    line = _one_error(capsys)
    assert "generation.temperature = 0.0, not its protocol's 0.7" in line
    assert "records no such departure" in line
    assert not (run / "card.json").exists()


def test_the_leaderboard_ranks_only_replayed_cards(
    expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(expert_run, tmp_path)
    assert main(["card", str(run), "--no-progress"]) == 0
    # A card that records no replay (as for a run that kept no step log).
    card = json.loads((run / "card.json").read_text())
    card["replay"] = None
    card["run"] = "unreplayed"
    card["started_at"] = "2030-01-01T00:00:00Z"
    body = {k: v for k, v in card.items() if k != "digest"}
    import hashlib

    card["digest"] = hashlib.sha256(
        json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()
    ).hexdigest()
    other = tmp_path / "other"
    other.mkdir()
    (other / "card.json").write_text(json.dumps(card))
    capsys.readouterr()
    table = tmp_path / "results.md"
    arguments = [f"{run / 'card.json'}={run}", str(other / "card.json"), "--markdown", str(table)]
    assert main(["leaderboard", *arguments]) == 2
    assert "cannot be replayed here (it is given without its run)" in _one_error(capsys)
    assert not table.exists()

    assert main(["leaderboard", *arguments, "--unverified"]) == 0
    text = table.read_text()
    ranked, unranked = text.split("NOT replayed here**")
    assert f"[{run.name}](" in ranked and "card.md)" in ranked and "unreplayed" not in ranked
    assert "| unreplayed |" in unranked and "| none recorded |" in unranked
    # Departures are stated with their values.
    assert "first 9 episodes of the schedule" in ranked
