"""The ladder benchmark (`benchmarks/ladder.py`) on small real runs: the mock backend reads and
acts, the expert plays; its table must say what the runs hold."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from benchmarks import ladder
from llm_agents.agents.registry import AGENTS
from llm_agents.evaluation.grounding_run import read_groundings
from llm_agents.run_data.metrics import clustered_rate, goal_cluster
from llm_agents.run_data.store import read_episodes

CATEGORIES = ("one", "new_objects")
#: Reads are JSON-less (invalid), actions cycle; deterministic whatever the batching.
MODEL = "mock:hash:LEFT|DO|NOOP"


@pytest.fixture(scope="module")
def played(
    official_repository: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[ladder.LadderSettings, str]:
    settings = ladder.LadderSettings(
        model=MODEL,
        out=tmp_path_factory.mktemp("ladder"),
        categories=CATEGORIES,
        limit=2,
        zero_shot_episodes=3,
        max_steps=10,
        grounding_shots=0,
        dataset=str(official_repository),
        batch_size=2,
    )
    return settings, ladder.ladder(settings)


def _row(settings: ladder.LadderSettings, key: str) -> ladder.LadderRow:
    [rung] = [rung for rung in ladder.RUNGS if rung.key == key]
    return ladder.ladder_row(settings, rung)


def _episodes(settings: ladder.LadderSettings, key: str) -> list[Any]:
    return [
        episode
        for category in CATEGORIES
        for episode in read_episodes(settings.out / f"{key}-{category}" / "episodes.jsonl")
    ]


def _line(table: str, key: str) -> str:
    [line] = [line for line in table.splitlines() if line.startswith(f"{key} ")]
    return line


@pytest.mark.slow
def test_each_rung_reports_its_runs_rate_interval_and_cost(
    played: tuple[ladder.LadderSettings, str],
) -> None:
    settings, table = played
    for key in ("expert", "guided", "plans"):
        episodes = _episodes(settings, key)
        assert len(episodes) == 2 * len(CATEGORIES)
        row = _row(settings, key)
        expected = clustered_rate((goal_cluster(e), int(e.success), 1) for e in episodes)
        assert row.rate == expected
        # The expert never asks; guided asks once per text it reads; skills once per decision.
        calls = {"expert": 0.0, "guided": 1.0}.get(key, sum(e.model_calls for e in episodes) / 4)
        assert row.calls_per_item == calls
        assert row.cpu_s_per_item is not None and row.cpu_s_per_item > 0
        assert f"{expected.rate:.2f}" in _line(table, key)
    # The mock answers no skill: every skills episode asks, fails, and is labelled.
    plans = _episodes(settings, "plans")
    assert all(e.model_calls > 0 and not e.success for e in plans)
    errors = ladder.skill_errors(settings)
    assert errors is not None and sum(errors.counts.values()) == len(plans)
    assert f"What the skills agent got wrong ({len(plans)} failed episodes):" in table

    # Zero-shot asks at every step, on the 3-episode subset (2 of `one`, 1 of new objects).
    acts = _episodes(settings, "acts")
    assert len(acts) == 3
    row = _row(settings, "acts")
    assert row.subset == {"one": 2, "new_objects": 1}
    assert row.calls_per_item == pytest.approx(sum(e.steps for e in acts) / 3)
    assert "* acts: a subset of 3 episodes (2 one, 1 new_objects)" in table
    assert _line(table, "acts").split()[3] == "3*"

    # Reads: one call per text, exact match from the groundings (none: no JSON answered).
    records = [
        record
        for category in CATEGORIES
        for record in read_groundings(settings.out / f"reads-{category}")
    ]
    assert len(records) == 4 and not any(record.correct for record in records)
    reads = _row(settings, "reads")
    assert reads.rate is not None and (reads.rate.episodes, reads.rate.successes) == (4, 0)
    assert reads.calls_per_item == 1.0
    assert reads.by_category.keys() == set(CATEGORIES)


@pytest.mark.slow
def test_a_rerun_resumes_plays_nothing_and_prints_the_same_table(
    played: tuple[ladder.LadderSettings, str],
) -> None:
    settings, table = played
    ledger = (settings.out / ladder.CPU_LEDGER).read_text()
    assert ladder.ladder(settings) == table
    assert (settings.out / ladder.CPU_LEDGER).read_text() == ledger
    assert len(_episodes(settings, "expert")) == 4


def test_a_rung_without_its_agent_is_skipped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delitem(AGENTS, "skills")
    settings = ladder.LadderSettings(model=MODEL, out=tmp_path, rungs=("plans", "expert"))
    # Nothing is played for a rung without its agent; the table says why.
    table = ladder.format_ladder(settings, [_row(settings, "plans"), _row(settings, "expert")])
    assert "plans   skills success            skipped: agent `skills` is not registered" in table
    assert "expert  expert success (ceiling)  skipped: not run yet" in table


def test_the_zero_shot_subset_is_spread_over_the_categories(tmp_path: Path) -> None:
    [acts] = [rung for rung in ladder.RUNGS if rung.key == "acts"]
    [expert] = [rung for rung in ladder.RUNGS if rung.key == "expert"]
    settings = ladder.LadderSettings(model=MODEL, out=tmp_path)
    assert settings.per_category_limit(acts) == {"one": 6, "combo": 5, "new_objects": 5}
    assert settings.per_category_limit(expert) == dict.fromkeys(ladder.DEFAULT_CATEGORIES)
    capped = ladder.LadderSettings(model=MODEL, out=tmp_path, limit=4)
    assert capped.per_category_limit(acts) == {"one": 4, "combo": 4, "new_objects": 4}
    full = ladder.LadderSettings(model=MODEL, out=tmp_path, zero_shot_episodes=0)
    assert full.per_category_limit(acts) == dict.fromkeys(ladder.DEFAULT_CATEGORIES)
    # Fewer episodes than categories: the categories left none are not played at all.
    one = ladder.LadderSettings(model=MODEL, out=tmp_path, zero_shot_episodes=1)
    assert one.per_category_limit(acts) == {"one": 1, "combo": 0, "new_objects": 0}
    [(category, config)] = ladder.rung_configs(one, acts)
    assert (category, config.limit, tuple(config.categories)) == ("one", 1, ("one",))


@pytest.mark.slow
def test_a_stopped_rung_keeps_the_cpu_time_of_what_it_played(
    official_repository: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.evaluation import runner

    settings = ladder.LadderSettings(
        model=MODEL,
        out=tmp_path,
        categories=CATEGORIES,
        limit=1,
        max_steps=5,
        dataset=str(official_repository),
        batch_size=1,
        rungs=("expert",),
    )
    real_run_eval = runner.run_eval
    calls = []

    def stopped_after_one_category(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        if len(calls) > 1:
            raise KeyboardInterrupt
        return real_run_eval(*args, **kwargs)

    monkeypatch.setattr(runner, "run_eval", stopped_after_one_category)
    [expert] = [rung for rung in ladder.RUNGS if rung.key == "expert"]
    with pytest.raises(KeyboardInterrupt):
        ladder.play_rung(settings, expert)
    entry = ladder._read_ledger(tmp_path)["expert"]
    assert entry["items"] == 1 and entry["cpu_s"] > 0
