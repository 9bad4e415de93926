"""hf free generation over kept prompt prefixes (`llm_agents/backends/hf/prefix.py`): the answers
of computing every prompt whole, on real prompts of every agent that generates, for less."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

import torch
from test_agents import Seen, text_of

from env.variant import Variant
from llm_agents.agents.grounding import grounding_messages
from llm_agents.agents.strategies.cot import ChainOfThoughtAgent
from llm_agents.agents.strategies.skills import SkillsAgent
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.backends.base import ChatMessage, Conversation, GenerateConfig, ModelOutput
from llm_agents.backends.hf import HFModel
from llm_agents.backends.hf.prefix import PrefixStore
from llm_agents.planning.checks import PlanLimits
from llm_agents.planning.loop import _Prompter
from llm_agents.run_data.records import SkillRecord

SNAPSHOT = Path(__file__).parent / "snapshots" / "prompt_classic_first_step.txt"
#: A real Classic observation, as the textualizer renders it.
OBSERVATION = SNAPSHOT.read_text().split("Current observation:\n")[1].split("\n\n")[0]
INSTRUCTIONS = ["Collect some wood.", "Build a crafting table, then make a wooden pickaxe."]
#: How far apart two tokens' logits may be where rounding alone picks another one.
NEAR_TIE = 1e-4


@pytest.fixture(scope="module")
def model() -> HFModel:
    return HFModel("smollm2-135m", GenerateConfig(max_tokens=8), threads=1)


def with_store(
    model: HFModel, store: PrefixStore, conversations: Sequence[Conversation]
) -> list[ModelOutput]:
    model.prefixes = store
    return model.generate(conversations)


def first_difference(model: HFModel, conversation: Conversation, want: str, got: str) -> float:
    """Where the two answers part: the gap between their two tokens' logits after the prompt
    and the tokens they share, computed whole (no kept prefix)."""
    ids_want, ids_got = model._encode(want), model._encode(got)
    at = next(i for i, (a, b) in enumerate(zip(ids_want, ids_got, strict=False)) if a != b)
    prompt = list(model._prompt_ids([conversation])[0]) + ids_want[:at]
    with torch.inference_mode():
        logits = model.model(input_ids=torch.tensor([prompt])).logits[0, -1]
    return float((logits[ids_want[at]] - logits[ids_got[at]]).abs())


def compare_steps(
    model: HFModel,
    steps: int,
    step_conversations: Callable[[int, list[ModelOutput]], list[Conversation]],
) -> list[list[ModelOutput]]:
    """Plays `steps` batches twice, every prompt computed whole and over kept prefixes (one
    store through all steps, as a run keeps it); each step's conversations are built from
    the previous step's whole-prompt answers. Asserts the answers agree (or part at a near
    tie) and returns the kept-prefix outputs per step."""
    reusing = PrefixStore(32768)
    answers: list[ModelOutput] = []
    kept_steps = []
    for step in range(steps):
        conversations = step_conversations(step, answers)
        answers = with_store(model, PrefixStore(0), conversations)
        kept = with_store(model, reusing, conversations)
        for conversation, whole, reused in zip(conversations, answers, kept, strict=True):
            assert reused.prompt_tokens == whole.prompt_tokens
            assert whole.computed_prompt_tokens == whole.prompt_tokens
            if reused.text != whole.text:
                assert first_difference(model, conversation, whole.text, reused.text) < NEAR_TIE
        kept_steps.append(kept)
    return kept_steps


def assert_reused(outputs: list[ModelOutput], share: float) -> None:
    """Less than `share` of the batch's prompt tokens were computed."""
    computed = sum(o.computed_prompt_tokens or 0 for o in outputs)
    assert 0 < computed < share * sum(o.prompt_tokens for o in outputs)


def played(
    agent: ZeroShotAgent | ChainOfThoughtAgent,
) -> Callable[[int, list[ModelOutput]], list[Conversation]]:
    """Two episodes of `agent`, stepped on the model's answers."""
    for slot, text in enumerate(INSTRUCTIONS):
        agent.start_episode(slot, EpisodeStart(text))
    pending: list = []

    def step(index: int, answers: list[ModelOutput]) -> list[Conversation]:
        for prompt, answer in zip(pending, answers, strict=True):
            agent.decide(prompt, answer)
        seen = Seen(text=OBSERVATION.replace("You face", f"Step {index}: you face"))
        pending[:] = [agent.prepare(slot, seen) for slot in range(len(INSTRUCTIONS))]
        return [prompt.messages for prompt in pending]

    return step


@pytest.mark.slow
@pytest.mark.parametrize(
    "agent_class", [ZeroShotAgent, ChainOfThoughtAgent], ids=["zero-shot", "cot"]
)
def test_step_agents_answer_as_without_reuse(model: HFModel, agent_class: type) -> None:
    agent = agent_class(Variant.CLASSIC, renderer=text_of)
    first, second = compare_steps(model, 2, played(agent))
    # The first step computes the system prompt once for both; the second starts each
    # episode's prompt from its first step's, through its instruction.
    assert (first[0].computed_prompt_tokens or 0) > (first[1].computed_prompt_tokens or 0) > 0
    assert_reused(first, 0.7)
    assert_reused(second, 0.4)


@pytest.mark.slow
def test_skills_decisions_answer_as_without_reuse(model: HFModel) -> None:
    agent = SkillsAgent(Variant.CLASSIC, difficulty="easy")
    for slot, text in enumerate(INSTRUCTIONS):
        agent.start_episode(slot, EpisodeStart(text))

    def step(index: int, answers: list[ModelOutput]) -> list[Conversation]:
        conversations: list[Conversation] = []
        for slot in range(len(INSTRUCTIONS)):
            episode = agent._episode(slot)
            if index:
                episode.history.append(
                    SkillRecord(
                        index=index - 1,
                        step=0,
                        skill="collect wood 1",
                        label="collect wood",
                        outcome="succeeded",
                        steps=4,
                        parse_stage="exact",
                        prompt="",
                        answer=answers[slot].text,
                    )
                )
            conversations.append(agent._messages(episode, OBSERVATION, []))
        return conversations

    _, second = compare_steps(model, 2, step)
    assert_reused(second, 0.4)


@pytest.mark.slow
@pytest.mark.parametrize("request_kind", ["grounding", "plans"])
def test_single_requests_reuse_their_shared_system_prompt(
    model: HFModel, request_kind: str
) -> None:
    prompter = _Prompter(PlanLimits(), Variant.CLASSIC, None)

    def request(text: str) -> list[ChatMessage]:
        if request_kind == "grounding":
            return grounding_messages(text, Variant.CLASSIC)
        return prompter.plan(text)

    batches = [INSTRUCTIONS, ["Drink water.", "Eat a cow."]]
    _, second = compare_steps(model, 2, lambda index, _: [request(t) for t in batches[index]])
    # Another batch of other instructions computes only what follows the system prompt.
    assert_reused(second, 0.4)


@pytest.mark.slow
def test_planner_totals_say_how_much_of_the_prompts_was_computed(
    model: HFModel, tmp_path: Path
) -> None:
    from llm_agents.planning import PlannerConfig, plan_instructions

    model.prefixes = PrefixStore(32768)
    config = PlannerConfig.model_validate(
        {"output": tmp_path / "plans.json", "requests_per_call": 1, "repair": False}
    )
    summary = plan_instructions(INSTRUCTIONS, model, config)
    # The second request reuses the first one's system prompt.
    assert summary.computed_prompt_tokens is not None
    assert 0 < summary.computed_prompt_tokens < 0.8 * summary.prompt_tokens


def test_free_generation_rows_follow_the_device_and_choices_keep_theirs() -> None:
    from llm_agents.backends.hf import model as hf_model

    cpu = HFModel("smollm2-135m", device="cpu")
    assert cpu.rows_per_forward == hf_model.ROWS_PER_FORWARD["cpu"]
    assert cpu.choice_rows_per_forward == hf_model.CHOICE_ROWS_PER_FORWARD
    assert cpu.prefixes.budget_tokens == 32768
    given = HFModel("smollm2-135m", device="cpu", rows_per_forward=3, prefix_cache_tokens=0)
    assert (given.rows_per_forward, given.choice_rows_per_forward) == (3, 3)
    assert given.prefixes.budget_tokens == 0


def test_the_store_keeps_the_longest_match_within_its_budget() -> None:
    def states(length: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(torch.zeros(1, 1, length, 2), torch.ones(1, 1, length, 2))]

    store = PrefixStore(10)
    system = np.arange(4)
    store.keep(system, states(4))
    store.keep(np.arange(6), states(6))
    # A prefix of a kept one adds nothing.
    store.keep(np.arange(3), states(3))
    assert (len(store), store.tokens) == (2, 10)
    length, kept = store.longest(np.array([0, 1, 2, 3, 4, 9, 9]))
    assert length == 5 and kept is not None and len(kept.ids) == 6
    # A prompt keeps its last token to compute, however much is kept.
    assert store.longest(np.arange(6))[0] == 5
    # Over the budget, the least recently used goes: the 6-token one was just used.
    store.keep(np.array([7, 7, 7]), states(3))
    assert store.longest(np.arange(4))[1] is not None
    assert store.tokens <= 10 and len(store) == 2
    assert store.longest(np.array([7, 7, 7, 1]))[0] == 3
    nothing = PrefixStore(0)
    nothing.keep(system, states(4))
    assert len(nothing) == 0 and nothing.longest(system) == (0, None)
