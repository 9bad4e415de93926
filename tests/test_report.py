"""The results table and chart, rebuilt from run directories: finished, partial, torn or empty."""

from __future__ import annotations

import itertools
import struct
from datetime import UTC, datetime
from pathlib import Path

import pytest
from pydantic import ValidationError
from scipy.stats import binomtest

from env.dataset import OFFICIAL_SPLIT_SHA256
from env.errors import UserError
from llm_agents.judging.published import PUBLISHED
from llm_agents.judging.report import report_run
from llm_agents.judging.report_chart import plot_success
from llm_agents.judging.report_tables import format_table
from llm_agents.judging.rescoring import rescore
from llm_agents.run_data.metrics import summarize
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import RunIdentity, RunResults, append_records, write_results

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def episode(index: int, category: str, success: bool) -> EpisodeRecord:
    return EpisodeRecord.model_validate(
        {
            "episode_id": f"ep{index}",
            # A goal per episode: its outcome is independent of the others' (plain Wilson).
            "goal_id": f"{category}-goal-{index}",
            "instruction": "place a table",
            "instruction_variant": 2 if category == "paraphrased" else 0,
            "category": category,
            "seed": index,
            "episode_index": index,
            "success": success,
            "steps": 12,
            "termination": "success" if success else "death",
            "episode_return": 0.0,
        }
    )


def episodes_with(counts: dict[str, tuple[int, int]]) -> list[EpisodeRecord]:
    """Episodes with `k` successes out of `n` per category."""
    index = itertools.count()
    return [
        episode(next(index), category, success=i < k)
        for category, (k, n) in counts.items()
        for i in range(n)
    ]


def expected_cell(k: int, n: int) -> str:
    ci = binomtest(k, n).proportion_ci(method="wilson")
    return f"{k / n:.2f} [{ci.low:.2f}, {ci.high:.2f}] n={n} g={n}"


def table_rows(table: str) -> dict[str, dict[str, str]]:
    """The table as {row label: {column header: cell}}."""
    lines = table.splitlines()
    header = [cell.strip() for cell in lines[0].split("|")]
    rows: dict[str, dict[str, str]] = {}
    for line in lines[2:]:
        if "|" not in line:
            break
        cells = [cell.strip() for cell in line.split("|")]
        rows[cells[0]] = dict(zip(header[1:], cells[1:], strict=False))
    return rows


def make_run(
    run_dir: Path,
    episodes: list[EpisodeRecord],
    base: RunResults | None = None,
    scheduled: int | None = None,
    **fields: object,
) -> Path:
    """A run directory as the runner leaves it: episodes appended, results summarising them.

    `base` lends its config and dataset; `scheduled` adds unfinished episodes to the schedule.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    append_records(run_dir / "episodes.jsonl", episodes)
    scheduled = len(episodes) if scheduled is None else scheduled
    schedule = [e.episode_id for e in episodes]
    schedule += [f"pending{i}" for i in range(scheduled - len(episodes))]
    data: dict[str, object] = {
        "config": {"model": "hf:Qwen/QwQ-32B", "variant": "full"},
        "identity": RunIdentity(settings={}, templates={}),
        "schedule": schedule,
        "finished": len(episodes),
        "summary": summarize(episodes) if episodes else None,
        "status": "complete" if len(episodes) == scheduled else "partial",
        "started_at": datetime(2025, 1, 1, tzinfo=UTC),
    }
    if base is not None:
        data |= base.model_dump(include={"config", "dataset"})
    results = RunResults.model_validate(data | fields)
    write_results(run_dir / "results.json", results)
    return run_dir


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def test_table_puts_our_rates_beside_the_published_ones() -> None:
    counts = {"one": (3, 10), "combo": (1, 8), "new_objects": (0, 6)}
    table = format_table(summarize(episodes_with(counts)), "mock:random")
    rows = table_rows(table)

    assert list(next(iter(rows.values()))) == ["one", "combo", "New objects", "overall"]
    ours = rows["mock:random (this run)"]
    assert ours["one"] == expected_cell(3, 10)
    assert ours["combo"] == expected_cell(1, 8)
    assert ours["New objects"] == expected_cell(0, 6)
    assert ours["overall"] == expected_cell(4, 24)
    assert rows["Qwen QwQ-32B (published)"] == {
        "one": "0.21",
        "combo": "0.10",
        "New objects": "0.07",
        "overall": "-",
    }
    assert rows["Mistral-Small-24B (published)"]["New objects"] == "0.09"
    assert rows["DeepSeek-R1-Distill-Qwen-32B (published)"]["one"] == "0.15"
    assert len(rows) == 1 + len(PUBLISHED)


def test_table_adds_paraphrased_and_marks_missing_categories() -> None:
    counts = {"one": (2, 5), "paraphrased": (1, 4)}
    rows = table_rows(format_table(summarize(episodes_with(counts)), "m", partial=True))

    ours = rows["m (this run, partial)"]
    assert ours["Paraphrased"] == expected_cell(1, 4)
    assert ours["combo"] == "-"
    assert ours["New objects"] == "-"
    for result in PUBLISHED:
        assert rows[f"{result.model} (published)"]["Paraphrased"] == "-"


def test_table_has_no_overall_column_for_a_single_category() -> None:
    rows = table_rows(format_table(summarize(episodes_with({"combo": (1, 3)})), "m"))
    assert "overall" not in rows["m (this run)"]
    assert "Paraphrased" not in rows["m (this run)"]


def test_chart_is_a_png(tmp_path: Path) -> None:
    path = tmp_path / "chart.png"
    summary = summarize(episodes_with({"one": (3, 10), "paraphrased": (0, 4)}))
    plot_success(summary, "mock:random", path)
    width, height = png_size(path)
    assert width > 400 and height > 300


def test_chart_to_an_unwritable_place_is_a_user_error(tmp_path: Path) -> None:
    summary = summarize(episodes_with({"one": (1, 2)}))
    with pytest.raises(UserError, match="cannot write chart"):
        plot_success(summary, "m", tmp_path / "no" / "such" / "dir" / "chart.png")


def test_report_of_a_finished_run_names_the_model_and_draws_the_chart(tmp_path: Path) -> None:
    episodes = episodes_with({"one": (4, 9), "combo": (2, 7), "new_objects": (1, 5)})
    run_dir = make_run(tmp_path / "run", episodes)

    report = report_run(run_dir)
    rows = table_rows(report)
    ours = rows["hf:Qwen/QwQ-32B (this run)"]
    assert ours["one"] == expected_cell(4, 9)
    assert ours["overall"] == expected_cell(7, 21)
    assert "Run status: complete (21 of 21 episodes)." in report
    png_size(run_dir / "success.png")


def test_the_report_gives_the_computed_share_of_prompt_tokens_where_it_is_known(
    tmp_path: Path,
) -> None:
    counted = [
        e.model_copy(update={"prompt_tokens": 1000, "computed_prompt_tokens": 300})
        for e in episodes_with({"one": (1, 4)})
    ]
    assert "Prompt tokens computed: 30% (the rest reused" in report_run(
        make_run(tmp_path / "counted", counted)
    )
    assert "Prompt tokens computed" not in report_run(
        make_run(tmp_path / "unknown", episodes_with({"one": (1, 4)}))
    )


def test_report_of_a_partial_run_says_how_far_it_got_and_why_it_stopped(tmp_path: Path) -> None:
    episodes = episodes_with({"one": (1, 3)})
    errors = {"failed_calls": 9, "aborted_episodes": ["a", "b"], "last_error": "HTTP 503"}
    run_dir = make_run(
        tmp_path / "run",
        episodes,
        scheduled=10,
        status="failed",
        failure="HTTP 503",
        backend_errors=errors,
    )
    report = report_run(str(run_dir))
    assert table_rows(report)["hf:Qwen/QwQ-32B (this run, partial)"]["one"] == expected_cell(1, 3)
    assert "Run status: failed (3 of 10 episodes)." in report
    assert "9 failed answers, 2 episodes cut short" in report
    assert "Stopped by: HTTP 503" in report


def test_report_before_any_episode_finished_is_a_user_error(tmp_path: Path) -> None:
    run_dir = make_run(tmp_path / "run", [], scheduled=4)
    with pytest.raises(UserError, match="no episode"):
        report_run(run_dir)
    assert not (run_dir / "success.png").exists()


def test_report_of_a_directory_without_results_is_a_user_error(tmp_path: Path) -> None:
    append_records(tmp_path / "episodes.jsonl", episodes_with({"one": (1, 1)}))
    with pytest.raises(UserError, match="not a run directory"):
        report_run(tmp_path)


def test_report_of_a_missing_directory_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="does not exist"):
        report_run(tmp_path / "nowhere")


def test_report_rejects_a_broken_results_file(tmp_path: Path) -> None:
    run_dir = make_run(tmp_path / "run", episodes_with({"one": (1, 2)}))
    (run_dir / "results.json").write_text('{"config": ')
    with pytest.raises(UserError, match=r"results\.json"):
        report_run(run_dir)


def test_episode_records_round_trip_and_stay_consistent() -> None:
    record = episode(3, "combo", success=True).model_copy(update={"invalid_actions": 3})
    line = record.model_dump_json()
    assert '"invalid_action_rate":0.25' in line
    assert EpisodeRecord.model_validate_json(line) == record
    with pytest.raises(ValidationError, match="contradicts"):
        EpisodeRecord.model_validate({**record.model_dump(), "termination": "death"})
    with pytest.raises(ValidationError, match="exceeds"):
        EpisodeRecord.model_validate({**record.model_dump(), "invalid_actions": 13})


# --- the paper's protocol: comparable or labelled; re-scoring under either success rule ---------


def paper_results(**config: object) -> RunResults:
    """Results of a run that followed the paper's protocol, with `config` changes."""
    return RunResults(
        config={
            "model": "m",
            "variant": "classic",
            "max_steps": 250,
            "success_rule": "official",
            **config,
        },
        dataset={
            "kind": "archive",
            "path": "https://github.com/AIRI-Institute/CrafText/archive/x.zip",
            "split_sha256": dict(OFFICIAL_SPLIT_SHA256),
            "goals": {"one": 20, "combo": 37, "paraphrased": 41, "new_objects": 44},
        },
        identity=RunIdentity(settings={}, templates={}),
        started_at=datetime(2025, 1, 1, tzinfo=UTC),
    )


def published_section(table: str) -> tuple[list[str], dict[str, dict[str, str]]]:
    """The listed differences and the published rows of a table with a 'NOT comparable' part."""
    lines = table.splitlines()
    start = next(i for i, line in enumerate(lines) if "NOT comparable" in line)
    differences = []
    index = start + 1
    while lines[index].startswith("  - "):
        differences.append(lines[index].removeprefix("  - "))
        index += 1
    return differences, table_rows("\n".join(lines[index:]))


def test_published_numbers_sit_beside_a_run_under_the_papers_protocol(tmp_path: Path) -> None:
    episodes = episodes_with({"one": (1, 4), "combo": (0, 3), "new_objects": (1, 2)})
    table = report_run(make_run(tmp_path / "run", episodes, paper_results()))
    assert "NOT comparable" not in table
    rows = table_rows(table)
    assert rows["m (this run)"]["one"] == expected_cell(1, 4)
    assert rows["Qwen QwQ-32B (published)"]["one"] == "0.21"
    assert (tmp_path / "run" / "success.png").is_file()


def test_published_numbers_of_an_incomparable_run_come_under_its_differences(
    tmp_path: Path,
) -> None:
    episodes = episodes_with({"one": (1, 4), "combo": (0, 3), "new_objects": (1, 2)})
    results = paper_results(variant="full", max_steps=100, success_rule="game_over_counts")
    wheel_train = "1f4fcafcf70b518ab29681ff6a834e25f40bdb4d0584b8606ef090b4c9044aa6"
    results.dataset["split_sha256"]["easy_train"] = wheel_train
    results.dataset["kind"], results.dataset["path"] = "wheel", "craftext-0.2.2.whl"
    table = report_run(make_run(tmp_path / "run", episodes, results))

    rows = table_rows(table)
    assert list(rows) == ["m (this run)"]
    differences, published = published_section(table)
    assert differences == [
        "variant: full Craftax (paper: classic)",
        "dataset: easy_train not the official data at 1c518ae (source: wheel craftext-0.2.2.whl)",
        "step cap: 100 steps (paper: 250)",
        "success rule: game_over_counts, a goal completed on the step the game ends counts "
        "(paper: official, it does not; try --success-rule official)",
    ]
    assert published["Mistral-Small-24B (published)"]["New objects"] == "0.09"
    assert len(published) == len(PUBLISHED)


def test_categories_missing_from_the_dataset_say_so(tmp_path: Path) -> None:
    results = paper_results()
    results.dataset["goals"] = {"one": 0, "combo": 12, "paraphrased": 41, "new_objects": 44}
    episodes = episodes_with({"combo": (1, 3), "new_objects": (0, 2)})
    rows = table_rows(report_run(make_run(tmp_path / "run", episodes, results)))
    assert rows["m (this run)"]["one"] == "not in this dataset"
    # A category the dataset has but the run did not reach stays a dash.
    results.dataset["goals"]["one"] = 20
    rows = table_rows(report_run(make_run(tmp_path / "other", episodes, results)))
    assert rows["m (this run)"]["one"] == "-"


def at_game_over(
    index: int, category: str, *, counted: bool, ended: str = "death"
) -> EpisodeRecord:
    """An episode whose goal was completed on the step the game ended (`ended`)."""
    return episode(index, category, success=counted).model_copy(
        update={
            "goal_at_game_over": ended,
            "termination": "success" if counted else ended,
            "episode_return": 1.0 if counted else 0.0,
        }
    )


@pytest.mark.parametrize("played", ["game_over_counts", "official"])
def test_a_run_is_rescored_under_either_rule_from_its_records(tmp_path: Path, played: str) -> None:
    counted = played == "game_over_counts"
    episodes = [
        *episodes_with({"one": (1, 3)}),
        at_game_over(10, "one", counted=counted),
        at_game_over(11, "one", counted=counted, ended="timeout"),
    ]
    run_dir = make_run(tmp_path / "run", episodes, paper_results(success_rule=played))
    as_played = report_run(run_dir)
    lenient = report_run(run_dir, success_rule="game_over_counts")
    official = report_run(run_dir, success_rule="official")

    assert table_rows(lenient)["m (this run)"]["one"] == expected_cell(3, 5)
    assert table_rows(official)["m (this run)"]["one"] == expected_cell(1, 5)
    assert as_played == (lenient if counted else official)
    assert "Episodes: 5 (success 1, death 3, timeout 1)." in official
    assert "Episodes: 5 (success 3, death 2, timeout 0)." in lenient
    assert "Goals completed on the step the game ended: 2." in official
    # Only the official rule matches the paper's protocol.
    assert "NOT comparable" in lenient and "NOT comparable" not in official
    rescored = "re-scored; the run was played under"
    assert (rescored in official) == counted and (rescored in lenient) != counted


def game_ended_with_goal(
    index: int, played: str, *, at_game_over: bool, in_new_world: bool, ended: str = "timeout"
) -> EpisodeRecord:
    """An episode whose game ended (`ended`) with its goal met on the final state, in the
    auto-reset world, or both, scored as the rule it was `played` under scores it."""
    counted = at_game_over if played == "game_over_counts" else in_new_world
    return episode(index, "one", success=counted).model_copy(
        update={
            "goal_at_game_over": ended if at_game_over else None,
            "goal_in_new_world": ended if in_new_world else None,
            "termination": "success" if counted else ended,
            "episode_return": 1.0 if counted else 0.0,
        }
    )


@pytest.mark.parametrize("played", ["game_over_counts", "official"])
def test_successes_in_the_new_world_count_under_official_and_apart(
    tmp_path: Path, played: str
) -> None:
    # The official wrapper checks the auto-reset world on the game-over step (Medium and Hard
    # goals can be met there): those successes are the official rule's, counted apart.
    episodes = [
        *episodes_with({"one": (1, 3)}),
        game_ended_with_goal(10, played, at_game_over=False, in_new_world=True, ended="death"),
        game_ended_with_goal(11, played, at_game_over=False, in_new_world=True),
        game_ended_with_goal(12, played, at_game_over=True, in_new_world=True),
        game_ended_with_goal(13, played, at_game_over=True, in_new_world=False, ended="death"),
    ]
    run_dir = make_run(tmp_path / "run", episodes, paper_results(success_rule=played))
    official = report_run(run_dir, success_rule="official")
    lenient = report_run(run_dir, success_rule="game_over_counts")

    assert table_rows(official)["m (this run)"]["one"] == expected_cell(4, 7)
    assert table_rows(lenient)["m (this run)"]["one"] == expected_cell(3, 7)
    assert "Episodes: 7 (success 4, death 3, timeout 0)." in official
    assert "Episodes: 7 (success 3, death 3, timeout 1)." in lenient
    for report in (official, lenient):
        assert "Goals completed on the step the game ended: 2." in report
        assert "Succeeded on the game-over step, in the new world: 3" in report
    assert "(a success under this rule)" in official
    assert "(not counted under this rule)" in lenient
    assert report_run(run_dir) == (official if played == "official" else lenient)


def test_a_new_world_success_must_agree_with_the_termination_and_the_game_end() -> None:
    record = game_ended_with_goal(0, "official", at_game_over=False, in_new_world=True)
    with pytest.raises(ValidationError, match="goal_in_new_world"):
        EpisodeRecord.model_validate(
            {**record.model_dump(), "termination": "death", "success": False}
        )
    with pytest.raises(ValidationError, match="one game end"):
        EpisodeRecord.model_validate({**record.model_dump(), "goal_at_game_over": "death"})


def test_rescoring_keeps_other_episodes_and_fixes_the_return() -> None:
    plain = episode(0, "combo", success=False)
    lucky = at_game_over(1, "combo", counted=True)
    official = rescore([plain, lucky], "official")
    assert official[0] == plain
    assert (official[1].success, official[1].termination, official[1].episode_return) == (
        False,
        "death",
        0.0,
    )
    assert rescore(official, "game_over_counts")[1] == lucky


def test_an_unknown_success_rule_is_a_user_error(tmp_path: Path) -> None:
    run_dir = make_run(tmp_path / "run", episodes_with({"one": (1, 2)}))
    with pytest.raises(UserError, match="unknown success rule 'strict'"):
        report_run(run_dir, success_rule="strict")  # type: ignore[arg-type]


def test_a_game_over_goal_must_agree_with_the_termination() -> None:
    record = at_game_over(0, "one", counted=False)
    with pytest.raises(ValidationError, match="goal_at_game_over"):
        EpisodeRecord.model_validate({**record.model_dump(), "termination": "timeout"})


def test_report_command_rescores_with_a_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from llm_agents.cli import main

    episodes = [*episodes_with({"one": (0, 1)}), at_game_over(5, "one", counted=True)]
    run_dir = make_run(tmp_path / "run", episodes, paper_results(success_rule="game_over_counts"))
    assert main(["report", str(run_dir), "--success-rule", "official"]) == 0
    assert table_rows(capsys.readouterr().out)["m (this run)"]["one"] == expected_cell(0, 2)
    assert main(["report", str(run_dir)]) == 0
    assert table_rows(capsys.readouterr().out)["m (this run)"]["one"] == expected_cell(1, 2)


# ----------------------------------------------------------------------------- provenance and comparisons


def test_a_run_whose_episodes_came_from_different_code_says_so(tmp_path: Path) -> None:
    played = episodes_with({"one": (1, 3), "combo": (0, 2)})
    versions = ["v1", "v1", "v2", None, "v2"]
    mixed = [e.model_copy(update={"code": v}) for e, v in zip(played, versions, strict=True)]
    report = report_run(make_run(tmp_path / "mixed", mixed))
    assert (
        "Note: the episodes of this run came from different code: "
        "v1 (2), v2 (2), not recorded (1)." in report
    )
    same = [e.model_copy(update={"code": "v1"}) for e in played]
    assert "different code" not in report_run(make_run(tmp_path / "same", same))


def test_compared_runs_that_differ_in_a_setting_changing_the_numbers_say_which(
    tmp_path: Path,
) -> None:
    from llm_agents.judging.comparison import compare_runs

    played = episodes_with({"one": (1, 3)})
    config = {"model": "hf:m", "variant": "full", "protocol": "default", "choice": None,
              "success_rule": "game_over_counts"}  # fmt: skip
    first = make_run(tmp_path / "a", played, config=config)
    alike = make_run(tmp_path / "b", played, config=config)
    assert "differ in" not in compare_runs(first, alike)

    other = config | {"choice": "loglik", "variant": "classic", "success_rule": "official"}
    table = compare_runs(first, make_run(tmp_path / "c", played, config=other))
    assert (
        "Note: the compared runs differ in choice (unset, loglik); variant (full, classic); "
        "success rule (game_over_counts, official) (in the rows' order)." in table
    )
    paper = config | {"protocol": "paper"}
    assert "differ in protocol (default, paper)" in compare_runs(
        first, make_run(tmp_path / "d", played, config=paper)
    )
