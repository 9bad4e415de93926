"""`--structured-output`: the one JSON-schema spec (`OutputSchema`) every backend takes, the
schemas of a goal reading and of an action, the guided reader and zero-shot under them, the
setting's record and its place in the paper's protocol, and the bad input that refuses it."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace

import jsonschema
import pytest
from fault_server import FaultServer
from test_grounding import GOALS, dataset_file, instruction_of, right_answer, short_env

from env import CrafTextEnv, Variant
from env.dataset import load_dataset
from env.errors import UserError
from env.goals import DIFFICULTY_KINDS
from llm_agents.agents.answer_schemas import (
    READING_MAX,
    action_schema,
    agent_schema,
    answered_action,
    reading_schema,
)
from llm_agents.agents.answers.actions import action_names
from llm_agents.agents.grounding import grounding_messages, parse_grounding, reading_json
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig, OutputSchema
from llm_agents.backends.cache import CachedModel
from llm_agents.backends.mock import MockModel
from llm_agents.backends.openai import OpenAIModel
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import output_schema_of, run_eval
from llm_agents.judging.published import paper_differences
from llm_agents.run_data.readings import reading_of
from llm_agents.run_data.store import read_episodes, read_results

__all__ = ["dataset_file", "short_env"]  # fixtures shared with test_grounding

CLASSIC = Variant.CLASSIC
ASK = [ChatMessage(role="user", content="What is the goal?")]


def validator(schema: OutputSchema) -> jsonschema.Draft202012Validator:
    jsonschema.Draft202012Validator.check_schema(schema.as_data())
    return jsonschema.Draft202012Validator(schema.as_data())


# ----------------------------------------------------------------------------- the schemas


@pytest.mark.parametrize("variant", list(Variant))
def test_every_easy_goal_reads_under_the_schema_and_only_known_names_do(variant: Variant) -> None:
    check = validator(reading_schema(variant, "easy"))
    for goal in GOALS:
        answer = reading_json(reading_of(goal), "easy")
        check.validate(json.loads(answer))
        assert parse_grounding(answer, variant).reading == reading_of(goal)
    for wrong in (
        {"required": ["BUILD_CASTLE"], "forbidden": []},  # no such achievement
        {"required": [], "forbidden": ["EAT_COW"]},  # nothing required
        {"required": ["EAT_COW"]},  # a field left out
        {"required": ["EAT_COW"], "forbidden": [], "kind": "achievements"},  # EASY asks no kind
        {"required": ["EAT_COW"], "forbidden": [], "avoid": []},
        # Longer lists than any goal needs: a looping answer is closed, not cut off.
        {"required": ["EAT_COW"] * (READING_MAX["required"] + 1), "forbidden": []},
        {"required": ["EAT_COW"], "forbidden": ["PLACE_TABLE"] * (READING_MAX["forbidden"] + 1)},
    ):
        assert not check.is_valid(wrong), wrong


def test_every_official_goal_of_every_difficulty_follows_its_schema_and_parses(
    official_repository: Path,
) -> None:
    dataset = load_dataset(official_repository)
    checked = 0
    for difficulty in ("easy", "medium", "hard"):
        variant = CLASSIC if difficulty != "hard" else Variant.FULL
        check = validator(reading_schema(variant, difficulty))
        goals = [g for g in dataset.goals if g.difficulty == difficulty]
        assert goals and {g.kind for g in goals} <= set(DIFFICULTY_KINDS[difficulty])
        for goal in goals:
            answer = reading_json(reading_of(goal), difficulty)
            check.validate(json.loads(answer))
            assert parse_grounding(answer, variant, difficulty).reading == reading_of(goal)
            checked += 1
    assert checked == len(dataset.goals)


def test_a_placing_goal_names_only_the_variants_blocks() -> None:
    check = validator(reading_schema(CLASSIC, "medium"))
    line = {"kind": "build_line", "block": "STONE", "size": 3, "diagonal": False}
    assert check.is_valid(line)
    assert not check.is_valid(line | {"block": "CASTLE"})
    assert not check.is_valid(line | {"size": 0})
    assert not check.is_valid({k: v for k, v in line.items() if k != "diagonal"})


@pytest.mark.parametrize("variant", list(Variant))
def test_the_action_schema_is_the_variants_names_and_reads_back(variant: Variant) -> None:
    names = action_names(variant)
    check = validator(action_schema(variant))
    assert all(check.is_valid({"action": name}) for name in names)
    assert not check.is_valid({"action": "FLY"})
    reasoned = validator(action_schema(variant, reasoning=True))
    answer = {"reasoning": "a tree is left", "action": names[1]}
    assert reasoned.is_valid(answer) and not reasoned.is_valid({"action": names[1]})
    assert list(action_schema(variant, reasoning=True).as_data()["properties"]) == [
        "reasoning",
        "action",
    ]  # reasoning is decoded first
    assert answered_action(json.dumps(answer)) == names[1]
    assert answered_action('{"action": "NO') == '{"action": "NO'  # cut short: parsed as is


def test_agents_without_a_schema_are_refused_in_one_line() -> None:
    assert agent_schema("cot", CLASSIC, "easy") == action_schema(CLASSIC, reasoning=True)
    for agent in ("few-shot", "skills", "expert", "noop", "my.pkg:Agent"):
        with pytest.raises(UserError, match=f"not of the {agent} agent"):
            agent_schema(agent, CLASSIC, "easy")


# ----------------------------------------------------------------------------- mock and cache


def test_the_mock_backend_returns_only_answers_that_follow_the_schema(tmp_path: Path) -> None:
    schema = reading_schema(CLASSIC, "easy")
    good = '{"required": ["COLLECT_WOOD"], "forbidden": []}'
    model = MockModel(outputs=[good, '{"required": ["COLLECT_WOOD"]}', "wood"], cycle=False)
    first, missing, free = model.generate([ASK] * 3, schema=schema)
    assert (first.text, first.finish_reason) == (good, "stop")
    assert missing.finish_reason == "error" and "'forbidden' is a required property" in (
        missing.error or ""
    )
    assert free.finish_reason == "error" and "goal_reading_easy_classic" in (free.error or "")
    with pytest.raises(ValueError, match="options or to a schema"):
        model.generate([ASK], ChoiceSet(options=("NOOP",), rule="guided"), schema)
    # The cache keys the schema: the same conversation under another schema is asked again.
    cached = CachedModel(MockModel(outputs=[good, '{"action": "NOOP"}']), tmp_path / "c.sqlite")
    assert cached.generate([ASK], schema=schema)[0].text == good
    assert cached.generate([ASK], schema=schema)[0].cached
    again = cached.generate([ASK], schema=action_schema(CLASSIC))[0]
    assert not again.cached and again.text == '{"action": "NOOP"}'
    assert not cached.generate([ASK])[0].cached  # and free text is a request of its own


# ----------------------------------------------------------------------------- openai on loopback


@pytest.fixture
def server(monkeypatch: pytest.MonkeyPatch) -> Iterator[FaultServer]:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    started = FaultServer().start()
    yield started
    started.stop()


def openai_model(server: FaultServer) -> OpenAIModel:
    return OpenAIModel(
        "test-model", GenerateConfig(timeout_s=2.0, max_retries=0), base_url=server.url
    )


def test_openai_sends_the_schema_as_response_format(server: FaultServer) -> None:
    schema = reading_schema(CLASSIC, "easy")
    answer = '{"required": ["COLLECT_WOOD"], "forbidden": []}'
    server.answer = lambda body: {"role": "assistant", "content": answer}
    backend = openai_model(server)
    backend.check_schema(schema)
    [output] = backend.generate([ASK], schema=schema)
    assert output.text == answer
    sent = server.requests[-1].body["response_format"]
    assert sent == {
        "type": "json_schema",
        "json_schema": {"name": schema.name, "schema": schema.as_data(), "strict": True},
    }
    assert "response_format" not in backend._body(ASK, None, False)  # free text asks none


def test_a_server_without_response_format_is_refused_before_the_run(server: FaultServer) -> None:
    server.reject_structured_outputs = True
    backend = openai_model(server)
    with pytest.raises(UserError) as refused:
        backend.check_schema(reading_schema(CLASSIC, "easy"))
    message = str(refused.value)
    assert "\n" not in message and "openai backend" in message
    assert "rejects response_format" in message and "--structured-output off" in message
    # Mid-run, a rejected request is that answer's error, never an unconstrained answer.
    [output] = backend.generate([ASK], schema=reading_schema(CLASSIC, "easy"))
    assert output.finish_reason == "error" and "rejected" in (output.error or "")
    assert server.count(ASK[-1].content) == 1  # asked once: no free-text fallback


# ----------------------------------------------------------------------------- hf: a missing library


def test_hf_without_llguidance_is_one_line_naming_the_backend_and_the_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("torch")
    from llm_agents.backends.hf import structured

    monkeypatch.setitem(sys.modules, "llguidance", None)
    with pytest.raises(UserError) as missing:
        structured.Grammars(None, 10, [0])
    message = str(missing.value)
    assert "\n" not in message and "hf backend" in message
    assert "pip install 'craftext-llm[hf]'" in message


# ----------------------------------------------------------------------------- runs


def structured_answer(conversation: Sequence[ChatMessage]) -> str:
    """Right for the wood texts; the table goal read as wood."""
    text = instruction_of(conversation)
    if text.startswith("Collect wood"):
        return right_answer(text)
    return '{"required": ["COLLECT_WOOD"], "forbidden": []}'


def test_a_structured_guided_run_records_each_reading_and_reports_accuracy_beside_success(
    tmp_path: Path,
    dataset_file: Path,
    short_env: CrafTextEnv,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from test_grounding import MAX_STEPS

    settings = {
        "agent": "guided", "model": "mock:", "dataset": str(dataset_file), "variant": "classic",
        "categories": ["one", "combo"], "max_steps": MAX_STEPS, "batch_size": 2,
        "structured_output": True, "output_dir": str(tmp_path / "run"),
    }  # fmt: skip
    config = build_config(settings)
    model = MockModel(outputs=structured_answer)
    run_eval(config, model, env=short_env)

    schema = output_schema_of(config)
    assert schema == reading_schema(CLASSIC, "easy")
    episodes = read_episodes(tmp_path / "run" / "episodes.jsonl")
    assert len(episodes) == 4 and all(e.grounding is not None for e in episodes)
    assert all(e.termination != "not_started" for e in episodes)  # every reading parsed
    right = {e.episode_id: e.grounding_correct for e in episodes}
    assert right == {
        "one/COLLECT_WOOD/0/0": True,
        "one/COLLECT_WOOD/1/0": True,
        "combo/PLACE_TABLE_NO_SAPLING/0/0": False,
        "combo/PLACE_TABLE_NO_SAPLING/1/0": False,
    }
    results = read_results(tmp_path / "run" / "results.json")
    assert results.config["structured_output"] is True
    assert results.identity.settings["structured_output"] is True
    read = results.summary.understanding if results.summary else None
    assert read is not None
    assert (read.by_category["one"].successes, read.by_category["one"].episodes) == (2, 2)
    assert (read.by_category["combo"].successes, read.by_category["combo"].episodes) == (0, 2)
    assert read.by_scenario["Achievements"].episodes == 4
    assert read.scenario_success["Achievements"].episodes == 4

    capsys.readouterr()
    assert main(["report", str(tmp_path / "run")]) == 0
    report = capsys.readouterr().out
    assert "Reading accuracy (texts read exactly right) beside success:" in report
    table = report.split("beside success:")[1]
    assert "Achievements" in table and "1.00" in table and "0.00" in table


def test_zero_shot_under_the_action_schema_plays_the_named_action(tmp_path: Path) -> None:
    from llm_agents.agents.loading import build_agent

    config = build_config(
        {"agent": "zero-shot", "model": "mock:", "variant": "classic", "structured_output": True}
    )
    agent = build_agent(config)
    assert agent.output_schema == action_schema(CLASSIC)  # type: ignore[attr-defined]
    cot = build_agent(config.model_copy(update={"agent": "cot"}))
    assert cot.output_schema == action_schema(CLASSIC, reasoning=True)  # type: ignore[attr-defined]
    plain = build_agent(build_config({"agent": "zero-shot", "model": "mock:"}))
    assert plain.output_schema is None  # type: ignore[attr-defined]


def test_the_paper_protocol_records_structured_output_as_a_departure(tmp_path: Path) -> None:
    config = build_config(
        {"agent": "guided", "model": "mock:", "protocol": "paper"}, {"structured_output": True}
    )
    assert config.structured_output and "structured_output" in config.protocol_overrides
    plain = build_config({"agent": "guided", "model": "mock:", "protocol": "paper"})
    assert not plain.structured_output and "structured_output" not in plain.protocol_overrides


def test_ground_reads_every_text_under_the_schema(tmp_path: Path, dataset_file: Path) -> None:
    from test_grounding import ground_config

    from llm_agents.evaluation.grounding_run import (
        execute_grounding,
        prepare_grounding,
        read_groundings,
    )

    cfg = ground_config(tmp_path / "run", dataset_file, structured_output=True)
    assert output_schema_of(cfg) == reading_schema(CLASSIC, "easy")
    model = MockModel(outputs=structured_answer)
    results = execute_grounding(prepare_grounding(cfg), model)
    assert results.status == "complete"
    assert {schema for _, schema in model.schemas} == {reading_schema(CLASSIC, "easy")}
    rows = read_groundings(tmp_path / "run")
    assert len(rows) == 6 and all(row.grounding.outcome == "valid" for row in rows)
    assert results.identity.settings["structured_output"] is True


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--agent", "few-shot", "--demos", "x"], "not of the few-shot agent"),
        (["--agent", "guided", "--choice", "guided"], "a run asks under one of them"),
        (["--agent", "guided", "--model", "mock:error"], "does not answer"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2_nothing_written(
    tmp_path: Path,
    dataset_file: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    out = tmp_path / "run"
    args = ["eval", "--model", "mock:", "--dataset", str(dataset_file), "--variant", "classic",
            "--structured-output", "--output-dir", str(out), "--no-progress", *extra]  # fmt: skip
    assert main(args) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert not out.exists()


def test_a_paper_run_under_a_schema_lists_the_departure() -> None:
    recorded = SimpleNamespace(
        config={"variant": "classic", "max_steps": 1500, "structured_output": True},
        dataset={"split_sha256": {}},
    )
    lines = paper_differences(recorded, "official")  # type: ignore[arg-type]
    assert any(line.startswith("structured output:") for line in lines)
    recorded.config["structured_output"] = False
    lines = paper_differences(recorded, "official")  # type: ignore[arg-type]
    assert not any(line.startswith("structured output:") for line in lines)


# ----------------------------------------------------------------------------- hf, for real


@pytest.mark.slow
def test_the_embedded_model_under_the_reading_schema_always_reads_a_goal() -> None:
    """SmolLM2-135M cannot read these goals, and in free text it rarely answers JSON at all;
    held to the schema, every answer it gives is a goal."""
    pytest.importorskip("llguidance")
    from llm_agents.backends import get_model

    texts = ("Collect wood.", "Make a table but do not collect saplings.")
    requests = [grounding_messages(text, CLASSIC) for text in texts]
    model = get_model("hf:smollm2-135m", GenerateConfig(max_tokens=64))
    model.check_schema(reading_schema(CLASSIC, "easy"))
    outputs = model.generate(requests, schema=reading_schema(CLASSIC, "easy"))
    for output in outputs:
        assert output.finish_reason == "stop", output
        grounding = parse_grounding(output.text, CLASSIC)
        assert grounding.outcome == "valid" and grounding.stage == "json", output.text
        assert output.text == json.dumps(json.loads(output.text))  # no stray whitespace
    [action] = model.generate(
        [[ChatMessage(role="user", content="Which action now?")]], schema=action_schema(CLASSIC)
    )
    assert action.finish_reason == "stop" and answered_action(action.text) in action_names(CLASSIC)
    with pytest.raises(UserError, match="hf backend cannot take the bad JSON schema"):
        model.check_schema(OutputSchema.of("bad", {"type": "array", "uniqueItems": True}))


def test_cli_a_server_rejecting_response_format_stops_the_run_before_anything_is_written(
    tmp_path: Path,
    dataset_file: Path,
    server: FaultServer,
    capsys: pytest.CaptureFixture[str],
) -> None:
    server.reject_structured_outputs = True
    out = tmp_path / "run"
    args = ["eval", "--agent", "guided", "--model", f"openai:test-model@{server.url}",
            "--dataset", str(dataset_file), "--variant", "classic", "--structured-output",
            "--output-dir", str(out), "--no-progress"]  # fmt: skip
    assert main(args) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "rejects response_format" in error
    assert not out.exists()
