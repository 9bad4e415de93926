"""Results cards and the leaderboard: a card holds what a real (mock-backend) run's records give,
`card --verify` names every figure a changed record or an edited card no longer agrees with,
mistakes are one line with nothing written, and the leaderboard page works in Chromium."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from headless import launch_chromium, open_page

from llm_agents.agents import NoModel
from llm_agents.backends import get_model
from llm_agents.cli import main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.judging.card import model_size_billions
from llm_agents.judging.published import PUBLISHED, PUBLISHED_MEDIUM, PUBLISHED_TRAINED_EASY
from llm_agents.run_data.metrics import clustered_rate

MAX_STEPS = 30
SCRIPT = "mock:hash:ACTION: DO|ACTION: LEFT|I go RIGHT|<action>UP</action>|ACTION: DO|hmm|DOWN"


def _config(out: Path, **settings: Any) -> Any:
    return build_config(
        {
            "protocol": "paper",
            "categories": ["combo", "new_objects"],
            "max_steps": MAX_STEPS,
            "batch_size": 4,
            "output_dir": str(out),
            **settings,
        }
    )


@pytest.fixture(scope="module")
def model_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "mock-zero-shot"
    config = _config(out, model=SCRIPT, limit=6)
    with get_model(config.model, config.generation) as model:
        run_eval(config, model)
    return out


@pytest.fixture(scope="module")
def expert_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "expert"
    run_eval(_config(out, agent="expert", limit=4), NoModel())
    return out


def _copy(run: Path, tmp_path: Path, name: str | None = None) -> Path:
    copy = tmp_path / (name or run.name)
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("card.*", "report"))
    return copy


def _card(run: Path, capsys: Any) -> dict[str, Any]:
    assert main(["card", str(run)]) == 0
    capsys.readouterr()
    data: dict[str, Any] = json.loads((run / "card.json").read_text())
    return data


def _episodes(run: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]


def _reseal(card: dict[str, Any]) -> None:
    """Give an edited card the digest of its new content, as a careful forger would."""
    body = {key: value for key, value in card.items() if key != "digest"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    card["digest"] = hashlib.sha256(canonical.encode()).hexdigest()


def _one_error(capsys: Any) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    return lines[0]


# ---------------------------------------------------------------- cards


def test_a_card_holds_what_the_run_records_give(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(model_run, tmp_path)
    card = _card(run, capsys)
    episodes = _episodes(run)
    results = json.loads((run / "results.json").read_text())
    figures = card["figures"]

    assert card["schema_version"] == 3 and card["agent"] == "zero-shot"
    assert card["model"]["spec"] == SCRIPT and card["model"]["pinned_digest"] is None
    assert card["protocol"]["name"] == "paper" and card["protocol"]["difficulty"] == "easy"
    # The step cap and goal sets were set against the protocol's; the limit is recorded beside.
    assert card["protocol"]["departures"] == {
        "categories": {
            "protocol": ["one", "combo", "new_objects"],
            "run": ["combo", "new_objects"],
        },
        "max_steps": {"protocol": 250, "run": MAX_STEPS},
    }
    assert card["protocol"]["limit"] == 6
    assert card["code_version"] == results["versions"]["code"]
    assert card["hardware"] == results["hardware"] and int(card["hardware"]["cpu_cores"]) >= 1
    assert card["dataset_digest"] == results["identity"]["dataset"]

    assert figures["episodes"] == len(episodes) == 6
    assert figures["success"]["successes"] == sum(e["success"] for e in episodes)
    goals: Counter[tuple[str, str]] = Counter()
    wins: Counter[tuple[str, str]] = Counter()
    for e in episodes:
        goals[(e["category"], e["goal_id"])] += 1
        wins[(e["category"], e["goal_id"])] += e["success"]
    expected = clustered_rate({goal: (wins[goal], goals[goal]) for goal in goals})
    assert figures["success"]["low"] == pytest.approx(expected.low)
    assert figures["success"]["high"] == pytest.approx(expected.high)
    assert set(figures["success_by_category"]) == {e["category"] for e in episodes}
    for category, rate in figures["success_by_category"].items():
        mine = [e for e in episodes if e["category"] == category]
        assert rate["episodes"] == len(mine)
        assert rate["successes"] == sum(e["success"] for e in mine)
    cost = figures["cost"]
    assert cost["prompt_tokens_per_episode"] == pytest.approx(
        sum(e["prompt_tokens"] for e in episodes) / 6
    )
    assert cost["prompt_tokens_per_episode"] > 0
    assert cost["model_calls_per_episode"] == pytest.approx(
        sum(e["model_calls"] for e in episodes) / 6
    )
    steps = [json.loads(line) for line in (run / "steps.jsonl").read_text().splitlines()]
    assert cost["model_seconds_per_episode"] == pytest.approx(
        sum(s["latency_s"] for s in steps) / 6
    )
    unlocked = [{a.upper() for a in e["achievements"]} for e in episodes]
    assert figures["scores"]["progression"] == pytest.approx(
        100 * sum(len(u) for u in unlocked) / 6 / 22
    )

    md = (run / "card.md").read_text()
    overall = figures["success"]
    assert f"{overall['rate']:.2f} [{overall['low']:.2f}, {overall['high']:.2f}]" in md
    assert "max_steps = 30 (protocol: 250)" in md


def test_cards_of_other_runs_differ_where_their_settings_do(
    model_run: Path, expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    ours = _card(_copy(model_run, tmp_path), capsys)
    again = _card(_copy(model_run, tmp_path, "again"), capsys)
    expert = _card(_copy(expert_run, tmp_path), capsys)
    assert ours["settings_digest"] == again["settings_digest"]
    assert ours["figures"] == again["figures"]
    assert expert["settings_digest"] != ours["settings_digest"]
    assert expert["model"] == {
        "spec": None,
        "resolved_revision": None,
        "pinned_digest": None,
        "size_billions": None,
    }
    assert expert["figures"]["cost"]["model_calls_per_episode"] == 0


def test_verify_accepts_the_card_and_refuses_a_changed_record_or_answer(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(model_run, tmp_path)
    card = _card(run, capsys)
    # The zero-shot agent's actions are parsed answers: each was parsed again.
    steps = [json.loads(line) for line in (run / "steps.jsonl").read_text().splitlines()]
    assert card["replay"]["answers"] == len(steps) > 0
    assert main(["card", "--verify", str(run / "card.json"), str(run)]) == 0
    assert "matches" in capsys.readouterr().out

    # One episode's outcome changed in the records after the card was written.
    original = (run / "episodes.jsonl").read_text()
    episodes = _episodes(run)
    flipped = episodes[0]
    flipped["success"] = not flipped["success"]
    flipped["termination"] = "success" if flipped["success"] else "timeout"
    (run / "episodes.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    assert main(["card", "--verify", str(run / "card.json"), str(run)]) == 1
    line = _one_error(capsys)
    assert (
        f"episode {flipped['episode_id']}: termination: recorded {flipped['termination']}" in line
    )

    # A recorded answer that does not give the recorded action (the action replays: it is the
    # answer that was changed).
    (run / "episodes.jsonl").write_text(original)
    answered = next(s for s in steps if s["action_name"] != "NOOP" and not s["fallback_used"])
    answered["raw_output"] = "ACTION: NOOP"
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    assert main(["card", "--verify", str(run / "card.json"), str(run)]) == 1
    line = _one_error(capsys)
    assert f"episode {answered['episode_id']}: step {answered['step']} action: recorded" in line
    assert "gives NOOP" in line


def test_answers_are_parsed_again_whatever_the_records_say_of_the_model(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    # Whether answers are parsed again follows from the agent: zeroing every count that says a
    # model was asked must not switch the check off.
    run = _copy(model_run, tmp_path)
    steps = [json.loads(line) for line in (run / "steps.jsonl").read_text().splitlines()]
    answered = next(s for s in steps if s["action_name"] != "NOOP" and not s["fallback_used"])
    answered["raw_output"] = "ACTION: NOOP"
    for step in steps:
        step.update(prompt_tokens=0, completion_tokens=0, computed_prompt_tokens=None)
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    episodes = _episodes(run)
    for episode in episodes:
        episode.update(
            model_calls=0, prompt_tokens=0, completion_tokens=0, computed_prompt_tokens=None
        )
    (run / "episodes.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    assert main(["card", str(run)]) == 1
    line = _one_error(capsys)
    assert f"episode {answered['episode_id']}: step {answered['step']} action: recorded" in line
    assert "gives NOOP" in line
    assert not (run / "card.json").exists()

    # Unedited answers with the counts zeroed: still parsed again, and the card names the model.
    answered["raw_output"] = next(
        json.loads(line)
        for line in (model_run / "steps.jsonl").read_text().splitlines()
        if json.loads(line)["episode_id"] == answered["episode_id"]
        and json.loads(line)["step"] == answered["step"]
    )["raw_output"]
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    card = _card(run, capsys)
    assert card["replay"]["answers"] == len(steps)
    assert card["model"]["spec"] == SCRIPT


def test_an_edited_card_is_refused_and_a_resealed_one_fails_verification(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(model_run, tmp_path)
    card = _card(run, capsys)
    card["figures"]["success"]["rate"] = 0.99
    path = run / "card.json"
    path.write_text(json.dumps(card))
    assert main(["card", "--verify", str(path), str(run)]) == 2
    assert "changed after it was written" in _one_error(capsys)

    _reseal(card)
    path.write_text(json.dumps(card))
    assert main(["card", "--verify", str(path), str(run)]) == 1
    err = capsys.readouterr().err
    assert "figures.success.rate: card 0.99" in err
    assert "1 figures differ" in err


def test_a_card_of_another_schema_version_is_refused(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(model_run, tmp_path)
    card = _card(run, capsys)
    # Version 2 cards (figures read from the records once they replayed) are refused, not read.
    for version in (1, 2):
        card["schema_version"] = version
        _reseal(card)
        (run / "card.json").write_text(json.dumps(card))
        before = sorted(p.name for p in run.iterdir())
        assert main(["card", "--verify", str(run / "card.json"), str(run)]) == 2
        assert f"schema version {version}" in _one_error(capsys)
        markdown = ["--markdown", str(tmp_path / "t.md")]
        assert main(["leaderboard", str(run / "card.json"), *markdown]) == 2
        assert f"schema version {version}" in _one_error(capsys)
        assert not (tmp_path / "t.md").exists()
        assert sorted(p.name for p in run.iterdir()) == before


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"status": "partial", "finished_at": None}, "only for a complete run"),
        ({"config": "no protocol"}, "records no protocol"),
    ],
)
def test_no_card_for_an_incomplete_run_or_one_without_protocol(
    model_run: Path, tmp_path: Path, capsys: Any, change: dict[str, Any], message: str
) -> None:
    run = _copy(model_run, tmp_path)
    results = json.loads((run / "results.json").read_text())
    if change.get("config"):
        del results["config"]["protocol"]
    else:
        results.update(change)
    (run / "results.json").write_text(json.dumps(results))
    before = sorted(p.name for p in run.iterdir())
    assert main(["card", str(run)]) == 2
    assert message in _one_error(capsys)
    assert sorted(p.name for p in run.iterdir()) == before


def test_a_directory_that_is_not_a_run_is_one_line_and_nothing_written(
    model_run: Path, tmp_path: Path, capsys: Any
) -> None:
    run = _copy(model_run, tmp_path)
    _card(run, capsys)
    empty = tmp_path / "empty"
    empty.mkdir()
    for arguments in (
        ["card", str(empty)],
        ["card", "--verify", str(run / "card.json"), str(empty)],
    ):
        assert main(arguments) == 2
        assert "it is not a run directory" in _one_error(capsys)
    assert not any(empty.iterdir())


def test_a_card_given_with_another_run_is_one_line_and_nothing_written(
    model_run: Path, expert_run: Path, tmp_path: Path, capsys: Any
) -> None:
    ours = _copy(model_run, tmp_path)
    _card(ours, capsys)
    other = _copy(expert_run, tmp_path)
    before = sorted(p.name for p in other.iterdir())
    assert main(["card", "--verify", str(ours / "card.json"), str(other)]) == 2
    line = _one_error(capsys)
    assert f"is not the card of the run in {other}" in line
    assert sorted(p.name for p in other.iterdir()) == before


@pytest.mark.parametrize(
    ("name", "billions"),
    [
        ("hf:smollm2-135m", 0.135),
        ("hf:qwen2.5-coder-0.5b", 0.5),
        ("Qwen2.5-7B-it", 7.0),
        ("Llama-3.2-1B-it", 1.0),
        ("DeepSeek-R1-Distill-Qwen-32B", 32.0),
        ("GPT-4o", None),
        ("mock:hash:ACTION: DO", None),
    ],
)
def test_model_size_is_read_from_the_name(name: str, billions: float | None) -> None:
    assert model_size_billions(name) == billions


# ---------------------------------------------------------------- the leaderboard


@pytest.fixture(scope="module")
def carded(
    model_run: Path, expert_run: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Path]:
    """Copies of both runs, each with its card."""
    root = tmp_path_factory.mktemp("carded")
    runs = {name: _copy(run, root) for name, run in (("model", model_run), ("expert", expert_run))}
    for run in runs.values():
        assert main(["card", str(run)]) == 0
    return runs


def test_leaderboard_mistakes_are_one_line_and_write_nothing(
    carded: dict[str, Path], tmp_path: Path, capsys: Any
) -> None:
    out = tmp_path / "site"
    card = carded["model"] / "card.json"
    with pytest.raises(SystemExit) as exited:
        main(["leaderboard", "--out", str(out)])
    assert exited.value.code == 2
    assert "Traceback" not in capsys.readouterr().err

    shutil.copyfile(card, tmp_path / "same.json")
    # The same run's card written again differs in its writing time, so in its digest.
    rewritten = json.loads(card.read_text())
    rewritten["created_at"] = "2030-01-01T00:00:00Z"
    _reseal(rewritten)
    (tmp_path / "again.json").write_text(json.dumps(rewritten))
    for twice in ([card, card], [card, tmp_path / "same.json"], [card, tmp_path / "again.json"]):
        assert main(["leaderboard", *map(str, twice), "--out", str(out)]) == 2
        assert "given twice" in _one_error(capsys)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    assert main(["leaderboard", str(card), "--out", str(tmp_path / "other")]) == 2
    assert "holds other files" in _one_error(capsys)
    assert main(["leaderboard", str(card)]) == 2
    assert "--out DIR, --markdown FILE" in _one_error(capsys)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.json", "other", "same.json"]


def test_leaderboard_refuses_a_card_its_run_does_not_give(
    carded: dict[str, Path], tmp_path: Path, capsys: Any
) -> None:
    run = _copy(carded["expert"], tmp_path)
    episodes = _episodes(run)
    episodes[-1]["achievements"] = [*episodes[-1]["achievements"], "COLLECT_DIAMOND"]
    (run / "episodes.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    card = carded["expert"] / "card.json"
    out = tmp_path / "site"
    code = main(
        [
            *("leaderboard", f"{carded['model'] / 'card.json'}", f"{card}={run}"),
            *("--unverified", "--out", str(out)),
        ]
    )
    assert code == 1
    err = capsys.readouterr().err
    assert f"refused 1 card(s) that their runs' records do not give: {card}" in err
    assert f"episode {episodes[-1]['episode_id']}: achievements: recorded" in err
    assert not out.exists()


def test_a_card_given_with_a_run_not_its_own_is_one_line(
    carded: dict[str, Path], tmp_path: Path, capsys: Any
) -> None:
    card, other = carded["model"] / "card.json", carded["expert"]
    out = tmp_path / "site"
    assert main(["leaderboard", f"{card}={other}", "--out", str(out)]) == 2
    assert f"card {card} is not the card of the run in {other}" in _one_error(capsys)
    assert not out.exists()


def test_the_markdown_tables_rank_only_cards_replayed_here(
    carded: dict[str, Path], tmp_path: Path, capsys: Any
) -> None:
    target = tmp_path / "results.md"
    model, expert = (carded[name] / "card.json" for name in ("model", "expert"))
    # The model's card records the replay it passed at `card` time: given alone, it is still
    # not replayed here.
    assert json.loads(model.read_text())["replay"] is not None
    assert main(["leaderboard", str(model), "--markdown", str(target)]) == 2
    assert "cannot be replayed here (it is given without its run)" in _one_error(capsys)
    assert not target.exists()

    arguments = [str(model), f"{expert}={carded['expert']}", "--unverified"]
    assert main(["leaderboard", *arguments, "--markdown", str(target)]) == 0
    assert "1 replayed here and ranked, 1 not replayed here" in capsys.readouterr().out
    text = target.read_text()
    ranked, _, apart = text.partition("NOT replayed here")
    for path, part, replay in ((expert, ranked, "replayed here"), (model, apart, "the card says")):
        card = json.loads(path.read_text())
        # Each row links its card.md, beside its card.json, and says what ran under what rule.
        link = Path(os.path.relpath(path.with_name("card.md"), tmp_path)).as_posix()
        row = next(
            line for line in part.splitlines() if line.startswith(f"| [{card['run']}]({link}) |")
        )
        rate = card["figures"]["success"]
        assert f"| {rate['rate']:.2f} [{rate['low']:.2f}, {rate['high']:.2f}] |" in row
        assert f"`{card['code_version']}`" in row and f"| `{card['success_rule']}` |" in row
        assert "step cap: 30 steps (paper: 250)" in row and row.endswith(" |")
        assert replay in row.split("|")[-2]
    # Both runs differ from the paper's protocol (30 steps): neither is beside the paper's rows.
    assert "**EASY, protocol paper: not comparable with the paper's numbers**" in ranked
    assert "**EASY, protocol paper**" not in text
    assert not (tmp_path / "site").exists()

    # A card.md edited by hand is not the card's: the row no longer links it.
    edited = tmp_path / "edited"
    shutil.copytree(carded["model"], edited, ignore=shutil.ignore_patterns("report"))
    (edited / "card.md").write_text("# Results card\n\n<script>alert(1)</script>\n")
    arguments = [str(edited / "card.json"), "--unverified", "--markdown", str(target)]
    assert main(["leaderboard", *arguments]) == 0
    assert "not linked, having no card.md of their own" in capsys.readouterr().out
    assert "card.md" not in target.read_text()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    yield from launch_chromium()


def _board_rows(page: Any, section: str) -> list[str]:
    return [
        name.strip()
        for name in page.locator(
            f"#table-{section} tbody tr td:first-child .name"
        ).all_inner_texts()
    ]


@pytest.mark.slow
def test_leaderboard_page_in_chromium_sorts_filters_and_links(
    carded: dict[str, Path], tmp_path: Path, browser: Any, capsys: Any
) -> None:
    from llm_agents.viewer import build_view

    expert = carded["expert"]
    build_view(expert, progress=False)
    out = tmp_path / "site"
    arguments = [str(carded["model"] / "card.json"), f"{expert / 'card.json'}={expert}"]
    assert main(["leaderboard", *arguments, "--unverified", "--out", str(out)]) == 0
    # A rebuild replaces the earlier site whole.
    assert main(["leaderboard", *arguments, "--unverified", "--out", str(out)]) == 0
    capsys.readouterr()
    assert not [p for p in tmp_path.iterdir() if p.name != "site"]

    page, problems = open_page(browser, out / "index.html")
    cards = {name: json.loads((carded[name] / "card.json").read_text()) for name in carded}
    model_name, expert_name = cards["model"]["run"], cards["expert"]["run"]

    # EASY paper: only the paper's zero-shot rows and its trained agent, marked published:
    # both cards depart from the paper's protocol (30 steps), the model's is not replayed here.
    easy_published = [*PUBLISHED, *PUBLISHED_TRAINED_EASY]
    assert _board_rows(page, "easy-paper") == [p.model for p in easy_published]
    published = page.locator("#table-easy-paper tr.published")
    assert published.locator(".badge").all_inner_texts() == ["published"] * len(easy_published)
    assert _board_rows(page, "medium-paper") == [p.model for p in PUBLISHED_MEDIUM]
    assert _board_rows(page, "easy-paper-differs") == [expert_name]
    assert _board_rows(page, "easy-paper-unverified") == [model_name]
    headings = page.locator("h2").all_inner_texts()
    assert "EASY, protocol paper: NOT replayed here" in headings
    assert "nothing here checked them" in page.locator("p.unverified-note").inner_text()
    # Each card's row: its rule, its data source, its departures; intervals drawn for cards.
    row = page.locator("#table-easy-paper-differs tr.card").first
    assert row.locator("td.rule").inner_text() == cards["expert"]["success_rule"]
    assert row.locator("td.data").inner_text()
    assert "max_steps = 30" in row.locator(".departure-list").inner_text()
    assert row.locator("line.ci").count() >= 2
    assert published.first.locator("line.ci").count() == 0

    # Sorting: by `combo` ascending, then descending; rows without the figure stay last.
    header = page.locator("#table-easy-paper th[data-key='rate:combo']")
    header.click()
    descending = _board_rows(page, "easy-paper")
    header.click()
    ascending = _board_rows(page, "easy-paper")
    assert header.get_attribute("aria-sort") == "ascending"

    def combo(name: str) -> float:
        return next(p.rates["combo"] for p in easy_published if p.model == name)

    assert [combo(n) for n in ascending] == sorted(combo(n) for n in ascending)
    assert [combo(n) for n in descending] == sorted((combo(n) for n in descending), reverse=True)

    # Filters: by agent, and by model size (the expert has no model; the paper's are 24-32B).
    page.locator("#agent-filter input[value='expert']").uncheck()
    assert _board_rows(page, "easy-paper-differs") == []
    page.locator("#agent-filter input[value='expert']").check()
    page.select_option("#size-filter", "none")
    no_model = [p.model for p in PUBLISHED_TRAINED_EASY]
    assert sorted(_board_rows(page, "easy-paper")) == sorted(no_model)
    assert _board_rows(page, "easy-paper-differs") == [expert_name]
    page.select_option("#size-filter", "large")
    assert sorted(_board_rows(page, "easy-paper")) == sorted(p.model for p in PUBLISHED)
    page.select_option("#size-filter", "all")

    # Links: each card row to its card in the site; the expert's, given its run, to the copy
    # of its report in the site. Nothing the page links is outside the folder.
    for name, section in (("model", "easy-paper-unverified"), ("expert", "easy-paper-differs")):
        row = page.locator(f"#table-{section} tr.card").first
        href = row.locator("a.card-link").get_attribute("href")
        assert json.loads((out / href).read_text())["digest"] == cards[name]["digest"]
        assert (out / row.locator("a.card-md-link").get_attribute("href")).is_file()
    hrefs = page.locator("a[href]").evaluate_all("links => links.map(a => a.href)")
    assert hrefs and all(h.startswith(out.resolve().as_uri() + "/") for h in hrefs), hrefs
    assert page.locator("#table-easy-paper-unverified a.view-link").count() == 0
    expert_row = page.locator("#table-easy-paper-differs tr.card").first
    view = expert_row.locator("a.view-link").get_attribute("href")
    assert (out / view).is_file() and (out / view).resolve().is_relative_to(out.resolve())
    expert_row.locator("a.view-link").click()
    page.wait_for_load_state("load")
    assert page.url == (out / view).resolve().as_uri()
    assert problems == []
