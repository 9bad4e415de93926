"""Protocol presets: the default one is today's settings, the paper one the official evaluation's;
a preset fills in what the user did not set, and a run records its protocol and overrides."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from env import EnvConfig, Variant, shared_env
from env.errors import UserError
from llm_agents.backends import get_model
from llm_agents.backends.base import GenerateConfig
from llm_agents.evaluation.config import EvalConfig, build_config
from llm_agents.evaluation.protocol import PROTOCOLS, apply_protocol, get_protocol, protocol_for
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.store import read_episodes, read_results


def _value(config: EvalConfig, setting: str) -> object:
    head, _, leaf = setting.rpartition(".")
    owner = getattr(config, head) if head else config
    value = getattr(owner, leaf)
    return value.value if isinstance(value, Variant) else value


def test_the_default_protocol_is_the_configs_defaults() -> None:
    config = EvalConfig()
    for choice in PROTOCOLS["default"].choices:
        assert _value(config, choice.setting) == choice.value, choice.setting
    assert build_config({}) == config


def test_the_paper_protocol_sets_the_official_evaluation() -> None:
    config = build_config({"protocol": "paper"})
    assert (config.variant, config.max_steps, config.episodes_per_instruction) == (
        Variant.CLASSIC,
        250,
        1,
    )
    assert (config.success_rule, config.world_seeding) == ("official", "official")
    assert (config.generation.temperature, config.generation.max_tokens) == (0.7, 10)
    assert config.history_length == 4
    assert config.protocol_overrides == ()
    for choice in PROTOCOLS["paper"].choices:
        assert _value(config, choice.setting) == choice.value, choice.setting
        assert choice.source


def test_the_medium_paper_protocol_plays_classic_over_50_worlds_per_instruction() -> None:
    config = build_config({"protocol": "paper", "difficulty": "medium"})
    assert (config.variant, config.max_steps, config.success_rule) == (
        Variant.CLASSIC,
        250,
        "official",
    )
    assert config.categories == ("train", "paraphrased", "new_objects")
    # 50 worlds per instruction need 50 worlds: the one official world would repeat one sample.
    assert (config.episodes_per_instruction, config.world_seeding) == (50, "per_episode")
    assert config.generation.temperature == 0.7 and config.protocol_overrides == ()
    for choice in protocol_for("paper", "medium").choices:
        assert _value(config, choice.setting) == choice.value, choice.setting


def test_hard_plays_full_craftax_and_its_only_split_by_default() -> None:
    paper = build_config({"protocol": "paper", "difficulty": "hard"})
    assert (paper.variant, paper.categories) == (Variant.FULL, ("train",))
    # The official data has no Hard test splits, so no protocol asks for them.
    assert build_config({"difficulty": "hard"}).categories == ("train",)
    assert build_config({"difficulty": "medium"}).categories == (
        "train",
        "paraphrased",
        "new_objects",
    )


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"difficulty": "medum"}, "unknown difficulty 'medum'; known: easy, medium, hard"),
        (
            {"difficulty": "medium", "categories": "one"},
            "category 'one' is not one of medium's; choose from train, paraphrased, new_objects",
        ),
        ({"categories": "train"}, "category 'train' is not one of easy's"),
    ],
)
def test_a_difficulty_without_those_goal_sets_is_a_user_error(
    settings: dict[str, object], message: str
) -> None:
    with pytest.raises(UserError, match=message):
        build_config(settings)


def test_explicit_settings_win_and_are_recorded_as_overrides() -> None:
    config = build_config(
        {"protocol": "paper", "history_length": 4, "categories": "one,combo,new_objects"},
        {"max_steps": 100, "variant": "classic", "generation": {"temperature": 0.0}},
    )
    assert config.max_steps == 100 and config.generation.temperature == 0.0
    # Settings given with the protocol's own value are not overrides.
    assert config.protocol_overrides == ("max_steps", "generation.temperature")
    assert config.generation.max_tokens == 10 and config.success_rule == "official"


def test_a_preset_only_fills_in() -> None:
    settings = {"protocol": "paper", "generation": {"seed": 3}, "limit": 2}
    applied, overrides = apply_protocol(settings, {"generation.seed", "limit"})
    assert applied["generation"] == {"seed": 3, "temperature": 0.7, "max_tokens": 10}
    assert applied["limit"] == 2 and overrides == []
    assert settings == {"protocol": "paper", "generation": {"seed": 3}, "limit": 2}


def test_every_choice_names_a_real_setting() -> None:
    fields = set(EvalConfig.model_fields)
    generation = set(GenerateConfig.model_fields)
    every = [
        protocol_for(name, level)
        for name in PROTOCOLS
        for level in (("easy",) if name == "balrog" else ("easy", "medium", "hard"))
    ]
    for protocol in every:
        for choice in protocol.choices:
            head, _, leaf = choice.setting.rpartition(".")
            assert leaf in (generation if head == "generation" else fields), choice.setting
    assert [c.setting for c in PROTOCOLS["default"].choices] == [
        c.setting for c in PROTOCOLS["paper"].choices
    ]


def test_an_unknown_protocol_is_a_user_error() -> None:
    with pytest.raises(UserError, match="unknown protocol 'papers'; known: default, paper, balrog"):
        get_protocol("papers")
    with pytest.raises(UserError, match="unknown protocol"):
        build_config({"protocol": "papers"})


@pytest.mark.slow
def test_a_paper_run_plays_the_official_world_and_records_its_protocol(tmp_path: Path) -> None:
    config = build_config(
        {
            "protocol": "paper",
            "model": "mock:hash:ACTION: LEFT|ACTION: DO|ACTION: UP",
            "categories": ["combo", "new_objects"],
            "max_steps": 6,
            "batch_size": 2,
            "limit": 4,
            "output_dir": str(tmp_path),
        }
    )
    env = shared_env(
        EnvConfig(variant=Variant.CLASSIC, max_steps=6, success_rule="official", world_key=1)
    )
    with get_model(config.model, config.generation) as model:
        run_eval(config, model, env=env)
    saved = read_results(tmp_path / "results.json").config
    assert saved["protocol"] == "paper"
    assert saved["protocol_overrides"] == ["categories", "max_steps"]
    assert (saved["success_rule"], saved["world_seeding"]) == ("official", "official")
    assert len(read_episodes(tmp_path / "episodes.jsonl")) == 4
    steps = [json.loads(line) for line in (tmp_path / "steps.jsonl").read_text().splitlines()]
    first_views = {s["observation"] for s in steps if s["step"] == 0}
    # Four instructions, one world: every episode starts from the same observation.
    assert len(first_views) == 1
    mismatched = config.model_copy(
        update={"world_seeding": "per_episode", "output_dir": str(tmp_path / "other")}
    )
    with (
        pytest.raises(ValueError, match="does not match"),
        get_model(config.model, config.generation) as model,
    ):
        run_eval(mismatched, model, env=env)


def test_the_balrog_protocol_sets_balrogs_crafter_evaluation() -> None:
    config = build_config({"protocol": "balrog"})
    assert (config.task, config.variant, config.max_steps) == ("open_ended", Variant.CLASSIC, 2000)
    assert (config.episodes_per_instruction, config.world_seeding) == (10, "per_episode")
    assert (config.generation.temperature, config.history_length) == (1.0, 16)
    assert (config.fallback_action, config.report_invalid_answers) == ("NOOP", True)
    assert config.protocol_overrides == ()
    # The other protocols leave both new settings as runs had them before.
    assert (EvalConfig().task, EvalConfig().report_invalid_answers) == ("craftext", False)
    with pytest.raises(UserError, match="open-ended Crafter task, no CrafText difficulty"):
        build_config({"protocol": "balrog", "difficulty": "medium"})


@pytest.mark.slow
def test_a_balrog_run_plays_the_open_ended_goal_until_the_game_or_the_cap_ends(
    tmp_path: Path,
) -> None:
    from env.open_ended import OPEN_ENDED_ID, OPEN_ENDED_TEXT

    config = build_config(
        {
            "protocol": "balrog",
            "model": "mock:hash:ACTION: LEFT|no idea|ACTION: DO|ACTION: UP",
            "max_steps": 12,
            "episodes_per_instruction": 3,
            "batch_size": 3,
            "output_dir": str(tmp_path),
        }
    )
    env = shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=12))
    with get_model(config.model, config.generation) as model:
        run_eval(config, model, env=env)
    results = read_results(tmp_path / "results.json")
    assert (results.config["task"], results.status) == ("open_ended", "complete")
    episodes = read_episodes(tmp_path / "episodes.jsonl")
    assert len(episodes) == 3
    for episode in episodes:
        assert (episode.goal_id, episode.instruction) == (OPEN_ENDED_ID, OPEN_ENDED_TEXT)
        # Never "met": the episode runs to the cap (or the player's death).
        assert not episode.success and episode.termination in ("timeout", "death")
    assert any(e.steps == 12 for e in episodes)
    assert results.scores is not None and results.scores.overall.episodes == 3
    assert results.scores.overall.achievement_list == "classic"
    steps = [json.loads(line) for line in (tmp_path / "steps.jsonl").read_text().splitlines()]
    invalid = [s for s in steps if s["fallback_used"]]
    assert invalid and all(s["action_name"] == "NOOP" for s in invalid)
