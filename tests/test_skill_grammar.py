"""Answers held to the skills catalogue (`--choice guided` for the skills agent): the catalogue's
grammar, the agent's requests under it, and constrained decoding by a real model (SmolLM2 in the
hf backend: every answer a catalogue skill, each token the model's own likeliest among those the
grammar allows, never one chosen for it)."""

from __future__ import annotations

from typing import Any

import pytest
import torch
from test_skills import observation

from env import Variant
from env.goals import DIFFICULTIES
from llm_agents.agents.expert.navigation import ExpertEpisode
from llm_agents.agents.skills.catalogue import read_skill, skill_offer
from llm_agents.agents.skills.runner import valid_now
from llm_agents.agents.strategies.skills import SkillsAgent
from llm_agents.agents.types import EpisodeStart, StepPrompt
from llm_agents.backends.base import ChoiceSet, GenerateConfig, ModelOutput

CLASSIC, FULL = Variant.CLASSIC, Variant.FULL


@pytest.mark.parametrize("variant", [CLASSIC, FULL])
@pytest.mark.parametrize("difficulty", DIFFICULTIES)
def test_the_grammar_is_every_skill_of_the_catalogue_once(
    variant: Variant, difficulty: str
) -> None:
    offer = skill_offer(variant, difficulty)
    grammar = offer.grammar()
    assert len(set(grammar)) == len(grammar)
    assert all(read_skill(text, offer).text == text for text in grammar)
    episode = ExpertEpisode((), ())
    rich = observation({"wood": 9, "stone": 9, "coal": 2, "iron": 2, "sapling": 1})
    episode.world.update(rich)
    assert set(valid_now(offer, episode, rich)) <= set(grammar)
    assert ("place stone left 2 of water" in grammar) == (difficulty != "easy")


def guided_prompt(agent: SkillsAgent, instruction: str = "Place a crafting table.") -> StepPrompt:
    agent.start_episode(0, EpisodeStart(instruction))
    return agent.prepare(0, observation({"wood": 3}))


def test_every_request_carries_the_catalogue_grammar_and_lists_no_options() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", choice_rule="guided")
    prompt = guided_prompt(agent)
    assert prompt.choices == ChoiceSet(
        options=skill_offer(CLASSIC, "easy").grammar(), rule="guided"
    )
    # Not the skills valid now: a skill that cannot start is the model's to name, and fails.
    assert "craft stone_pickaxe" in prompt.choices.options
    request = prompt.messages[-1].content
    assert "written as in the list of skills" in request and "SKILL:" not in request
    assert "Skills you can start now" not in request
    decision = agent.decide(prompt, ModelOutput(text="craft stone_pickaxe", finish_reason="choice"))
    assert decision.skills[-1].outcome == "failed" and decision.skills[-1].prerequisite


def test_an_answer_cut_short_is_invalid_and_no_skill_is_chosen_for_the_model() -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", choice_rule="guided")
    prompt = guided_prompt(agent)
    decision = agent.decide(prompt, ModelOutput(text="craft wood_", finish_reason="length"))
    assert decision.fallback_used and decision.name == "NOOP"
    assert decision.skills[-1].outcome == "invalid" and decision.skills[-1].skill is None


# ------------------------------------------------------------------------------- a real model


@pytest.fixture(scope="module")
def smollm() -> Any:
    from llm_agents.backends.hf import HFModel

    return HFModel("smollm2-135m", GenerateConfig(max_tokens=24), threads=1)


INSTRUCTIONS = (
    "Place a crafting table.",
    "Make a stone pickaxe, but do not place a furnace.",
    "Eat a cow and drink some water.",
    "Place a stone two blocks to the left of the water.",
)


@pytest.mark.parametrize("difficulty", ["easy", "medium"])
def test_constrained_decoding_always_yields_a_catalogue_skill(smollm: Any, difficulty: str) -> None:
    from llm_agents.backends.hf.guided import OptionTrie

    agent = SkillsAgent(CLASSIC, difficulty=difficulty, choice_rule="guided")  # type: ignore[arg-type]
    prompts = [guided_prompt(agent, text) for text in INSTRUCTIONS]
    grammar = prompts[0].choices
    assert grammar is not None
    outputs = smollm.generate([p.messages for p in prompts], grammar)
    offer = skill_offer(CLASSIC, difficulty)
    for output in outputs:
        assert output.text in grammar.options and output.finish_reason == "choice"
        assert read_skill(output.text, offer).text == output.text
    # Each token is the model's own likeliest among those the grammar allows at that point.
    trie = OptionTrie(smollm._candidate_ids(grammar.options))
    ends = smollm._eos_ids()
    for prompt, output in zip(prompts, outputs, strict=True):
        answer = smollm._encode(output.text)
        ids = [*smollm._prompt_ids([prompt.messages])[0].tolist(), *answer]
        with torch.inference_mode():
            logits = smollm.model(torch.tensor([ids])).logits[0]
        start = len(ids) - len(answer) - 1
        for position in range(len(answer) + 1):
            node = trie.node(answer[:position])
            assert node is not None
            allowed = [token for token in node if token >= 0]
            allowed += sorted(ends) if -1 in node else []
            row = logits[start + position]
            chosen = answer[position] if position < len(answer) else None
            best = max(allowed, key=lambda token: float(row[token]))
            assert chosen == best or (chosen is None and best in ends)
    # Unconstrained, the same model's answers are mostly no skill at all.
    free = smollm.generate([p.messages for p in prompts])
    assert any(output.text not in grammar.options for output in free)


def test_a_budget_too_short_for_any_skill_cuts_the_answer(smollm: Any) -> None:
    agent = SkillsAgent(CLASSIC, difficulty="easy", choice_rule="guided")
    prompt = guided_prompt(agent, "Make a wood pickaxe.")
    assert prompt.choices is not None
    saved, smollm.config = smollm.config, GenerateConfig(max_tokens=1)
    try:
        [output] = smollm.generate([prompt.messages], prompt.choices)
    finally:
        smollm.config = saved
    if output.text in prompt.choices.options:  # a skill of one token
        assert len(smollm._encode(output.text)) == 1
        return
    assert output.finish_reason == "length" and len(smollm._encode(output.text)) == 1
    decision = agent.decide(prompt, output)
    assert decision.skills[-1].outcome == "invalid" and decision.fallback_used
