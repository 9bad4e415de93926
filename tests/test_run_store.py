"""The run directory's files: durable appends, torn-line recovery, atomic rewrites, identity."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from env.errors import UserError
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.store import (
    RunIdentity,
    append_records,
    atomic_write_text,
    check_output_dir,
    complete_lines,
    keep_steps_of,
    read_episodes,
    read_steps,
)


def episode(index: int, success: bool = False) -> EpisodeRecord:
    return EpisodeRecord(
        episode_id=f"ep{index}",
        goal_id="g",
        instruction="place a table",
        instruction_variant=0,
        category="one",
        seed=0,
        episode_index=index,
        success=success,
        steps=5,
        termination="success" if success else "timeout",
        episode_return=0.0,
    )


def test_a_torn_last_line_is_dropped_and_cut_off_so_appends_stay_whole(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "episodes.jsonl"
    append_records(path, [episode(0), episode(1)])
    with path.open("a") as handle:
        handle.write(episode(2).model_dump_json()[:30])

    with caplog.at_level(logging.WARNING):
        assert [e.episode_id for e in read_episodes(path, repair=True)] == ["ep0", "ep1"]
    assert any("torn last line" in message for message in caplog.messages)
    append_records(path, [episode(3)])
    assert [e.episode_id for e in read_episodes(path)] == ["ep0", "ep1", "ep3"]


def test_reading_without_repair_leaves_the_file_as_it_is(tmp_path: Path) -> None:
    path = tmp_path / "episodes.jsonl"
    append_records(path, [episode(0)])
    with path.open("a") as handle:
        handle.write('{"episode_id": "ep')
    before = path.read_bytes()
    assert len(read_episodes(path)) == 1
    assert path.read_bytes() == before


def test_a_corrupt_whole_line_is_an_error_naming_the_line(tmp_path: Path) -> None:
    path = tmp_path / "episodes.jsonl"
    append_records(path, [episode(0)])
    with path.open("a") as handle:
        handle.write("not json\n")
    append_records(path, [episode(1)])
    with pytest.raises(UserError, match=r"episodes\.jsonl, line 2"):
        read_episodes(path)


def test_a_redone_episode_counts_once_with_its_last_outcome(tmp_path: Path) -> None:
    path = tmp_path / "episodes.jsonl"
    append_records(path, [episode(0), episode(1)])
    append_records(path, [episode(1, success=True)])
    episodes = read_episodes(path)
    assert [(e.episode_id, e.success) for e in episodes] == [("ep0", False), ("ep1", True)]


def step(episode_id: str, index: int) -> StepRecord:
    return StepRecord(
        episode_id=episode_id,
        step=index,
        observation=f"{episode_id} view {index}",
        prompt_hash="",
        raw_output="DO",
        action_name="DO",
        action_id=5,
        parse_stage="exact",
        fallback_used=False,
        reward=0.0,
        done=False,
    )


def test_steps_are_read_in_file_order_for_the_episodes_asked(tmp_path: Path) -> None:
    path = tmp_path / "steps.jsonl"
    append_records(path, [step("a", 0), step("b", 0), step("a", 1), step("c", 0)])
    assert [(s.episode_id, s.step) for s in read_steps(path)] == [
        ("a", 0),
        ("b", 0),
        ("a", 1),
        ("c", 0),
    ]
    chosen = read_steps(path, {"a", "c"})
    assert [(s.episode_id, s.observation) for s in chosen] == [
        ("a", "a view 0"),
        ("a", "a view 1"),
        ("c", "c view 0"),
    ]


def test_reading_steps_skips_a_torn_last_line_and_leaves_the_file_as_it_is(
    tmp_path: Path,
) -> None:
    path = tmp_path / "steps.jsonl"
    append_records(path, [step("a", 0)])
    with path.open("a") as handle:
        handle.write(step("a", 1).model_dump_json()[:40])
    before = path.read_bytes()
    assert [s.step for s in read_steps(path)] == [0]
    assert path.read_bytes() == before


@pytest.mark.parametrize("line", ["not json", '{"episode_id": "a", "step": 1}', "[1, 2]"])
def test_a_whole_line_that_is_no_step_record_is_an_error_naming_it(
    tmp_path: Path, line: str
) -> None:
    path = tmp_path / "steps.jsonl"
    append_records(path, [step("a", 0)])
    with path.open("a") as handle:
        handle.write(line + "\n")
    with pytest.raises(UserError, match=r"steps\.jsonl, line 2: not a step record"):
        list(read_steps(path))


def test_keeping_the_steps_of_finished_episodes_drops_the_others_and_a_torn_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "steps.jsonl"
    append_records(path, [step("a", 0), step("b", 0), step("a", 1), step("c", 0), step("b", 1)])
    with path.open("a") as handle:
        handle.write(step("a", 2).model_dump_json()[:40])
    # Read a line at a time: a long run's log does not fit in memory whole.
    monkeypatch.setattr(Path, "read_bytes", lambda self: pytest.fail("read whole"))
    monkeypatch.setattr(Path, "read_text", lambda self, **_: pytest.fail("read whole"))
    assert keep_steps_of(path, {"a", "c"}) == 3
    assert [(s.episode_id, s.step) for s in read_steps(path)] == [("a", 0), ("a", 1), ("c", 0)]
    assert os.listdir(tmp_path) == ["steps.jsonl"]


def test_a_step_log_with_nothing_to_drop_is_left_as_it_is(tmp_path: Path) -> None:
    path = tmp_path / "steps.jsonl"
    append_records(path, [step("a", 0), step("b", 0)])
    before = path.stat()
    assert keep_steps_of(path, {"a", "b", "c"}) == 0
    assert keep_steps_of(tmp_path / "none.jsonl", {"a"}) == 0
    after = path.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)


@pytest.mark.parametrize("contents", [b"", b"\n\n", b"   \n"])
def test_blank_files_hold_no_lines(tmp_path: Path, contents: bytes) -> None:
    path = tmp_path / "x.jsonl"
    path.write_bytes(contents)
    assert complete_lines(path) == []


def test_an_atomic_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    path.write_text("old")

    with pytest.raises(TypeError):
        atomic_write_text(path, 5)  # type: ignore[arg-type]
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["results.json"]


def test_identity_differences_name_each_change() -> None:
    before = RunIdentity(
        settings={"max_steps": 10, "variant": "full"},
        templates={"step.j2": "a", "system.j2": "b"},
        plans="p1",
        dataset="d",
    )
    now = RunIdentity(
        settings={"max_steps": 5, "variant": "full"},
        templates={"step.j2": "changed", "system.j2": "b"},
        plans="p2",
        dataset="d",
    )
    assert now.differences(before) == [
        "max_steps (10 before, 5 now)",
        "template step.j2 (its content changed)",
        "plans file content",
    ]
    assert before.differences(before) == []


def test_identity_names_both_hub_commits_of_a_moved_model() -> None:
    first, moved = "a" * 40, "b" * 40
    before = RunIdentity(settings={}, templates={}, model_revision=first)
    now = RunIdentity(settings={}, templates={}, model_revision=moved)
    assert now.differences(before) == [f"model revision (commit {first} before, {moved} now)"]
    # A run recorded before commits were (a hub id then came from the cache alone).
    unrecorded = RunIdentity(settings={}, templates={})
    assert now.differences(unrecorded) == [
        f"model revision (commit none recorded before, {moved} now)"
    ]
    assert unrecorded.differences(unrecorded) == []


def test_identity_compares_only_the_templates_the_run_renders() -> None:
    # Runs once hashed every packaged template; a template the agent does not render is none
    # of its business, one it renders that the older run did not hash is a change.
    older = RunIdentity(settings={}, templates={"step.j2": "a", "few_shot.j2": "b"})
    assert RunIdentity(settings={}, templates={"step.j2": "a"}).differences(older) == []
    assert RunIdentity(settings={}, templates={"ground.j2": "g"}).differences(older) == [
        "template ground.j2 (its content changed)"
    ]


def test_output_dir_checks(tmp_path: Path) -> None:
    file = tmp_path / "file"
    file.write_text("x")
    with pytest.raises(UserError, match="is a file"):
        check_output_dir(file)
    with pytest.raises(UserError, match=r"lies under .*file, which is a file"):
        check_output_dir(file / "run" / "deeper")
    check_output_dir(tmp_path / "new" / "run")
    assert not (tmp_path / "new").exists()


# ------------------------------------------------------------------ what a run's identity holds

#: A valid value other than the default for every setting: a new setting must be added here,
#: and so be marked (or not) as changing results.
OTHER_VALUES: dict[str, object] = {
    "model": "mock:noop",
    "generation": {"temperature": 0.5},
    "backend_options": {"dtype": "float16"},
    "cache": "answers.sqlite",
    "limit": 3,
    "templates_dir": ".",
    "dataset": "data.json",
    "variant": "classic",
    "probe": False,
    "choice": "guided",
    "choice_scoring": "bytes",
    "structured_output": True,
    "categories": ("combo",),
    "difficulty": "hard",
    "paraphrases": False,
    "episodes_per_instruction": 2,
    "max_steps": 9,
    "seed": 1,
    "batch_size": 2,
    "renderer": "grid",
    "history_length": 2,
    "report_invalid_answers": True,
    "task": "open_ended",
    "plans": "plans.json",
    "output_dir": "elsewhere",
    "fallback_action": "DO",
    "record_steps": False,
    "max_consecutive_failures": 2,
    "protocol": "paper",
    "protocol_overrides": ("max_steps",),
    "success_rule": "official",
    "world_seeding": "official",
    "step_keys": "whole",
    "env_device": "default",
    "ray": True,
    "ray_workers": 3,
    "ray_worker_gpus": 1.0,
    "agent": "cot",
    "cot_steps": 2,
    "cot_max_tokens": 100,
    "few_shot_steps": 2,
    "demos": "expert-run",
    "skill_steps": 20,
    "stuck_after": 0,
    "skill_demos": 2,
    "grounding_shots": 4,
    "observation": "both",
    "frame_history": 1,
}
OTHER_GENERATION: dict[str, object] = {
    "max_tokens": 9,
    "temperature": 0.5,
    "top_p": 0.5,
    "sampling_seed": 1,
    "stop": ["\n"],
    "reasoning_budget": 9,
    "timeout_s": 5.0,
    "max_concurrency": 2,
    "max_retries": 1,
}


def test_every_setting_has_another_value_to_try() -> None:
    from llm_agents.backends.base import GenerateConfig
    from llm_agents.evaluation.config import EvalConfig

    assert set(OTHER_VALUES) == set(EvalConfig.model_fields)
    assert set(OTHER_GENERATION) == set(GenerateConfig.model_fields)


def test_a_run_recorded_before_step_keys_replays_in_the_env_it_played_in() -> None:
    from llm_agents.evaluation.config import EvalConfig

    # Such runs stepped the game with the whole step key: replayed (view, card) or resumed, they
    # must get that env, while a new run steps as Craftax's auto-reset env.
    recorded = EvalConfig().model_dump(mode="json")
    del recorded["step_keys"]
    assert EvalConfig.recorded(recorded).env_config().step_keys == "whole"
    assert EvalConfig.recorded(recorded | {"step_keys": "auto_reset"}).env_config().step_keys == (
        "auto_reset"
    )
    assert EvalConfig().env_config().step_keys == "auto_reset"


@pytest.mark.parametrize("name", sorted(OTHER_VALUES))
def test_a_runs_identity_changes_iff_a_setting_marked_as_changing_results_changes(
    name: str,
) -> None:
    from llm_agents.backends.base import result_fields
    from llm_agents.evaluation.config import EvalConfig

    # Categories belong to a difficulty: a split both difficulties have keeps them valid; only
    # the guided agent is shown grounding examples.
    if name == "difficulty":
        base = EvalConfig(difficulty="medium", categories=("train",))
    elif name == "grounding_shots":
        base = EvalConfig(agent="guided")
    elif name == "frame_history":
        # Past frames are counted for an image observation only.
        base = EvalConfig(observation="image")
    elif name == "choice_scoring":
        # It scores loglik choices only, and is refused with any other.
        base = EvalConfig(choice="loglik")
    elif name in ("stuck_after", "skill_demos"):
        # Only the skills agent stops asking, and is shown skill sequences.
        base = EvalConfig(agent="skills")
    else:
        base = EvalConfig()
    changed = EvalConfig.model_validate(base.model_dump() | {name: OTHER_VALUES[name]})
    assert getattr(changed, name) != getattr(base, name)
    moved = changed.result_settings() != base.result_settings()
    assert moved == (name in result_fields(EvalConfig))


@pytest.mark.parametrize("name", sorted(OTHER_GENERATION))
def test_only_generation_settings_that_shape_answers_are_in_a_runs_identity(name: str) -> None:
    from llm_agents.backends.base import TRANSPORT_FIELDS
    from llm_agents.evaluation.config import EvalConfig

    base = EvalConfig()
    changed = EvalConfig.model_validate(
        base.model_dump() | {"generation": {name: OTHER_GENERATION[name]}}
    )
    moved = changed.result_settings() != base.result_settings()
    assert moved == (name not in TRANSPORT_FIELDS)
    assert {"timeout_s", "max_concurrency", "max_retries"} == TRANSPORT_FIELDS


def test_backend_options_about_speed_are_left_out_of_a_runs_identity() -> None:
    from llm_agents.evaluation.config import EvalConfig
    from llm_agents.evaluation.grounding_run import GroundConfig

    for config in (EvalConfig, GroundConfig):
        base = config(backend_options={"dtype": "float32"})
        other = config(backend_options={"dtype": "float16"})
        assert other.result_settings() != base.result_settings()
        for speed in (
            {"threads": 4},
            {"api_key_env": "OTHER_KEY"},
            {"health_interval_s": 1.0},
            {"backoff_initial_s": 5.0, "jitter_s": 0.0},
        ):
            faster = config(backend_options={"dtype": "float32", **speed})
            assert faster.result_settings() == base.result_settings(), speed


def test_a_setting_added_after_a_run_was_written_counts_at_its_default() -> None:
    from llm_agents.evaluation.config import EvalConfig

    added = EvalConfig.model_construct().result_settings()
    now = RunIdentity(settings=EvalConfig(agent="guided").result_settings(), templates={})
    newer = {"grounding_shots", "difficulty"}
    older = RunIdentity(
        settings={k: v for k, v in now.settings.items() if k not in newer}, templates={}
    )
    assert now.differences(older, added=added) == []
    # Without the defaults, the older run reads as having had none of them.
    assert len(now.differences(older)) == 2
    shown = EvalConfig(agent="guided", grounding_shots=2).result_settings()
    assert RunIdentity(settings=shown, templates={}).differences(older, added=added) == [
        "grounding_shots (0 before, 2 now)"
    ]
