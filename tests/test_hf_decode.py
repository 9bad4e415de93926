"""hf free generation's own decoding (`llm_agents/backends/hf/decode.py`): the answers
transformers' `generate` gives, on real agent prompts, with finished rows leaving the batch."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

import torch
from test_agents import Seen, text_of
from test_prefix_reuse import NEAR_TIE, OBSERVATION, first_difference

from env.variant import Variant
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.backends.base import ChatMessage, Conversation, GenerateConfig
from llm_agents.backends.hf import HFModel
from llm_agents.backends.hf.prefix import PrefixStore

TEXTS = [
    "Collect some wood.",
    "Build a crafting table, then make a wooden pickaxe.",
    "Find water and drink it.",
    "Defeat a zombie with a sword.",
    "Place a stone next to the table.",
]


@pytest.fixture(scope="module")
def model() -> HFModel:
    return HFModel("smollm2-135m", GenerateConfig(max_tokens=24), threads=1)


@pytest.fixture
def fresh(model: HFModel) -> Iterator[HFModel]:
    """The module's model with an empty prefix store and its rows settings, restored after."""
    saved = (model.prefixes, model.rows_per_forward, model.prefill_rows, model.config)
    model.prefixes = PrefixStore(32768)
    yield model
    model.prefixes, model.rows_per_forward, model.prefill_rows, model.config = saved


def step_prompts() -> list[Conversation]:
    """First-step zero-shot prompts of episodes whose texts differ in length."""
    agent = ZeroShotAgent(Variant.CLASSIC, renderer=text_of)
    conversations = []
    for slot, text in enumerate(TEXTS):
        agent.start_episode(slot, EpisodeStart(text))
        conversations.append(agent.prepare(slot, Seen(text=OBSERVATION)).messages)
    return conversations


def transformers_answers(model: HFModel, conversations: list[Conversation]) -> list[str]:
    """Each conversation answered alone by transformers' `generate` (greedy, no kept prefix)."""
    answers = []
    for prompt in model._prompt_ids(conversations):
        ids = torch.from_numpy(prompt)[None]
        with torch.inference_mode():
            out = model.model.generate(
                input_ids=ids,
                attention_mask=torch.ones_like(ids),
                do_sample=False,
                max_new_tokens=model.config.max_tokens,
                pad_token_id=model.tokenizer.pad_token_id,
            )
        tokens = out[0, len(prompt) :].tolist()
        ends = model._eos_ids()
        cut = next((i for i, token in enumerate(tokens) if token in ends), len(tokens))
        answers.append(model.tokenizer.decode(tokens[:cut], skip_special_tokens=True))
    return answers


def assert_same_answers(
    model: HFModel, conversations: list[Conversation], want: list[str], got: list[str]
) -> None:
    for conversation, expected, answer in zip(conversations, want, got, strict=True):
        if answer != expected:
            assert first_difference(model, conversation, expected, answer) < NEAR_TIE


@pytest.mark.slow
@pytest.mark.parametrize("prefill_rows", [1, 2, 5], ids=["row-by-row", "pairs", "all"])
def test_greedy_answers_are_transformers_generate_s(fresh: HFModel, prefill_rows: int) -> None:
    conversations = step_prompts()
    want = transformers_answers(fresh, conversations)
    fresh.rows_per_forward, fresh.prefill_rows = 5, prefill_rows
    got = [output.text for output in fresh.generate(conversations)]
    assert_same_answers(fresh, conversations, want, got)
    # The prompts differ, so a batch of them really is padded and merged.
    assert len({len(p) for p in fresh._prompt_ids(conversations)}) > 2


#: Questions SmolLM2 answers in a few tokens, beside step prompts it answers at length.
SHORT_ANSWERS = ["What is 2+2? Answer with a number only.", "Name one color."]


@pytest.mark.slow
def test_a_finished_row_leaves_the_batch(fresh: HFModel) -> None:
    conversations = [
        *step_prompts()[:3],
        *([ChatMessage(role="user", content=question)] for question in SHORT_ANSWERS),
    ]
    fresh.rows_per_forward, fresh.prefill_rows = 5, 1
    rows_per_pass: list[int] = []

    def count(_module: Any, args: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
        rows_per_pass.append(int(kwargs["input_ids"].shape[0]))

    hook = fresh.model.register_forward_pre_hook(count, with_kwargs=True)
    try:
        outputs = fresh.generate(conversations)
    finally:
        hook.remove()
    lengths = sorted(output.completion_tokens for output in outputs)
    # One pass per prompt, then one per answer token after the first (the prompt's pass gives
    # the first), each over the rows that had not ended before it.
    prompts, decoding = rows_per_pass[:5], rows_per_pass[5:]
    assert prompts == [1] * 5
    assert len(decoding) == lengths[-1] - 1
    for index, rows in enumerate(decoding, start=1):
        assert rows == sum(length > index for length in lengths)
    assert lengths[0] < lengths[-1]  # the test means something only if rows ended apart


@pytest.mark.slow
def test_the_models_own_generation_settings_apply_as_in_generate(fresh: HFModel) -> None:
    conversations = step_prompts()[:2]
    config = fresh.model.generation_config
    saved = config.repetition_penalty
    config.repetition_penalty = 1.8
    try:
        want = transformers_answers(fresh, conversations)
        got = [output.text for output in fresh.generate(conversations)]
    finally:
        config.repetition_penalty = saved
    plain = [output.text for output in fresh.generate(conversations)]
    assert_same_answers(fresh, conversations, want, got)
    assert got != plain  # the penalty changed something, so it was applied


@pytest.mark.slow
def test_sampled_answers_repeat_under_a_seed_and_stop_strings_cut_them(fresh: HFModel) -> None:
    conversations = step_prompts()
    fresh.config = GenerateConfig(max_tokens=24, temperature=0.9, sampling_seed=7)
    first = [output.text for output in fresh.generate(conversations)]
    fresh.prefixes = PrefixStore(32768)
    again = [output.text for output in fresh.generate(conversations)]
    assert first == again
    fresh.config = GenerateConfig(max_tokens=24, temperature=0.9, sampling_seed=8)
    assert [output.text for output in fresh.generate(conversations)] != first

    fresh.config = GenerateConfig(max_tokens=24)
    whole = fresh.generate(conversations)
    fresh.config = GenerateConfig(max_tokens=24, stop=[" "])
    cut = fresh.generate(conversations)
    for before, after in zip(whole, cut, strict=True):
        assert after.text == before.text.split(" ")[0]
    # Decoding stopped at the stop string, not at the end of the answer.
    assert sum(o.completion_tokens for o in cut) < sum(o.completion_tokens for o in whole)
