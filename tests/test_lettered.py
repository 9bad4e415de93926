"""`--choice-scoring letters`: the actions lettered in an order drawn per (seed, episode, step),
the backend picking a label, the label mapped back to its action, and the order recorded."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from env import CrafTextEnv, EnvConfig, Variant, shared_env
from env.errors import UserError
from llm_agents.agents.answers.actions import action_names
from llm_agents.agents.answers.lettered import LABELS, LetteredOptions, label_choices, lettered
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.agents.types import EpisodeStart, StepPrompt
from llm_agents.backends.base import ChatMessage, ModelOutput
from llm_agents.backends.embedded import NAMED_MODELS, cache_root, named_model_dir
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.config import build_config, build_settings
from llm_agents.evaluation.grounding_run import GroundConfig
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.store import read_steps

FULL = action_names(Variant.FULL)
CLASSIC = action_names(Variant.CLASSIC)


def test_every_action_of_full_craftax_gets_a_label_of_its_own() -> None:
    assert len(FULL) == 43 <= len(LABELS) == len(set(LABELS)) == 52
    assert label_choices(len(FULL)).options == tuple(LABELS[:43])
    with pytest.raises(UserError, match="at most 52"):
        lettered([str(i) for i in range(53)], 0, "e", 0)


def test_the_order_is_fixed_by_seed_episode_and_step_and_differs_across_them() -> None:
    order = lettered(FULL, 0, "one/3/0/0", 7).order
    assert sorted(order) == sorted(FULL)
    assert lettered(FULL, 0, "one/3/0/0", 7).order == order
    others = [
        lettered(FULL, 1, "one/3/0/0", 7),
        lettered(FULL, 0, "one/3/0/1", 7),
        lettered(FULL, 0, "one/3/0/0", 8),
    ]
    assert all(other.order != order for other in others)
    # Label bias is spread: over an episode's steps, many actions are listed first.
    firsts = {lettered(FULL, 0, "one/3/0/0", step).order[0] for step in range(60)}
    assert len(firsts) > 20


def test_a_label_stands_for_the_option_listed_under_it_and_nothing_else_does() -> None:
    shown = LetteredOptions(order=("DO", "NOOP", "LEFT"))
    assert shown.labels == "ABC"
    assert [shown.option_of(label) for label in ("A", " B\n", "C")] == ["DO", "NOOP", "LEFT"]
    assert [shown.option_of(answer) for answer in ("D", "a", "AB", "DO", "")] == [None] * 5
    assert shown.lines()[2] == {"label": "C", "option": "LEFT"}


@pytest.mark.parametrize("name", list(NAMED_MODELS))
def test_each_label_is_one_token_for_the_named_models(name: str) -> None:
    transformers = pytest.importorskip("transformers")
    folder = cache_root() / "models" / NAMED_MODELS[name].converted_dirname
    if not folder.is_dir():
        # CI fails a skip: there the model is fetched and converted once (about 2 minutes for
        # the 1.5B), as `hf:NAME` would; a developer's run skips rather than download gigabytes.
        if not os.environ.get("CI"):
            pytest.skip(f"{name} is not converted in the user cache")
        folder = named_model_dir(name)
    tokenizer = transformers.AutoTokenizer.from_pretrained(str(folder), local_files_only=True)
    lengths = {label: len(tokenizer(label, add_special_tokens=False).input_ids) for label in LABELS}
    assert set(lengths.values()) == {1}, lengths


def label_of(action: str, messages: Sequence[ChatMessage]) -> str:
    """The label the step message lists `action` under."""
    for line in messages[-1].content.splitlines():
        label, _, option = line.partition(". ")
        if option == action and label in LABELS:
            return label
    raise AssertionError(f"{action} is not lettered in the step message")


def test_the_agent_plays_the_action_its_label_stands_for() -> None:
    agent = ZeroShotAgent("classic", choice_rule="loglik", choice_scoring="letters", seed=5)
    assert agent.choices == label_choices(len(CLASSIC))
    agent.start_episode(0, EpisodeStart("Collect wood.", episode="one/1/0/0"))
    messages = agent.messages_for(0, "(observation)")
    shown = agent._episode(0).shown
    assert shown == lettered(CLASSIC, 5, "one/1/0/0", 0)
    listed = [line for line in messages[-1].content.splitlines() if line[1:3] == ". "]
    assert listed == [f"{entry['label']}. {entry['option']}" for entry in shown.lines()]
    assert "letter" in messages[-1].content

    def step(answer: str) -> Any:
        prompt = StepPrompt(
            slot=0, observation=None, messages=messages, text="", options_shown=shown.order
        )
        return agent.decide(prompt, ModelOutput(text=answer, finish_reason="choice"))

    wanted = label_of("DO", messages)
    decision = step(wanted)
    assert (decision.name, decision.action, decision.fallback_used) == (
        "DO",
        CLASSIC.index("DO"),
        False,
    )
    assert decision.options_shown == shown.order and decision.output.text == wanted
    # A name is no label: the fallback is played.
    assert step("DO").fallback_used


def test_few_shot_letters_its_step_after_the_demonstrations(tmp_path: Path) -> None:
    from agent_steps import play_step
    from test_agents import Seen, goal, make_expert_run, text_of

    from llm_agents.agents.strategies.few_shot import FewShotAgent

    agent = FewShotAgent(
        Variant.CLASSIC,
        demos=make_expert_run(tmp_path / "expert"),
        steps=3,
        choice_rule="loglik",
        choice_scoring="letters",
        seed=2,
    )
    agent.render_observation = text_of
    agent.start_episode(
        0,
        EpisodeStart(
            "Collect wood.", goal=goal("COLLECT_WOOD", ("COLLECT_WOOD",)), episode="one/W/0/0"
        ),
    )
    model = MockModel(outputs=lambda conversation: label_of("PLACE_TABLE", conversation))
    for step in range(2):
        [decision] = play_step(agent, model, [0], [Seen(text="A tree is 1 east.")])
        assert decision.name == "PLACE_TABLE"
        assert decision.options_shown == lettered(CLASSIC, 2, "one/W/0/0", step).order
    user = model.requests[0][0][-1].content
    assert user.index("Expert action:") < user.index("A. ") < user.index("letter of the one")


@pytest.fixture(scope="module")
def short_env() -> CrafTextEnv:
    return shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=4))


def letters_config(out: Path, **overrides: Any) -> Any:
    settings = {
        "model": "mock:",
        "variant": "classic",
        "categories": ["combo"],
        "max_steps": 4,
        "batch_size": 2,
        "limit": 2,
        "output_dir": str(out),
        "choice": "loglik",
        "choice_scoring": "letters",
    }
    return build_config(settings | overrides)


def test_a_run_plays_the_chosen_labels_and_records_each_step_s_order(
    tmp_path: Path, short_env: CrafTextEnv
) -> None:
    def pick_do(conversation: Sequence[ChatMessage]) -> str:
        return label_of("DO", conversation)

    config = letters_config(tmp_path)
    run_eval(config, MockModel(outputs=pick_do), env=short_env)
    steps = list(read_steps(tmp_path / "steps.jsonl"))
    assert len(steps) == 8
    for record in steps:
        assert record.action_name == "DO" and not record.fallback_used
        assert record.options_shown is not None
        assert record.options_shown[LABELS.index(record.raw_output)] == "DO"
        assert record.options_shown == list(
            lettered(CLASSIC, config.seed, record.episode_id, record.step).order
        )
    assert len({tuple(record.options_shown or ()) for record in steps}) == len(steps)
    with pytest.raises(UserError, match=r'choice_scoring \("letters" before, "pmi" now\)'):
        run_eval(letters_config(tmp_path, choice_scoring="pmi"), MockModel(), env=short_env)


@pytest.mark.parametrize("agent", ["cot", "skills"])
def test_letters_is_refused_for_an_agent_that_letters_nothing(tmp_path: Path, agent: str) -> None:
    with pytest.raises(UserError, match="letters works with: zero-shot, few-shot"):
        letters_config(tmp_path, agent=agent)


def test_letters_is_refused_for_grounding(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="never lettered"):
        build_settings(
            GroundConfig,
            {"output_dir": str(tmp_path), "choice": "loglik", "choice_scoring": "letters"},
        )
