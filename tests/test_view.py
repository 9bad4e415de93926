"""`craftext-llm view`: replays of a real (mock-backend) run reproduce its records, mismatches are
flagged loudly, the GIF export, and the report in a real browser (Debian's Chromium, Playwright).
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
from headless import launch_chromium, open_page
from PIL import Image

from env import CrafTextEnv, EnvConfig, Variant, episode_key, shared_env
from llm_agents.agents import NoModel
from llm_agents.backends import get_model
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.store import read_episodes
from llm_agents.viewer import build_view
from llm_agents.viewer.frames import FRAMES_PER_SECOND, sprite_sheet
from llm_agents.viewer.run import load_run

MAX_STEPS = 30
#: DO-heavy, so some episodes unlock achievements the replay must reproduce.
SCRIPT = "mock:hash:ACTION: DO|ACTION: LEFT|I go RIGHT|<action>UP</action>|ACTION: DO|hmm|DOWN"


@pytest.fixture(scope="module")
def classic_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))


def _settings(out: Path, **settings: Any) -> Any:
    return build_config(
        {
            "variant": "classic",
            "categories": ["combo", "new_objects"],
            "max_steps": MAX_STEPS,
            "batch_size": 4,
            "output_dir": str(out),
            **settings,
        }
    )


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory, classic_env: CrafTextEnv) -> Path:
    out = tmp_path_factory.mktemp("run")
    config = _settings(out, model=SCRIPT, limit=5)
    with get_model(config.model, config.generation) as model:
        run_eval(config, model, env=classic_env)
    return out


@pytest.fixture(scope="module")
def expert_dir(tmp_path_factory: pytest.TempPathFactory, classic_env: CrafTextEnv) -> Path:
    """The scripted expert on the same dataset, the run the report compares with."""
    out = tmp_path_factory.mktemp("expert")
    run_eval(_settings(out, agent="expert", limit=4), NoModel(), env=classic_env)
    return out


@pytest.fixture(scope="module")
def viewed(run_dir: Path, expert_dir: Path) -> Any:
    return build_view(run_dir, progress=False, compare=[expert_dir])


def _copy_run(run_dir: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns("report"))
    return copy


def _rewrite_episodes(run: Path, change: Any) -> list[EpisodeRecord]:
    path = run / "episodes.jsonl"
    records = [change(json.loads(line)) for line in path.read_text().splitlines()]
    path.write_text("".join(json.dumps(record) + "\n" for record in records))
    return read_episodes(path)


def test_runner_records_the_reset_key_that_older_records_derive(run_dir: Path) -> None:
    run = load_run(run_dir)
    for view in run.episodes:
        record = view.record
        assert record.reset_key is not None
        repeat = int(record.episode_id.rsplit("/", 1)[-1])
        derived = episode_key(record.seed, record.goal_id, record.instruction_variant, repeat)
        assert record.reset_key == derived.tolist()
        view.record = record.model_copy(update={"reset_key": None})
        assert view.reset_key().tolist() == record.reset_key


@pytest.mark.slow
def test_replays_reproduce_every_recorded_episode(run_dir: Path, viewed: Any) -> None:
    episodes = read_episodes(run_dir / "episodes.jsonl")
    assert viewed.statuses.keys() == {e.episode_id for e in episodes}
    assert {s.state for s in viewed.statuses.values()} == {"reproduced"}
    # The check has teeth only if some episode unlocked something.
    assert any(e.achievements for e in episodes)
    assert viewed.frames == sum(e.steps + 1 for e in episodes)
    pages = run_dir / "report" / "episodes"
    for episode in episodes:
        assert viewed.statuses[episode.episode_id].frames == episode.steps + 1
        page = (pages / f"episode-{episode.episode_index:05d}.html").read_text()
        assert episode.instruction in page
        assert 'id="replay-mismatch"' not in page
        data = json.loads(re.search(r'id="episode-data">(.*?)</script>', page, re.S).group(1))
        sheet = data["sheet"]
        assert len(sheet["index"]) == episode.steps + 1
        assert [s["step"] for s in data["steps"]] == list(range(episode.steps))
        image = Image.open(pages / f"episode-{episode.episode_index:05d}.png")
        tiles = max(sheet["index"]) + 1
        assert image.width == sheet["columns"] * sheet["width"]
        assert image.height == -(-tiles // sheet["columns"]) * sheet["height"]
    index = (run_dir / "report" / "index.html").read_text()
    assert 'id="replay-mismatch"' not in index


@pytest.mark.slow
def test_report_needs_no_network(viewed: Any) -> None:
    for page in viewed.index.parent.rglob("*.html"):
        text = page.read_text()
        assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text), page
        assert not re.search(r"""url\(\s*["']?(https?:)?//""", text), page


@pytest.mark.slow
def test_a_replay_that_differs_from_its_record_is_flagged_loudly(
    run_dir: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy_run(run_dir, tmp_path)

    def tamper(record: dict[str, Any]) -> dict[str, Any]:
        if record["episode_index"] == 0:
            record["achievements"] = [*record["achievements"], "DEFEAT_ZOMBIE"]
        # Records from before reset_key existed must still replay.
        record.pop("reset_key")
        return record

    episodes = _rewrite_episodes(run, tamper)
    tampered = next(e for e in episodes if e.episode_index == 0)

    assert main(["view", str(run), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "WARNING: 1 replays do NOT reproduce" in err
    assert tampered.episode_id in err and "DEFEAT_ZOMBIE" in err
    page = (run / "report" / "episodes" / "episode-00000.html").read_text()
    assert 'id="replay-mismatch"' in page and "DEFEAT_ZOMBIE" in page
    assert 'id="replay-mismatch"' in (run / "report" / "index.html").read_text()
    others = run / "report" / "episodes" / "episode-00001.html"
    assert 'id="replay-mismatch"' not in others.read_text()


def test_a_run_without_step_log_gets_pages_without_replays(
    run_dir: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy_run(run_dir, tmp_path)
    (run / "steps.jsonl").unlink()
    outcome = build_view(run, progress=False)
    assert {s.state for s in outcome.statuses.values()} == {"not replayed"}
    assert outcome.frames == 0 and not list((run / "report" / "episodes").glob("*.png"))
    page = (run / "report" / "episodes" / "episode-00000.html").read_text()
    assert 'id="replay-missing"' in page and "--no-record-steps" in page
    assert 'id="frame"' not in page


@pytest.mark.slow
def test_gif_export_shows_every_state_for_the_same_time(run_dir: Path, tmp_path: Path) -> None:
    episode = read_episodes(run_dir / "episodes.jsonl")[1]
    out = tmp_path / "episode.gif"
    assert main(["view", str(run_dir), "--episode", episode.episode_id, "--gif", str(out)]) == 0
    gif = Image.open(out)
    assert (gif.width, gif.height) == (2 * 144, 2 * 144)  # classic frames, enlarged twice
    durations = []
    for number in range(gif.n_frames):
        gif.seek(number)
        durations.append(gif.info["duration"])
    # Pillow merges identical consecutive frames into one longer frame.
    assert sum(durations) == (episode.steps + 1) * round(1000 / FRAMES_PER_SECOND)
    gif.seek(0)
    first = np.asarray(gif.convert("RGB"))
    gif.seek(gif.n_frames - 1)
    assert not np.array_equal(first, np.asarray(gif.convert("RGB")))


def test_mp4_export_without_ffmpeg_is_a_user_error(
    run_dir: Path, tmp_path: Path, capsys: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    if shutil.which("ffmpeg") is not None:
        monkeypatch.setenv("PATH", str(tmp_path))
    out = tmp_path / "episode.mp4"
    assert main(["view", str(run_dir), "--episode", "0", "--gif", str(out)]) == EXIT_USER_ERROR
    assert "ffmpeg is not installed" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--gif", "x.gif"], "--gif writes one episode: give it with --episode"),
        (["--episode", "no/such/0/0", "--gif", "x.gif"], "no finished episode 'no/such/0/0'"),
        (["--episode", "no/such/0/0"], "no finished episode 'no/such/0/0'"),
        (["--sample", "1000"], "--sample 1000 is larger than the"),
        (["--sample", "1", "--outcome", "won"], "unknown --outcome 'won'"),
        (["--class", "Build"], "no episode of"),
        (["--episode", "0", "--sample", "1"], "it does not go with --sample"),
        (["--episode", "0", "--gif", "x.gif", "--compare", "."], "it does not go with --gif"),
        (["--compare", "/no/such/run"], "/no/such/run has no results.json"),
    ],
)
def test_view_flag_mistakes_are_one_line_errors(
    run_dir: Path, tmp_path: Path, capsys: Any, flags: list[str], message: str
) -> None:
    run = _copy_run(run_dir, tmp_path)
    assert main(["view", str(run), *flags]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert sorted(path.name for path in run.iterdir()) == sorted(
        path.name for path in run_dir.iterdir() if path.name != "report"
    )


def test_a_goal_kind_the_viewer_does_not_know_writes_nothing(
    run_dir: Path, tmp_path: Path, capsys: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.viewer import goals

    run = _copy_run(run_dir, tmp_path)
    monkeypatch.delitem(goals.RENDERINGS, "achievements")
    assert main(["view", str(run), "--no-progress"]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert "cannot show goals of kind 'achievements'" in err and "Traceback" not in err
    assert not [path for path in run.iterdir() if "report" in path.name]


def test_a_failure_while_rendering_leaves_the_previous_report(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.viewer import pages

    run = _copy_run(run_dir, tmp_path)
    (run / "report").mkdir()
    (run / "report" / "index.html").write_text("the previous report")

    def fail(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(pages, "_run_context", fail)
    with pytest.raises(RuntimeError):
        build_view(run, progress=False)
    assert (run / "report" / "index.html").read_text() == "the previous report"
    assert sorted(path.name for path in run.iterdir() if "report" in path.name) == ["report"]


@pytest.mark.slow
def test_a_sample_renders_a_seeded_few_and_lists_the_rest(
    run_dir: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy_run(run_dir, tmp_path)
    episodes = read_episodes(run / "episodes.jsonl")
    assert main(["view", str(run), "--sample", "2", "--seed", "3", "--no-progress"]) == 0
    assert f"(2 episodes, {len(episodes) - 2} more listed" in capsys.readouterr().out
    pages = sorted(path.name for path in (run / "report" / "episodes").glob("*.html"))
    assert len(pages) == 2
    index = (run / "report" / "index.html").read_text()
    assert 'id="sample-note"' in index
    for episode in episodes:
        assert episode.instruction in index  # every episode is listed
    assert index.count('href="episodes/episode-') == 2  # links only to rendered pages
    # The same seed draws the same episodes.
    assert main(["view", str(run), "--sample", "2", "--seed", "3", "--no-progress"]) == 0
    assert sorted(p.name for p in (run / "report" / "episodes").glob("*.html")) == pages
    combo = [e for e in episodes if e.category == "combo"]
    assert main(["view", str(run), "--categories", "combo", "--no-progress"]) == 0
    assert len(list((run / "report" / "episodes").glob("*.html"))) == len(combo)


def test_view_of_a_directory_without_a_run_is_a_user_error(tmp_path: Path, capsys: Any) -> None:
    assert main(["view", str(tmp_path)]) == EXIT_USER_ERROR
    assert "has no results.json" in capsys.readouterr().err


def test_sprite_sheet_stores_each_distinct_frame_once() -> None:
    rng = np.random.default_rng(0)
    # Flat colour blocks, like the pixel art: few colours, so the 256-colour sheet is exact.
    blocks = rng.integers(0, 255, size=(3, 4, 5, 3), dtype=np.uint8)
    distinct = blocks.repeat(8, axis=1).repeat(8, axis=2)
    frames = distinct[[0, 0, 1, 2, 1, 0]]
    sheet = sprite_sheet(frames)
    assert sheet.index == [0, 0, 1, 2, 1, 0]
    image = np.asarray(Image.open(io.BytesIO(sheet.png)).convert("RGB"))
    height, width = frames.shape[1:3]
    for tile in range(3):
        row, column = divmod(tile, sheet.columns)
        drawn = image[row * height : (row + 1) * height, column * width : (column + 1) * width]
        assert np.array_equal(drawn, distinct[tile])


# ---------------------------------------------------------------- in a real browser


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    yield from launch_chromium()


def _open(browser: Any, path: Path) -> tuple[Any, list[str]]:
    return open_page(browser, path)


def _cell(rate: dict[str, Any]) -> str:
    goals = f" g={rate['clusters']}" if rate.get("clusters") else ""
    return f"{rate['rate']:.2f} [{rate['low']:.2f}, {rate['high']:.2f}] n={rate['episodes']}{goals}"


@pytest.mark.slow
def test_run_page_in_chromium_shows_the_results(
    run_dir: Path, expert_dir: Path, viewed: Any, browser: Any
) -> None:
    summary = json.loads((run_dir / "results.json").read_text())["summary"]
    page, problems = _open(browser, viewed.index)
    header = page.locator("#results-table thead th").all_inner_texts()
    ours = page.locator("#results-table tr.ours td").all_inner_texts()
    shown = dict(zip(header[1:], ours[1:], strict=True))
    assert shown["combo"] == _cell(summary["by_category"]["combo"])
    assert shown["New objects"] == _cell(summary["by_category"]["new_objects"])
    assert shown["overall"] == _cell(summary["overall"])
    assert shown["one"] == "-"  # not run

    # The expert's row, as `report --compare` gives it, beside the model's.
    expert = json.loads((expert_dir / "results.json").read_text())["summary"]
    compared = page.locator("#results-table tr.compared td").all_inner_texts()
    assert compared[0] == "expert (scripted, no model)"
    beside = dict(zip(header[1:], compared[1:], strict=True))
    assert beside.pop("overall") == _cell(expert["overall"])
    labels = {"one": "one", "combo": "combo", "New objects": "new_objects"}
    assert beside == {
        label: _cell(expert["by_category"][labels[label]])
        if labels[label] in expert["by_category"]
        else "-"
        for label in beside
    }
    assert expert["by_category"]  # the row has numbers to check
    assert page.locator("#compare-note").count() == 0  # same dataset
    # Issue 31: the intervals say they are clustered, and the run's actions are counted.
    assert "clustered by goal" in page.locator("#rates-legend").inner_text()
    actions = summary["actions"]
    cells = page.locator("#actions tr td").all_inner_texts()
    shown_actions = dict(zip(cells[0::3], (int(c) for c in cells[1::3]), strict=True))
    assert shown_actions == actions["counts"] and sum(shown_actions.values()) == actions["steps"]

    episodes = read_episodes(run_dir / "episodes.jsonl")
    rows = page.locator("#episodes tbody tr")
    assert rows.count() == len(episodes)
    page.select_option("#filter-category", "combo")
    visible = page.locator("#episodes tbody tr:visible")
    assert visible.count() == sum(e.category == "combo" for e in episodes)
    assert set(visible.locator("td:nth-child(3)").all_inner_texts()) == {"combo"}
    page.select_option("#filter-category", "")
    page.click("#episodes th:has-text('steps')")
    steps = [int(t) for t in page.locator("#episodes tbody td:nth-child(8)").all_inner_texts()]
    assert steps == sorted(steps)
    # Every goal label of the per-goal chart is drawn whole, however long the goal's id.
    lefts = page.eval_on_selector_all(
        "#chart-goals text", "texts => texts.map((text) => text.getBBox().x)"
    )
    assert lefts and min(lefts) >= 0
    assert problems == []
    page.close()


def _frame_pixels(page: Any) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.locator("#frame").screenshot())).convert("RGB"))


@pytest.mark.slow
def test_episode_page_in_chromium_steps_through_nonblank_frames(
    run_dir: Path, viewed: Any, browser: Any
) -> None:
    episode = max(read_episodes(run_dir / "episodes.jsonl"), key=lambda e: len(e.achievements))
    page, problems = _open(browser, viewed.index)
    page.locator("#episodes").get_by_role("link", name=episode.episode_id, exact=True).click()
    page.wait_for_load_state("load")
    assert page.locator("#instruction").inner_text() == episode.instruction

    first = _frame_pixels(page)
    # Craftax's grass, water, stone and the inventory bar: a blank or broken image has few colours.
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 50 and first.std() > 20
    assert page.locator("#counter").inner_text().startswith(f"frame 0 of {episode.steps}")

    seen_change = False
    for step in range(episode.steps):
        page.keyboard.press("ArrowRight")
        assert page.locator("#counter").inner_text().startswith(f"frame {step + 1} of")
        seen_change = seen_change or not np.array_equal(_frame_pixels(page), first)
        if seen_change and step >= 3:
            break
    assert seen_change
    page.keyboard.press("ArrowLeft")
    page.click("#next")
    page.click("#last")
    assert (
        page.locator("#decision-title").inner_text() == f"End of the episode: {episode.termination}"
    )
    page.keyboard.press("Home")
    assert np.array_equal(_frame_pixels(page), first)
    steps = json.loads(page.locator("#episode-data").text_content())["steps"]
    page.keyboard.press("ArrowRight")
    assert page.locator("#d-raw").text_content() == steps[1]["raw"]
    assert page.locator("#d-action").inner_text().startswith(steps[1]["action"])
    assert problems == []
    page.close()


@pytest.mark.slow
def test_a_replayed_world_does_not_depend_on_its_lane(
    run_dir: Path, viewed: Any, classic_env: CrafTextEnv
) -> None:
    # Vectorized over 12 or more worlds, Craftax's world generation rounds differently from
    # lane 8 on (AVX-512 CPUs): a replay batch must make each world as a lone reset does.
    from env.craftext_env import make_task
    from llm_agents.viewer.pages import _replayer

    # The replayer `view` compiled for the run (16 lanes: build_view's default batch size).
    replayer = _replayer(load_run(run_dir), batch_size=16)
    assert replayer.env is classic_env
    lanes = replayer.batch_size
    keys = np.stack([episode_key(0, "goal", 0, repeat) for repeat in range(lanes)])
    masks = np.zeros((lanes, 22), bool)
    (state, _), _, _ = replayer._reset(keys, make_task(masks, masks))
    for lane in (0, 9, 11, lanes - 1):
        alone = classic_env.jitted_reset(keys[lane], make_task(masks[lane], masks[lane]))
        for batched, single in zip(
            jax.tree.leaves(state.game), jax.tree.leaves(alone.game), strict=True
        ):
            assert np.array_equal(np.asarray(batched)[lane], np.asarray(single))


@pytest.mark.slow
def test_a_replay_does_not_depend_on_the_episodes_beside_it(
    run_dir: Path, viewed: Any, classic_env: CrafTextEnv
) -> None:
    # A chunk skips the steps past its batch's longest episode: a short episode replayed
    # beside a long one (stepped on past its end) and alone (not) must come out the same.
    from env.replay import ReplayInput
    from llm_agents.viewer.pages import _replayer
    from llm_agents.viewer.run import load_run

    rng = np.random.default_rng(4)
    masks = np.zeros(22, bool)
    short, long = (
        ReplayInput(
            reset_key=episode_key(0, "goal", 0, repeat),
            required=masks,
            forbidden=masks,
            actions=rng.integers(0, classic_env.num_actions, length).tolist(),
        )
        for repeat, length in ((0, 3), (1, 10))
    )
    # The replayer `view` compiled for the run (its batch size: build_view's default).
    replayer = _replayer(load_run(run_dir), batch_size=16)
    beside, long_replay = replayer.replay([short, long])
    [alone] = replayer.replay([short])
    assert len(alone.frames) == 4 and len(long_replay.frames) == 11
    for field in ("frames", "trace", "end_map"):
        assert np.array_equal(getattr(beside, field), getattr(alone, field))
    assert (beside.achievements, beside.termination, beside.episode_return) == (
        alone.achievements,
        alone.termination,
        alone.episode_return,
    )


@pytest.mark.slow
def test_a_replay_compiles_only_in_the_calling_thread(tmp_path: Path) -> None:
    # Two threads loading the same executable from the persistent cache at once crashed a
    # process (SIGSEGV in XLA's deserialization): the worker threads may only run what the
    # calling thread compiled. A fresh process, so nothing is compiled before the replay.
    child = """
import threading
import numpy as np
from jax import monitoring
from env import CrafTextEnv, EnvConfig, Variant, episode_key
from env.replay import Replayer, ReplayInput
threads = []
monitoring.register_event_listener(lambda name, **_: threads.append(threading.current_thread().name))
monitoring.register_event_duration_secs_listener(
    lambda name, _, **__: threads.append(threading.current_thread().name)
)
replayer = Replayer(CrafTextEnv(EnvConfig(variant=Variant.CLASSIC)), batch_size=2, render=False)
masks = np.zeros(22, bool)
episodes = [
    ReplayInput(reset_key=episode_key(0, "g", 0, i), required=masks, forbidden=masks, actions=[0] * 3)
    for i in range(5)
]
threads.clear()
assert len(list(replayer.replay(episodes, workers=2))) == 5
print(len(threads), sorted(set(threads)))
"""
    done = subprocess.run(
        [sys.executable, "-c", child],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    assert done.returncode == 0, done.stderr
    events, names = done.stdout.split(maxsplit=1)
    assert int(events) > 0
    assert names.strip() == "['MainThread']"


@pytest.mark.slow
def test_run_page_shows_the_achievement_scores_report_prints(
    run_dir: Path, expert_dir: Path, viewed: Any
) -> None:
    from llm_agents.evaluation.run_view import read_run
    from llm_agents.judging.rescoring import run_scores

    index = (run_dir / "report" / "index.html").read_text()
    section = index.split('id="scores-table"')[1].split("</table>")[0]
    for path, row_class in ((run_dir, ""), (expert_dir, ' class="compared"')):
        run = read_run(path)
        scores = run_scores(run.results, run.episodes)
        overall = scores.overall
        cell = f"{overall.progression:.1f} ± {overall.progression_stderr:.1f}"
        row = re.search(rf'<tr{row_class}><td>[^<]*</td><td class="num">([^<]*)</td>', section)
        assert row is not None and row.group(1) == cell
    assert "Crafter&#39;s 22 achievements" in index or "Crafter's 22 achievements" in index
    episodes = read_episodes(run_dir / "episodes.jsonl")
    table = index.split('id="episode-scores"')[1].split("</table>")[0]
    assert table.count("<tr>") == len(episodes) + 1


@pytest.mark.slow
def test_an_open_ended_run_replays_from_its_own_goal(
    tmp_path: Path, classic_env: CrafTextEnv
) -> None:
    out = tmp_path / "balrog"
    config = build_config(
        {
            "protocol": "balrog",
            "model": SCRIPT,
            "max_steps": MAX_STEPS,
            "episodes_per_instruction": 2,
            "batch_size": 2,
            "output_dir": str(out),
        }
    )
    with get_model(config.model, config.generation) as model:
        run_eval(config, model, env=classic_env)
    viewed = build_view(out, progress=False)
    assert {s.state for s in viewed.statuses.values()} == {"reproduced"}
    assert len(viewed.statuses) == 2


# ---------------------------------------------------------------- every goal kind


def test_every_goal_kind_has_a_rendering() -> None:
    from typing import get_args

    from env.goals import GOAL_KINDS, AnyGoal
    from llm_agents.viewer.goals import RENDERINGS, unrendered_kinds

    # The kinds the goal records can take, read from the union itself: a kind added to
    # `env.goals` without a rendering fails here.
    union = get_args(get_args(AnyGoal)[0])
    kinds = {get_args(member)[0].model_fields["kind"].default for member in union}
    assert kinds == set(GOAL_KINDS)
    assert unrendered_kinds() == []
    assert set(RENDERINGS) == kinds


@pytest.fixture(scope="module")
def every_kind(
    official_repository: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Path]:
    """An expert run per difficulty holding one episode of each of its goal kinds, from the
    official data, a few steps each, on Classic Craftax: Hard's protocol is full Craftax, whose
    replay compiles for minutes on a small machine, so each Hard kind is played with its first
    goal that Classic can score (what the viewer shows of a goal does not depend on the game)."""
    from env.dataset import Dataset, DatasetSource
    from env.errors import UserError
    from env.goals import DIFFICULTY_KINDS
    from env.official_source import parse_directory
    from env.scenario_tasks import encode_goal

    def classic(goal: Any) -> bool:
        try:
            return goal.kind == "achievements" or bool(encode_goal(goal, Variant.CLASSIC))
        except UserError:
            return False

    official = parse_directory(official_repository)
    out = tmp_path_factory.mktemp("every-kind")
    runs = {}
    for difficulty, variant in (("medium", "classic"), ("hard", "classic")):
        picked: dict[str, Any] = {}
        for goal in official.goals:
            if goal.difficulty == difficulty and goal.split.endswith("_train") and classic(goal):
                picked.setdefault(goal.kind, goal)
        assert set(picked) == set(DIFFICULTY_KINDS[difficulty])
        data = out / f"{difficulty}.json"
        source = DatasetSource(kind="json", path=str(data))
        Dataset(source=source, goals=tuple(picked.values())).save_json(data)
        config = build_config(
            {
                "agent": "expert",
                "difficulty": difficulty,
                "categories": ["train"],
                "variant": variant,
                "paraphrases": False,
                "max_steps": 6,
                "batch_size": 8,
                "dataset": str(data),
                "output_dir": str(out / difficulty),
                "probe": False,
            }
        )
        run_eval(config, NoModel())
        assert main(["view", str(out / difficulty), "--no-progress"]) == 0
        runs[difficulty] = out / difficulty
    return runs


@pytest.mark.slow
@pytest.mark.parametrize("difficulty", ["medium", "hard"])
def test_every_goal_kind_gets_a_page_naming_its_parameters(
    every_kind: dict[str, Path], difficulty: str
) -> None:
    from llm_agents.viewer.goals import rendering_of

    run = load_run(every_kind[difficulty])
    kinds = set()
    for view in run.episodes:
        goal = view.goal
        assert goal is not None
        kinds.add(goal.kind)
        page = (every_kind[difficulty] / "report" / "episodes" / view.page).read_text()
        words = rendering_of(goal.kind).describe(goal)
        assert 'id="replay-state">reproduced' in page
        # The parameters in words, each of them named, and the dataset's JSON of the goal.
        assert f'id="goal-words">{words}<' in page.replace("&#39;", "'")
        for value in goal.parameters():
            shown = value if isinstance(value, str | int) and not isinstance(value, bool) else None
            if isinstance(shown, str) and shown.isupper():
                assert shown.lower().replace("_", " ") in words
            elif shown is not None:
                assert str(shown) in words
        assert f"&#34;id&#34;: &#34;{goal.id}&#34;" in page
        fired = "after step" if view.record.success else "never"
        assert re.search(rf'id="goal-fired">{fired}', page)
        if goal.kind == "conditional_placing":
            assert 'id="count-chart"' in page
        elif goal.kind != "achievements":
            assert 'id="checker-map"' in page
            data = json.loads(re.search(r'id="episode-data">(.*?)</script>', page, re.S).group(1))
            region = data["checker"]["marks"]["region"]
            row, column = data["checker"]["positions"][data["checker"]["last"]]
            # The region is around the player (a line's window may be pushed off the edges).
            assert region[2] >= 1 and region[3] >= 1
            if goal.kind == "localization_placing":
                assert region[:2] == [row - 5, column - 5]
    assert kinds == {g for g in rendering_of.__globals__["RENDERINGS"] if g in kinds}
    assert len(kinds) == 5


def test_the_words_follow_the_checkers_semantics() -> None:
    from env.goals import BuildLineGoal, ConditionalPlacingGoal, LocalizationGoal
    from llm_agents.viewer.goals import rendering_of

    texts = {"instruction": "x", "paraphrases": (), "split": "medium_train", "scenario": "medium"}
    line = BuildLineGoal(id="L", block="STONE", size=3, diagonal=True, **texts)
    assert rendering_of("build_line").describe(line) == "a diagonal line of 3 stones"
    place = LocalizationGoal(
        id="P", place="FURNACE", target="CRAFTING_TABLE", side="left", distance=2, **texts
    )
    assert (
        rendering_of("localization_placing")
        .describe(place)
        .startswith("a furnace 2 cells left of a crafting table")
    )
    conditional = ConditionalPlacingGoal(
        id="C", collect="iron", collect_count=3, place="CRAFTING_TABLE", place_count=2, **texts
    )
    assert (
        rendering_of("conditional_placing")
        .describe(conditional)
        .startswith("hold 3 iron, then place 2 crafting tables")
    )


@pytest.mark.slow
def test_every_page_of_every_goal_kind_in_chromium(
    every_kind: dict[str, Path], browser: Any
) -> None:
    from llm_agents.viewer.goals import rendering_of

    for difficulty, run_path in every_kind.items():
        run = load_run(run_path)
        index, problems = _open(browser, run_path / "report" / "index.html")
        assert index.locator("#scenario-table tbody tr").count() == len(
            {view.record.scenario_class for view in run.episodes}
        )
        index.locator("a.show-class", has_text="Build").click()
        shown = index.locator("#episodes tbody tr:visible td:nth-child(4)").all_inner_texts()
        assert shown and set(shown) == {"Build"}
        assert problems == [], (difficulty, problems)
        index.close()
        for view in run.episodes:
            assert view.goal is not None
            page, problems = _open(browser, run_path / "report" / "episodes" / view.page)
            words = rendering_of(view.goal.kind).describe(view.goal)
            assert page.locator("#goal-words").inner_text() == words
            if view.goal.kind == "localization_placing":
                # The checker's area is centred on the player: it is on every frame.
                page.keyboard.press("End")
                assert page.locator("#marks rect.region").count() == 1
                page.uncheck("#show-marks")
                assert page.locator("#marks rect").count() == 0
            if view.goal.kind == "conditional_placing":
                assert page.locator("#count-chart polyline").count() == 2
            assert problems == [], (view.page, problems)
            page.close()


@pytest.mark.slow
def test_a_guided_episode_shows_the_models_reading_beside_the_truth(
    every_kind: dict[str, Path], tmp_path: Path
) -> None:
    run = _copy_run(every_kind["medium"], tmp_path)
    wrong = {
        "kind": "localization_placing",
        "place": "STONE",
        "target": "FURNACE",
        "side": "right",
        "distance": 1,
    }
    grounding = {"outcome": "valid", "stage": "json", "reading": wrong, "raw": json.dumps(wrong)}

    def read_wrongly(record: dict[str, Any]) -> dict[str, Any]:
        if record["goal_id"] == "INSTRUCTION_PLACE_STONE_FURNACE_1_1":
            record.update(grounding=grounding, grounding_correct=False)
        return record

    (episode,) = [
        e for e in _rewrite_episodes(run, read_wrongly) if e.grounding_correct is not None
    ]
    assert main(["view", str(run), "--episode", episode.episode_id, "--no-progress"]) == 0
    (page,) = (run / "report" / "episodes").glob("*.html")
    reading = re.search(r'id="goal-reading">(.*?)</div>', page.read_text(), re.S).group(1)
    assert "a stone 1 cell right of a furnace" in reading  # what the model read
    assert "a stone 1 cell left of a furnace" in reading  # the dataset's goal
    assert 'id="reading-verdict">wrong' in reading
