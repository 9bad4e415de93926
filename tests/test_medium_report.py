"""Medium and Hard runs in the report: the paper's Table 2 layout (scenario class x Train /
Paraphrased / New objects) and its Medium totals, beside a comparable run only."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime
from pathlib import Path

from scipy.stats import binomtest

from env.dataset import OFFICIAL_SPLIT_SHA256
from llm_agents.judging.report import report_run
from llm_agents.judging.report_tables import format_table
from llm_agents.run_data.metrics import summarize
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import RunIdentity, RunResults, append_records, write_results

#: (scenario class, goal set) -> (successes, episodes)
COUNTS = {
    ("Conditional", "train"): (2, 4),
    ("Build", "train"): (1, 5),
    ("Build", "new_objects"): (0, 3),
    ("Localization", "paraphrased"): (3, 3),
    ("Achievements", "train"): (1, 2),
    ("Achievements", "paraphrased"): (0, 2),
}
PAPER_MEDIUM_CONFIG = {
    "model": "hf:smollm2-135m",
    "difficulty": "medium",
    "variant": "classic",
    "max_steps": 250,
    "success_rule": "official",
}
MEDIUM_DIGESTS = {
    split: digest for split, digest in OFFICIAL_SPLIT_SHA256.items() if split.startswith("medium")
}


def episodes() -> list[EpisodeRecord]:
    index = itertools.count()
    records = []
    for (scenario, category), (k, n) in COUNTS.items():
        for i in range(n):
            number = next(index)
            records.append(
                EpisodeRecord(
                    episode_id=f"{category}/{scenario}-goal-{i}/0/0",
                    # A goal per episode: outcomes independent, the plain Wilson interval.
                    goal_id=f"{scenario}-goal-{i}",
                    instruction="build a line of stones",
                    instruction_variant=0,
                    category=category,  # type: ignore[arg-type]
                    scenario_class=scenario,  # type: ignore[arg-type]
                    seed=0,
                    episode_index=number,
                    success=i < k,
                    steps=10,
                    termination="success" if i < k else "timeout",
                    episode_return=0.0,
                )
            )
    return records


def cell(k: int, n: int) -> str:
    ci = binomtest(k, n).proportion_ci(method="wilson")
    return f"{k / n:.2f} [{ci.low:.2f}, {ci.high:.2f}] n={n} g={n}"


def rows_of(lines: list[str]) -> dict[str, dict[str, str]]:
    header = [cell.strip() for cell in lines[0].split("|")]
    rows = {}
    for line in lines[2:]:
        if "|" not in line:
            break
        cells = [cell.strip() for cell in line.split("|")]
        rows[cells[0]] = dict(zip(header[1:], cells[1:], strict=True))
    return rows


def test_a_medium_table_has_the_papers_columns_totals_and_scenario_rows() -> None:
    table = format_table(summarize(episodes()), "m", difficulty="medium")
    lines = table.splitlines()
    totals = rows_of(lines)
    assert list(totals["m (this run)"]) == ["Train", "Paraphrased", "New objects", "overall"]
    assert totals["m (this run)"]["Train"] == cell(4, 11)
    assert totals["m (this run)"]["Paraphrased"] == cell(3, 5)
    assert totals["m (this run)"]["New objects"] == cell(0, 3)
    assert totals["PPO-T (published)"] == {
        "Train": "0.40",
        "Paraphrased": "0.36",
        "New objects": "0.22",
        "overall": "-",
    }
    assert totals["Dynalang (published)"]["New objects"] == "0.10"
    assert "NOT comparable" not in table

    start = lines.index("By scenario class (medium):") + 1
    scenarios = rows_of(lines[start:])
    # The paper's row order, and only the classes the run played.
    assert list(scenarios) == ["Conditional", "Build", "Localization", "Achievements"]
    assert scenarios["Conditional"] == {"Train": cell(2, 4), "Paraphrased": "-", "New objects": "-"}
    assert scenarios["Build"]["New objects"] == cell(0, 3)
    assert scenarios["Localization"]["Paraphrased"] == cell(3, 3)
    assert scenarios["Achievements"]["Train"] == cell(1, 2)


def make_run(run_dir: Path, config: dict[str, object], digests: dict[str, str]) -> Path:
    records = episodes()
    run_dir.mkdir()
    append_records(run_dir / "episodes.jsonl", records)
    results = RunResults(
        config=config,
        identity=RunIdentity(settings={}, templates={}),
        dataset={"kind": "archive", "path": "official", "split_sha256": digests},
        schedule=[e.episode_id for e in records],
        finished=len(records),
        summary=summarize(records),
        status="complete",
        started_at=datetime(2025, 1, 1, tzinfo=UTC),
    )
    write_results(run_dir / "results.json", results)
    return run_dir


def test_a_medium_run_under_the_papers_protocol_sits_beside_its_medium_rows(
    tmp_path: Path,
) -> None:
    table = report_run(make_run(tmp_path / "run", PAPER_MEDIUM_CONFIG, MEDIUM_DIGESTS))
    assert "NOT comparable" not in table
    assert "PPO-T+ (published) | 0.45" in table.replace("  ", "")
    assert "Qwen QwQ-32B" not in table
    assert (tmp_path / "run" / "success.png").is_file()


def test_a_medium_run_off_the_papers_protocol_lists_why_it_is_not_comparable(
    tmp_path: Path,
) -> None:
    config = PAPER_MEDIUM_CONFIG | {"variant": "full", "max_steps": 100}
    other_data = MEDIUM_DIGESTS | {"medium_test_paraphrased": "0" * 64}
    table = report_run(make_run(tmp_path / "run", config, other_data))
    heading = (
        "Published numbers (the paper's trained agents, Medium totals, 50 worlds per "
        "instruction), NOT comparable with this run:"
    )
    assert heading in table
    after = table.split(heading)[1]
    assert "variant: full Craftax (paper: classic)" in after
    assert "step cap: 100 steps (paper: 250)" in after
    assert "medium_test_paraphrased not the official data" in after
    assert "FiLM (published)" in after


def test_a_hard_run_has_no_published_rows(tmp_path: Path) -> None:
    config = PAPER_MEDIUM_CONFIG | {"difficulty": "hard", "variant": "full"}
    table = report_run(make_run(tmp_path / "run", config, {}))
    assert "(published)" not in table and "NOT comparable" not in table
    assert "Published: none for Hard." in table
    assert "By scenario class (hard):" in table
