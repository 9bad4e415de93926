"""Grounding: the parser of goal answers, the scores, `craftext-llm ground` (resume, report, bad
input) and the `guided` agent (cached readings, unstarted episodes, understanding in the report),
on the mock backend; one real run with the embedded model."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from env.dataset import Dataset, DatasetSource, Goal, load_dataset
from env.errors import UserError
from llm_agents.agents.grounding import parse_grounding, reading_json
from llm_agents.backends.base import ChatMessage
from llm_agents.backends.mock import MockModel
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import EvalConfig, build_config, build_settings
from llm_agents.evaluation.grounding_run import (
    GroundConfig,
    execute_grounding,
    prepare_grounding,
    read_ground_results,
    read_groundings,
)
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.grounding_metrics import Scored, confusions, score
from llm_agents.run_data.metrics import wilson_interval
from llm_agents.run_data.readings import EasyReading
from llm_agents.run_data.store import read_episodes, read_results

CLASSIC = Variant.CLASSIC


def goal(split: str, goal_id: str, text: str, required: tuple[str, ...], forbidden=()) -> Goal:
    from env.goals import category_of

    return Goal(
        id=goal_id,
        split=split,  # type: ignore[arg-type]
        category=category_of(split, required, forbidden),  # type: ignore[arg-type]
        instruction=text,
        paraphrases=(f"{text} (again)",),
        required=required,
        forbidden=forbidden,
    )


GOALS = (
    goal("easy_train", "COLLECT_WOOD", "Collect wood.", ("COLLECT_WOOD",)),
    goal(
        "easy_train",
        "PLACE_TABLE_NO_SAPLING",
        "Make a table but do not collect saplings.",
        ("PLACE_TABLE",),
        ("COLLECT_SAPLING",),
    ),
    goal("easy_test_other_params", "DRINK", "Drink some water.", ("COLLECT_DRINK",)),
)


@pytest.fixture
def dataset_file(tmp_path: Path) -> Path:
    source = DatasetSource(kind="json", path="test goals")
    return Dataset(source=source, goals=GOALS).save_json(tmp_path / "goals.json")


def right_answer(text: str) -> str:
    """The correct JSON for every text of GOALS."""
    for item in GOALS:
        if text in item.texts:
            return reading_json(EasyReading(required=item.required, forbidden=item.forbidden))
    raise AssertionError(text)


def instruction_of(conversation: Sequence[ChatMessage]) -> str:
    return conversation[-1].content.removeprefix("Instruction: ").strip()


# ----------------------------------------------------------------------------- the parser


@pytest.mark.parametrize(
    ("answer", "stage"),
    [
        ('{"required": ["PLACE_TABLE"], "forbidden": ["COLLECT_SAPLING"]}', "json"),
        ('Sure!\n```json\n{"required": ["place table"], "forbidden": ["collect sapling"]}\n```', "fenced"),
        ('The goal is {"forbidden": ["Collect_Sapling"], "required": ["PLACE_TABLE"]} I think', "embedded"),
    ],
)  # fmt: skip
def test_a_goal_is_read_wherever_the_answer_puts_it(answer: str, stage: str) -> None:
    grounding = parse_grounding(answer, CLASSIC)
    assert grounding.outcome == "valid" and grounding.stage == stage
    assert grounding.reading == EasyReading(
        required=("PLACE_TABLE",), forbidden=("COLLECT_SAPLING",)
    )


@pytest.mark.parametrize(
    ("answer", "reason"),
    [
        ("I would place a table.", "no JSON object"),
        ('{"required": ["PLACE_TABLE"', "no JSON object"),
        ('note {"required": [PLACE_TABLE]}', "JSON does not parse"),
        ('["PLACE_TABLE"]', "not a goal: the JSON is not an object"),
        ('{"required": ["BUILD_CASTLE"]}', "unknown achievement: 'BUILD_CASTLE'"),
        ('{"required": "PLACE_TABLE"}', "not a goal: required is not a list"),
        ('{"required": [], "forbidden": ["EAT_COW"]}', "at least one achievement"),
        ('{"required": ["EAT_COW"], "avoid": []}', "unexpected keys avoid"),
    ],
)
def test_anything_but_a_well_formed_goal_is_invalid_with_its_reason(
    answer: str, reason: str
) -> None:
    grounding = parse_grounding(answer, CLASSIC)
    assert grounding.outcome == "invalid" and grounding.reading is None
    assert reason in (grounding.reason or "")
    assert grounding.raw == answer


def test_an_achievement_both_required_and_forbidden_is_read_as_required() -> None:
    # The one reading of the two whose goal can be met; a schema cannot rule the answer out.
    answer = '{"required": ["EAT_COW", "PLACE_TABLE"], "forbidden": ["EAT_COW", "COLLECT_WOOD"]}'
    grounding = parse_grounding(answer, CLASSIC)
    assert grounding.outcome == "valid" and grounding.reason is None
    assert grounding.reading == EasyReading(
        required=("EAT_COW", "PLACE_TABLE"), forbidden=("COLLECT_WOOD",)
    )
    # A record still cannot hold the contradiction: only the reader settles it.
    with pytest.raises(ValueError, match="both required and forbidden"):
        EasyReading(required=("EAT_COW",), forbidden=("EAT_COW",))


@given(st.text(max_size=200))
def test_any_answer_is_read_or_refused_never_raises(answer: str) -> None:
    grounding = parse_grounding(answer, CLASSIC)
    assert (grounding.outcome == "valid") == (grounding.reading is not None)


def test_every_official_goal_survives_its_own_json(dataset_file: Path) -> None:
    for item in load_dataset(dataset_file).goals + GOALS:
        reading = EasyReading(required=item.required, forbidden=item.forbidden)
        assert parse_grounding(reading_json(reading), Variant.FULL).reading == reading


# ----------------------------------------------------------------------------- scores


def scored(truth: tuple[tuple[str, ...], tuple[str, ...]], answer: str) -> Scored:
    return Scored(
        "easy_train", "combo", EasyReading(required=truth[0], forbidden=truth[1]),
        parse_grounding(answer, CLASSIC),
    )  # fmt: skip


def test_scores_count_fields_apart_and_name_the_confusion() -> None:
    truth = (("PLACE_TABLE",), ("COLLECT_SAPLING",))
    items = [
        scored(truth, '{"required": ["PLACE_TABLE"], "forbidden": ["COLLECT_SAPLING"]}'),
        # The negation missed: the forbidden achievement read as required.
        scored(truth, '{"required": ["PLACE_TABLE", "COLLECT_SAPLING"]}'),
        scored(truth, "no idea"),
    ]
    result = score(items)
    assert (result.texts, result.exact.successes, result.invalid) == (3, 1, 1)
    required, forbidden = result.fields["required"], result.fields["forbidden"]
    assert required.precision and (required.precision.successes, required.precision.episodes) == (
        2,
        3,
    )
    assert required.recall and (required.recall.successes, required.recall.episodes) == (2, 3)
    assert forbidden.precision and (
        forbidden.precision.successes,
        forbidden.precision.episodes,
    ) == (1, 1)
    assert forbidden.recall and (forbidden.recall.successes, forbidden.recall.episodes) == (1, 3)
    assert confusions(items) == {("forbidden read as required", "COLLECT_SAPLING"): 1}


def test_a_field_nobody_read_or_holds_has_no_rate() -> None:
    result = score([scored((("EAT_COW",), ()), '{"required": ["EAT_COW"]}')])
    assert (
        result.fields["forbidden"].precision is None and result.fields["forbidden"].recall is None
    )
    assert result.exact.rate == 1.0


def test_the_phrasings_of_a_goal_and_the_atoms_of_a_text_are_not_independent() -> None:
    right = '{"required": ["PLACE_TABLE", "COLLECT_WOOD", "COLLECT_STONE"]}'
    wood = (("COLLECT_WOOD", "COLLECT_STONE", "PLACE_TABLE"), ())
    # Six phrasings of each of two goals: one goal always read right, the other never.
    items = [scored(wood, right) for _ in range(6)]
    items += [scored((("EAT_COW",), ()), '{"required": ["DRINK_WATER"]}') for _ in range(6)]
    result = score(items)
    assert (result.exact.successes, result.exact.episodes, result.exact.clusters) == (6, 12, 2)
    # Twelve texts, but two goals' worth of evidence.
    assert (result.exact.low, result.exact.high) == pytest.approx(wilson_interval(1, 2))
    recall = result.fields["required"].recall
    assert recall is not None and (recall.successes, recall.episodes) == (18, 24)
    assert recall.clusters == 2 and recall.high - recall.low > 0.5
    # Told the goals' ids, the same: one cluster per goal.
    named = [
        Scored(i.split, i.category, i.truth, i.grounding, goal_id=str(n // 6))
        for n, i in enumerate(items)
    ]
    assert score(named).exact == result.exact


# ----------------------------------------------------------------------------- ground runs


def ground_config(out: Path, dataset_file: Path, **overrides: Any) -> GroundConfig:
    settings = {
        "model": "mock:",
        "dataset": str(dataset_file),
        "variant": "classic",
        "output_dir": str(out),
        "requests_per_call": 2,
        "categories": ["one", "combo", "new_objects"],
    }
    return build_settings(GroundConfig, settings | overrides)


def test_ground_scores_every_text_by_split_and_category(tmp_path: Path, dataset_file: Path) -> None:
    cfg = ground_config(tmp_path / "run", dataset_file)

    # Every text answered right except the paraphrases of the table goal, read without "not".
    def answer(conversation: Sequence[ChatMessage]) -> str:
        text = instruction_of(conversation)
        if text.endswith("(again)") and "table" in text:
            return '{"required": ["PLACE_TABLE", "COLLECT_SAPLING"]}'
        return right_answer(text)

    results = execute_grounding(prepare_grounding(cfg), MockModel(outputs=answer))
    assert results.status == "complete" and results.scheduled == results.finished == 6
    summary = results.summary
    assert summary is not None
    assert summary.overall.exact.successes == 5
    assert summary.by_category["combo"].exact.successes == 1
    assert summary.by_category["one"].exact.successes == 2
    assert summary.by_split["easy_test_other_params"].exact.rate == 1.0
    assert [(c.kind, c.subject, c.count) for c in summary.confusions] == [
        ("forbidden read as required", "COLLECT_SAPLING", 1)
    ]
    records = read_groundings(tmp_path / "run")
    assert sorted(r.key for r in records) == sorted(
        f"{g.split}/{g.id}/{v}" for g in GOALS for v in range(2)
    )
    assert read_ground_results(tmp_path / "run" / "results.json").summary == summary


def test_ground_resumes_asking_only_for_unanswered_texts(
    tmp_path: Path, dataset_file: Path
) -> None:
    out = tmp_path / "run"
    first = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    partial = execute_grounding(prepare_grounding(ground_config(out, dataset_file, limit=2)), first)
    assert partial.finished == 2 and len(first.requests) == 2

    # A backend failing half way: what it could not answer stays unanswered.
    failing = MockModel("list:" + right_answer("Drink some water."))
    interrupted = execute_grounding(prepare_grounding(ground_config(out, dataset_file)), failing)
    assert interrupted.status == "partial" and interrupted.failed_calls >= 1

    again = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    done = execute_grounding(prepare_grounding(ground_config(out, dataset_file)), again)
    asked = {instruction_of(conversation) for conversation, _ in again.requests}
    assert done.status == "complete" and done.finished == 6
    # The failing backend's one answer (the drinking goal's JSON, to the table's instruction)
    # was kept, wrong as it is; the texts after it are asked again, each once.
    assert len(again.requests) == 3 and asked == {
        "Make a table but do not collect saplings. (again)",
        "Drink some water.",
        "Drink some water. (again)",
    }
    assert len(read_groundings(out)) == 6
    assert done.summary is not None and done.summary.overall.exact.successes == 5


def test_ground_resumes_a_run_written_before_worked_examples_existed(
    tmp_path: Path, dataset_file: Path
) -> None:
    import json

    out = tmp_path / "run"
    first = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    execute_grounding(prepare_grounding(ground_config(out, dataset_file, limit=2)), first)
    results = json.loads((out / "results.json").read_text())
    del results["identity"]["settings"]["grounding_shots"]
    (out / "results.json").write_text(json.dumps(results))

    again = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    done = execute_grounding(prepare_grounding(ground_config(out, dataset_file)), again)
    assert done.status == "complete" and len(again.requests) == 4
    with pytest.raises(UserError, match=r"grounding_shots \(0 before, 1 now\)"):
        prepare_grounding(ground_config(out, dataset_file, grounding_shots=1))


def edit_results(out: Path, edit: Any) -> None:
    import json

    results = json.loads((out / "results.json").read_text())
    edit(results)
    (out / "results.json").write_text(json.dumps(results))


def test_ground_resumes_only_under_the_same_examples_and_parsed_goals(
    tmp_path: Path, dataset_file: Path
) -> None:
    out = tmp_path / "run"
    first = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    cfg = ground_config(out, dataset_file, grounding_shots=1, limit=2)
    execute_grounding(prepare_grounding(cfg), first)
    identity = read_ground_results(out / "results.json").identity
    assert identity.examples is not None and len(identity.examples) == 64
    assert set(identity.goals) == {"easy_train", "easy_test_other_params"}
    recorded = identity.examples

    def another_list(results: dict[str, Any]) -> None:
        results["identity"]["examples"] = "0" * 64

    edit_results(out, another_list)
    with pytest.raises(
        UserError, match=rf"worked-example list \(000000000000 before, {recorded[:12]} now\)"
    ):
        prepare_grounding(cfg)

    def unrecorded(results: dict[str, Any]) -> None:
        # As a run written before the list was digested left it, though it showed examples.
        del results["identity"]["examples"], results["identity"]["goals"]

    edit_results(out, unrecorded)
    with pytest.raises(UserError, match=r"worked-example list \(not recorded before"):
        prepare_grounding(cfg)
    edit_results(out, lambda results: results["identity"].update(examples=recorded))
    # Goals digested only beside the identity, as older runs recorded them, count as well.
    prepare_grounding(cfg)
    edit_results(out, lambda r: r["dataset"]["split_sha256"].update(easy_train="1" * 64))
    with pytest.raises(UserError, match=r"parsed goals of easy_train \(their digests changed\)"):
        prepare_grounding(cfg)
    edit_results(out, lambda r: r["dataset"].pop("split_sha256"))
    prepare_grounding(cfg)

    def other_goals(results: dict[str, Any]) -> None:
        results["identity"]["goals"] = identity.goals | {"easy_test_other_params": "2" * 64}

    edit_results(out, other_goals)
    with pytest.raises(UserError, match=r"parsed goals of easy_test_other_params"):
        prepare_grounding(cfg)


def test_ground_resumes_under_other_code_and_its_report_says_so(
    tmp_path: Path,
    dataset_file: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    from llm_agents.judging.grounding_report import report_grounding
    from llm_agents.run_data import provenance

    out = tmp_path / "run"
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    monkeypatch.setattr(provenance, "_running_code_version", lambda: "v1")
    execute_grounding(prepare_grounding(ground_config(out, dataset_file, limit=2)), model)
    assert "different code" not in report_grounding(out)
    monkeypatch.setattr(provenance, "_running_code_version", lambda: "v2")
    done = execute_grounding(prepare_grounding(ground_config(out, dataset_file)), model)
    assert done.status == "complete" and done.versions["code"] == "v2"
    assert "recorded by code v1; resuming it with v2" in caplog.text
    assert sorted(r.code or "" for r in read_groundings(out)) == ["v1"] * 2 + ["v2"] * 4
    assert "answers of this run came from different code: v2 (4), v1 (2)" in report_grounding(out)


def test_ground_stops_after_failed_answers_in_a_row_keeping_the_answered(
    tmp_path: Path, dataset_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from llm_agents.evaluation.runner import BackendFailure

    out = tmp_path / "run"
    texts = [t for g in GOALS for t in g.texts]
    # Two answers, then the backend fails for good.
    model = MockModel(outputs=[right_answer(t) for t in texts[:2]], cycle=False)
    cfg = ground_config(out, dataset_file, max_consecutive_failures=2, requests_per_call=1)
    with pytest.raises(BackendFailure, match="stopped after 2 failed model answers in a row"):
        execute_grounding(prepare_grounding(cfg), model)
    assert len(model.requests) == 4  # it stopped asking at the second failure in a row
    results = read_ground_results(out / "results.json")
    assert (results.status, results.finished, results.failed_calls) == ("failed", 2, 2)
    assert results.failure is not None and len(read_groundings(out)) == 2

    args = ["ground", "--model", "mock:error", "--no-probe", "--dataset", str(dataset_file),
            "--variant", "classic", "--output-dir", str(tmp_path / "cli"), "--no-progress",
            "--categories", "one", "combo", "new_objects", "--max-consecutive-failures", "3"]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 3
    assert "stopped after 3 failed model answers in a row" in capsys.readouterr().err


def test_ground_answers_picked_from_the_goals_are_read_by_the_same_parser(
    tmp_path: Path, dataset_file: Path
) -> None:
    cfg = ground_config(tmp_path / "run", dataset_file, choice="loglik")
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    results = execute_grounding(prepare_grounding(cfg), model)
    options = model.requests[0][1]
    assert options is not None and len(options.options) == len(GOALS)
    assert results.summary is not None and results.summary.overall.exact.rate == 1.0


@pytest.mark.parametrize("scoring", ["mean", None])
def test_ground_loglik_records_and_honours_its_scoring_rule(
    tmp_path: Path, dataset_file: Path, scoring: str | None
) -> None:
    given = {"choice_scoring": scoring} if scoring else {}
    cfg = ground_config(tmp_path / "run", dataset_file, choice="loglik", **given)
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    results = execute_grounding(prepare_grounding(cfg), model)
    # Unset, the rule is eval's default: the one declaration both commands share.
    rule = scoring or EvalConfig.model_fields["choice_scoring"].default
    assert {choices.scoring for _, choices in model.requests if choices} == {rule}
    assert len(model.requests) == 6
    assert results.config["choice_scoring"] == rule
    assert results.identity.settings["choice_scoring"] == rule


def test_ground_resumes_only_under_the_same_scoring_rule(
    tmp_path: Path, dataset_file: Path
) -> None:
    out = tmp_path / "run"
    first = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    played = ground_config(out, dataset_file, choice="loglik", choice_scoring="mean", limit=2)
    execute_grounding(prepare_grounding(played), first)
    with pytest.raises(UserError, match=r'choice_scoring \("mean" before, "bytes" now\)'):
        prepare_grounding(ground_config(out, dataset_file, choice="loglik", choice_scoring="bytes"))
    # Free answers never read the rule, so it is no part of their identity.
    free = ground_config(tmp_path / "free", dataset_file, limit=2)
    execute_grounding(prepare_grounding(free), first)
    assert (
        read_ground_results(tmp_path / "free" / "results.json").identity.settings["choice_scoring"]
        is None
    )


@pytest.mark.parametrize("choice", ["loglik", None])
def test_a_grounding_recorded_before_choice_scoring_resumes_under_the_rule_it_played(
    tmp_path: Path, dataset_file: Path, choice: str | None
) -> None:
    out = tmp_path / "run"
    chosen = {"choice": choice, "choice_scoring": "sum"} if choice else {}
    answer = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    execute_grounding(
        prepare_grounding(ground_config(out, dataset_file, limit=2, **chosen)), answer
    )

    def predate(results: dict[str, Any]) -> None:
        del results["identity"]["settings"]["choice_scoring"]
        del results["config"]["choice_scoring"]

    edit_results(out, predate)
    if choice:
        # Before the setting, loglik summed the options' tokens: the default now is another rule.
        with pytest.raises(UserError, match=r'choice_scoring \("sum" before, "pmi" now\)'):
            prepare_grounding(ground_config(out, dataset_file, choice=choice))
    again = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    done = execute_grounding(prepare_grounding(ground_config(out, dataset_file, **chosen)), again)
    assert done.status == "complete" and len(again.requests) == 4


def test_cli_ground_garbage_gives_invalid_rows_and_report_prints_them(
    tmp_path: Path, dataset_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    args = ["ground", "--model", "mock:cycle:lorem ipsum|{oops}", "--dataset", str(dataset_file),
            "--variant", "classic", "--output-dir", str(out), "--no-progress",
            "--categories", "one", "combo", "new_objects"]  # fmt: skip
    assert main(args) == 0
    rows = read_groundings(out)
    assert len(rows) == 6 and all(r.grounding.outcome == "invalid" and not r.correct for r in rows)
    capsys.readouterr()
    assert main(["report", str(out)]) == 0
    report = capsys.readouterr().out
    assert "complete (6 of 6 instruction texts)" in report
    assert "no JSON object in the answer" in report and "JSON does not parse" in report
    assert main(["report", str(out), "--success-rule", "official"]) == EXIT_USER_ERROR


@pytest.mark.parametrize(
    "extra",
    [
        ["--categories", "paraphrased"],  # no goals there
        ["--model", "mock:other"],  # another run is in the directory
        ["--grounding-shots", "17"],  # more than a prompt is given
        ["--choice-scoring", "mean"],  # scores --choice loglik only
    ],
)
def test_cli_ground_bad_input_is_one_line_exit_2_nothing_written(
    tmp_path: Path, dataset_file: Path, capsys: pytest.CaptureFixture[str], extra: list[str]
) -> None:
    out = tmp_path / "run"
    base = ["ground", "--model", "mock:", "--dataset", str(dataset_file), "--variant", "classic",
            "--categories", "one", "combo", "new_objects",
            "--output-dir", str(out), "--no-progress", "--limit", "1"]  # fmt: skip
    assert main(base) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    assert main([*base, *extra]) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("craftext-llm: error:")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


# ----------------------------------------------------------------------------- worked examples


def shown_examples(conversation: Sequence[ChatMessage]) -> list[tuple[str, str]]:
    """(instruction, answer) of the worked examples before a conversation's last request."""
    turns = conversation[1:-1]
    assert [m.role for m in turns] == ["user", "assistant"] * (len(turns) // 2)
    return [
        (instruction_of([asked]), answer.content)
        for asked, answer in zip(turns[::2], turns[1::2], strict=True)
    ]


def test_worked_examples_are_training_goals_answered_never_the_goal_being_read(
    tmp_path: Path, dataset_file: Path
) -> None:
    cfg = ground_config(tmp_path / "run", dataset_file, grounding_shots=2)
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    results = execute_grounding(prepare_grounding(cfg), model)
    shown = {instruction_of(c): shown_examples(c) for c, _ in model.requests}
    assert set(shown) == {text for g in GOALS for text in g.texts}

    wood, table = GOALS[0], GOALS[1]
    # A test text sees both training goals, each answered with its own goal's JSON.
    assert sorted(shown["Drink some water."]) == sorted(
        (g.instruction, right_answer(g.instruction)) for g in (wood, table)
    )
    assert shown["Drink some water. (again)"] == shown["Drink some water."]
    # A training text is never shown its own goal, in any of its wordings.
    for text in wood.texts:
        assert shown[text] == [(table.instruction, right_answer(table.instruction))]
    for text in table.texts:
        assert shown[text] == [(wood.instruction, right_answer(wood.instruction))]
    # The examples replace the prompt's own; without them it is there.
    first = model.requests[0][0]
    assert "Example" not in first[0].content
    assert results.summary is not None and results.summary.overall.exact.rate == 1.0

    plain = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    execute_grounding(prepare_grounding(ground_config(tmp_path / "plain", dataset_file)), plain)
    assert all(len(c) == 2 and "Example" in c[0].content for c, _ in plain.requests)


def test_worked_examples_take_goal_kinds_and_categories_in_turn() -> None:
    from env.goals import BuildLineGoal
    from llm_agents.agents.grounding import grounding_examples

    lines = [
        BuildLineGoal(id=f"LINE_{n}", scenario="medium", split="medium_train",
                      instruction=f"Line {n}.",
                      paraphrases=(), block="STONE", size=n, diagonal=False)
        for n in (2, 3, 4)
    ]  # fmt: skip
    combos = [goal("easy_train", f"C{n}", f"Combo {n}.", ("COLLECT_WOOD", "PLACE_TABLE"))
              for n in range(3)]  # fmt: skip
    ones = [goal("easy_train", f"O{n}", f"One {n}.", ("COLLECT_WOOD",)) for n in range(3)]
    examples = grounding_examples([*lines, *combos, *ones])
    first = {example.instruction.split()[0] for example in examples[:3]}
    assert first == {"Line", "Combo", "One"}
    assert len(examples) == 9 and len({e.instruction for e in examples}) == 9
    # The order is the goals' own, whatever order they come in.
    assert grounding_examples([*ones, *lines[::-1], *combos]) == examples


def test_worked_examples_need_a_training_split(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = DatasetSource(kind="json", path="test goals")
    only_test = Dataset(source=source, goals=GOALS[2:]).save_json(tmp_path / "goals.json")
    out = tmp_path / "run"
    args = ["ground", "--model", "mock:", "--dataset", str(only_test), "--variant", "classic",
            "--categories", "new_objects", "--grounding-shots", "2",
            "--output-dir", str(out), "--no-progress"]  # fmt: skip
    assert main(args) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "no easy_train goals" in error
    assert not out.exists()


# ----------------------------------------------------------------------------- the guided agent

MAX_STEPS = 30


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=CLASSIC, max_steps=MAX_STEPS))


def guided_answer(conversation: Sequence[ChatMessage]) -> str:
    """Wood read right; the table goal read as wood (original) or as garbage (paraphrase);
    the drinking goal never asked for (not in the run's splits)."""
    text = instruction_of(conversation)
    if text.startswith("Collect wood"):
        return right_answer(text)
    if text == "Make a table but do not collect saplings.":
        return '{"required": ["COLLECT_WOOD"]}'
    return "I do not know"


def test_guided_run_grounds_once_per_text_plays_the_reading_and_reports_understanding(
    tmp_path: Path, dataset_file: Path, short_env: CrafTextEnv, capsys: pytest.CaptureFixture[str]
) -> None:
    settings = {
        "agent": "guided", "model": "mock:", "dataset": str(dataset_file), "variant": "classic",
        "categories": ["one", "combo"], "max_steps": MAX_STEPS, "episodes_per_instruction": 2,
        "batch_size": 3, "output_dir": str(tmp_path / "run"),
    }  # fmt: skip
    model = MockModel(outputs=guided_answer)
    outcome = run_eval(build_config(settings), model, env=short_env)

    texts = [instruction_of(conversation) for conversation, _ in model.requests]
    assert len(texts) == len(set(texts)) == 4  # one request per text, however many episodes
    episodes = {e.episode_id: e for e in read_episodes(tmp_path / "run" / "episodes.jsonl")}
    assert len(episodes) == 8
    for repeat in (0, 1):
        wood = episodes[f"one/COLLECT_WOOD/0/{repeat}"]
        assert wood.grounding_correct and wood.success
        table = episodes[f"combo/PLACE_TABLE_NO_SAPLING/0/{repeat}"]
        assert table.grounding_correct is False and table.termination != "not_started"
        assert (
            table.achievements[:1] == ["COLLECT_WOOD"] and "PLACE_TABLE" not in table.achievements
        )
        unread = episodes[f"combo/PLACE_TABLE_NO_SAPLING/1/{repeat}"]
        assert (unread.termination, unread.steps, unread.success) == ("not_started", 0, False)
        assert unread.grounding is not None and unread.grounding.raw == "I do not know"
    steps = (tmp_path / "run" / "steps.jsonl").read_text()
    assert "PLACE_TABLE_NO_SAPLING/1/" not in steps  # an unstarted episode took no step

    results = read_results(tmp_path / "run" / "results.json")
    assert set(results.groundings) == set(episodes)
    assert results.groundings["one/COLLECT_WOOD/0/0"].reading == EasyReading(
        required=("COLLECT_WOOD",)
    )
    summary = outcome.summary
    assert summary is not None and summary.understanding is not None
    read = summary.understanding
    # Counted per text (4 texts, 2 read right), not per episode: each text played in 2 worlds.
    assert (read.grounded.successes, read.grounded.episodes, read.not_started) == (2, 4, 2)
    # Two goals, each with both its texts read right or both wrong: each counts once.
    assert read.grounded.clusters == 2
    assert (read.grounded.low, read.grounded.high) == pytest.approx(wilson_interval(1, 2))
    assert read.success_when_right is not None and read.success_when_right.episodes == 4
    assert read.success_when_wrong is not None and read.success_when_wrong.successes == 0
    assert summary.terminations["not_started"] == 2

    capsys.readouterr()
    assert main(["report", str(tmp_path / "run")]) == 0
    report = capsys.readouterr().out
    assert "not started 2" in report
    assert "goal read exactly right in 0.50" in report and "n=4 g=2 texts" in report
    assert "(could not start: 2 episodes)" in report


def test_guided_is_shown_the_worked_examples_ground_shows(
    tmp_path: Path, dataset_file: Path, short_env: CrafTextEnv
) -> None:
    settings = {
        "agent": "guided", "model": "mock:", "dataset": str(dataset_file), "variant": "classic",
        "categories": ["new_objects"], "max_steps": MAX_STEPS, "grounding_shots": 1,
        "batch_size": 2, "output_dir": str(tmp_path / "run"),
    }  # fmt: skip
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    outcome = run_eval(build_config(settings), model, env=short_env)
    assert outcome.summary is not None and outcome.summary.understanding is not None
    assert outcome.summary.understanding.grounded.successes == 2  # two texts

    grounder = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    cfg = ground_config(tmp_path / "ground", dataset_file, categories=["new_objects"])
    execute_grounding(prepare_grounding(cfg.model_copy(update={"grounding_shots": 1})), grounder)
    guided = {instruction_of(c): c for c, _ in model.requests}
    grounded = {instruction_of(c): c for c, _ in grounder.requests}
    assert guided == grounded and all(len(shown_examples(c)) == 1 for c in guided.values())


def test_guided_asks_once_for_a_text_several_slots_start_at_once(
    tmp_path: Path, dataset_file: Path, short_env: CrafTextEnv
) -> None:
    settings = {
        "agent": "guided", "model": "mock:", "dataset": str(dataset_file), "variant": "classic",
        "categories": ["one"], "paraphrases": False, "max_steps": MAX_STEPS,
        "episodes_per_instruction": 4, "batch_size": 4, "output_dir": str(tmp_path / "run"),
    }  # fmt: skip
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    outcome = run_eval(build_config(settings), model, env=short_env)
    assert len(model.requests) == 1  # four slots began "Collect wood." together
    assert outcome.summary is not None and outcome.summary.understanding is not None
    # Understanding counts the one text once; all four episodes played its reading.
    grounded = outcome.summary.understanding.grounded
    assert (grounded.successes, grounded.episodes) == (1, 1)
    assert outcome.summary.overall.episodes == 4
    assert outcome.results.status == "complete"


def test_guided_examples_and_code_are_the_runs_identity(
    tmp_path: Path,
    dataset_file: Path,
    short_env: CrafTextEnv,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    from llm_agents.judging.report import report_run
    from llm_agents.run_data import provenance

    out = tmp_path / "run"
    settings = {
        "agent": "guided", "model": "mock:", "dataset": str(dataset_file), "variant": "classic",
        "categories": ["one", "combo"], "max_steps": MAX_STEPS, "grounding_shots": 1,
        "batch_size": 2, "output_dir": str(out),
    }  # fmt: skip
    model = MockModel(outputs=lambda c: right_answer(instruction_of(c)))
    monkeypatch.setattr(provenance, "_running_code_version", lambda: "v1")
    run_eval(build_config(settings | {"limit": 1}), model, env=short_env)
    identity = read_results(out / "results.json").identity
    assert identity.examples is not None and set(identity.goals) == {"easy_train"}

    monkeypatch.setattr(provenance, "_running_code_version", lambda: "v2")
    outcome = run_eval(build_config(settings), model, env=short_env)
    assert outcome.results.status == "complete" and outcome.results.versions["code"] == "v2"
    assert "recorded by code v1; resuming it with v2" in caplog.text
    codes = [e.code for e in read_episodes(out / "episodes.jsonl")]
    assert sorted(c or "" for c in codes) == ["v1", "v2", "v2", "v2"]
    assert "episodes of this run came from different code: v2 (3), v1 (1)" in report_run(out)

    edit_results(out, lambda r: r["identity"].update(examples="0" * 64))
    with pytest.raises(UserError, match=r"worked-example list \(000000000000 before"):
        run_eval(build_config(settings), model, env=short_env)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--choice", "loglik"], "free text"),
        (["--model", "hf:"], "names no model"),
        (["--agent", "zero-shot", "--grounding-shots", "2"], "asks for none"),
    ],
)
def test_cli_guided_bad_input_is_one_line_exit_2_nothing_written(
    tmp_path: Path,
    dataset_file: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    out = tmp_path / "run"
    args = ["eval", "--agent", "guided", "--model", "mock:", "--dataset", str(dataset_file),
            "--variant", "classic", "--output-dir", str(out), "--no-progress", *extra]  # fmt: skip
    assert main(args) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert not out.exists()


# ----------------------------------------------------------------------------- the embedded model


@pytest.mark.slow
def test_the_embedded_model_grounds_real_instructions(tmp_path: Path, dataset_file: Path) -> None:
    pytest.importorskip("torch")
    from llm_agents.evaluation.runner import open_model

    cfg = ground_config(
        tmp_path / "run", dataset_file, model="hf:smollm2-135m", generation={"max_tokens": 48}
    )
    with open_model(cfg) as model:
        results = execute_grounding(prepare_grounding(cfg), model)
    rows = read_groundings(tmp_path / "run")
    assert results.status == "complete" and len(rows) == 6
    assert all(r.prompt_tokens > 100 and r.completion_tokens > 0 for r in rows)
    assert results.summary is not None and results.summary.overall.texts == 6
    assert all(r.correct == (r.grounding.reading == r.truth) for r in rows)
