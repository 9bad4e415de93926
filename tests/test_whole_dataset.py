"""The whole official CrafText dataset through every command: each text of every split of every
difficulty (paraphrases included) played a few steps by the scripted expert through `eval`, each
run read back by `report`, its every episode replayed and rendered by `view`, and each text
planned by a mock model through `plan`.

Nothing here judges play or plans: it checks that the whole dataset goes through each command,
which writes its files and prints no traceback (Medium's train split once stopped at its 693rd
text, the first with more than five paraphrases). The runs are a module-scoped fixture,
`played_runs`, so that other commands over the same runs (`view`) can be tested here too.
"""

from __future__ import annotations

import contextlib
import io
import json
import time
import traceback
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from env.dataset import Dataset, load_dataset
from env.goals import (
    DIFFICULTIES,
    DIFFICULTY_CATEGORIES,
    Category,
    Difficulty,
    category_split,
    run_category,
)
from llm_agents.cli import main
from llm_agents.run_data.store import read_episodes, read_steps

#: The variant each difficulty's official configs play (EASY's are Classic's goals as well).
VARIANTS: dict[Difficulty, str] = {"easy": "classic", "medium": "classic", "hard": "full"}
MAX_STEPS = 2
#: Wider than any difficulty's texts: every episode in flight at once, so a run is one batch
#: stepped MAX_STEPS times with a single compiled step.
BATCH_SIZE = 4096
#: Plans the mock planner answers in turn, in Craftax names, one per kind of goal.
PLANS = [
    "1. Collect wood.\n2. Place a table.",
    "1. Collect 3 iron.\n2. Place 2 crafting tables.",
    "1. Find the table.\n2. Place a furnace 2 blocks left of it.",
    "1. Collect stone.\n2. Place 3 stones in a diagonal line.",
    "1. Collect stone.\n2. Lay stones in a solid 3x3 square.",
    "1. Collect stone.\n2. Place stones in a star shape.",
]

pytestmark = pytest.mark.slow


@dataclass(frozen=True)
class Command:
    """One in-process `craftext-llm` command and what it printed."""

    code: int
    out: str
    err: str
    seconds: float


def run_command(argv: list[str]) -> Command:
    out, err = io.StringIO(), io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except Exception:
            # As the console script would end: each test then fails on its own run's traceback.
            traceback.print_exc()
            code = 1
    return Command(code, out.getvalue(), err.getvalue(), time.perf_counter() - started)


def assert_clean(command: Command) -> None:
    assert command.code == 0, command.err[-3000:]
    assert "Traceback" not in command.out + command.err


@dataclass(frozen=True)
class PlayedRun:
    """One difficulty's `eval` over every text it has."""

    run_dir: Path
    categories: tuple[Category, ...]
    texts: Counter[tuple[Category, str, int]]
    """(category, goal id, variant) of every text the dataset has for the difficulty."""
    eval: Command


@pytest.fixture(scope="module")
def official_data(official_repository: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The official data as a dataset JSON (read back faster than the modules are parsed)."""
    path = tmp_path_factory.mktemp("whole-dataset") / "official.json"
    load_dataset(official_repository).save_json(path)
    return path


def categories_held(dataset: Dataset, difficulty: Difficulty) -> tuple[Category, ...]:
    """The difficulty's categories whose split the dataset holds (Hard: train only)."""
    return tuple(
        category
        for category in DIFFICULTY_CATEGORIES[difficulty]
        if dataset.has_split(category_split(category, difficulty))
    )


@pytest.fixture(scope="module")
def played_runs(
    official_data: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[Difficulty, PlayedRun]:
    """Every text of every difficulty played by the expert, a run directory per difficulty."""
    dataset = load_dataset(official_data)
    root = tmp_path_factory.mktemp("whole-dataset-runs")
    runs = {}
    for difficulty in DIFFICULTIES:
        categories = categories_held(dataset, difficulty)
        texts = Counter(
            (run_category(text.goal), text.goal.id, text.variant)
            for text in dataset.instructions(categories, difficulty=difficulty)
        )
        run_dir = root / difficulty
        argv = [
            "eval", "--agent", "expert", "--difficulty", difficulty,
            "--categories", *categories, "--variant", VARIANTS[difficulty],
            "--max-steps", str(MAX_STEPS), "--batch-size", str(BATCH_SIZE),
            "--dataset", str(official_data), "--output-dir", str(run_dir), "--no-progress",
        ]  # fmt: skip
        command = run_command(argv)
        runs[difficulty] = PlayedRun(run_dir, categories, texts, command)
    return runs


def test_the_runs_cover_every_split_of_the_dataset(
    official_data: Path, played_runs: dict[Difficulty, PlayedRun]
) -> None:
    dataset = load_dataset(official_data)
    covered = {
        category_split(category, difficulty)
        for difficulty, run in played_runs.items()
        for category in run.categories
    }
    assert covered == {goal.split for goal in dataset.goals}
    assert sum(sum(run.texts.values()) for run in played_runs.values()) == sum(
        len(goal.texts) for goal in dataset.goals
    )


@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_eval_plays_every_text(
    played_runs: dict[Difficulty, PlayedRun], difficulty: Difficulty
) -> None:
    run = played_runs[difficulty]
    assert_clean(run.eval)
    results = json.loads((run.run_dir / "results.json").read_text())
    assert results["status"] == "complete"
    episodes = read_episodes(run.run_dir / "episodes.jsonl")
    played = Counter((e.category, e.goal_id, e.instruction_variant) for e in episodes)
    assert played == run.texts
    assert all(1 <= episode.steps <= MAX_STEPS for episode in episodes)
    steps = sum(1 for _ in read_steps(run.run_dir / "steps.jsonl"))
    assert steps == sum(episode.steps for episode in episodes)
    total = len(episodes)
    assert f"Run status: complete ({total} of {total} episodes)" in run.eval.out


@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_report_reads_every_run(
    played_runs: dict[Difficulty, PlayedRun], difficulty: Difficulty
) -> None:
    run = played_runs[difficulty]
    chart = run.run_dir / "success.png"
    chart.unlink()
    command = run_command(["report", str(run.run_dir)])
    assert_clean(command)
    total = sum(run.texts.values())
    assert f"Run status: complete ({total} of {total} episodes)" in command.out
    assert chart.stat().st_size > 0


@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_plan_plans_every_text(official_data: Path, tmp_path: Path, difficulty: Difficulty) -> None:
    dataset = load_dataset(official_data)
    categories = categories_held(dataset, difficulty)
    texts = {text.text for text in dataset.instructions(categories, difficulty=difficulty)}
    script = tmp_path / "plans.json"
    script.write_text(json.dumps(PLANS))
    output = tmp_path / "out" / "plans.json"
    argv = [
        "plan", "--model", f"mock:file:{script}", "--difficulty", difficulty,
        "--categories", *categories, "--variant", VARIANTS[difficulty],
        "--requests-per-call", "512", "--dataset", str(official_data),
        "--output", str(output), "--no-progress",
    ]  # fmt: skip
    command = run_command(argv)
    assert_clean(command)
    assert set(json.loads(output.read_text())) == texts
    assert f"{len(texts)} instructions: {len(texts)} valid, 0 repaired, 0 failed" in command.out
    assert output.with_suffix(".meta.json").is_file()


@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_view_renders_every_episode(
    played_runs: dict[Difficulty, PlayedRun], difficulty: Difficulty
) -> None:
    run = played_runs[difficulty]
    command = run_command(["view", str(run.run_dir), "--no-progress"])
    assert_clean(command)
    report = run.run_dir / "report"
    episodes = read_episodes(run.run_dir / "episodes.jsonl")
    pages = list((report / "episodes").glob("*.html"))
    assert len(pages) == len(episodes)
    # Every replay reproduced its record (a mismatch is flagged on the run page), and every
    # page states its goal in words, whatever its kind.
    assert 'id="replay-mismatch"' not in (report / "index.html").read_text()
    assert all('id="goal-words">' in page.read_text() for page in pages)
