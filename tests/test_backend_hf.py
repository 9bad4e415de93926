"""The transformers backend on the real embedded model (SmolLM2-135M-Instruct, CPU)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

import torch

from env.errors import UserError
from llm_agents.backends import embedded, get_model
from llm_agents.backends.base import (
    ChatMessage,
    ChoiceSet,
    GenerateConfig,
    content_free_conversation,
    local_model_path,
)
from llm_agents.backends.hf import HFModel, scoring
from llm_agents.backends.hf import model as hf_model
from llm_agents.backends.hf.scoring import (
    CandidateTrie,
    _attend,
    _SharedPrefixAttention,
    _split_attention_forward,
)
from llm_agents.backends.hf.thinking import ThinkingBudgetLogitsProcessor

FRANCE = [
    ChatMessage(role="system", content="Answer with one word."),
    ChatMessage(role="user", content="What is the capital of France?"),
]
PERU = [FRANCE[0], ChatMessage(role="user", content="And what is the capital of Peru, please?")]
GREETINGS = [
    [ChatMessage(role="user", content="Say hello.")],
    [
        ChatMessage(
            role="user", content="Name a colour, then name three animals that live in a forest."
        )
    ],
    FRANCE,
]


SNAPSHOTS = Path(__file__).parent / "snapshots"


def snapshot_conversation(name: str) -> list[ChatMessage]:
    """A real agent conversation, from the prompt snapshots the agent tests keep."""
    messages: list[ChatMessage] = []
    for part in (SNAPSHOTS / name).read_text(encoding="utf-8").split("=== ")[1:]:
        role, _, content = part.partition(" ===\n")
        messages.append(ChatMessage.model_validate({"role": role, "content": content[:-1]}))
    return messages


#: Real prompts: zero-shot (classic and full, choice and free), cot with earlier replies,
#: few-shot with demonstrations, plan-conditioned.
REAL = [snapshot_conversation(path.name) for path in sorted(SNAPSHOTS.glob("prompt_*.txt"))]


def summed(options: list[str]) -> ChoiceSet:
    """`options` scored by the summed rule: their tokens' log-likelihood, what a plain forward
    pass gives."""
    return ChoiceSet(options=tuple(options), rule="loglik", scoring="sum")


@pytest.fixture(scope="module")
def model() -> HFModel:
    return HFModel("smollm2-135m", GenerateConfig(max_tokens=12), threads=1)


def naive_log_likelihood(
    model: HFModel,
    prompt: str,
    candidate: str,
    attention: str | None = None,
    *,
    ended: bool = False,
) -> float:
    """Score a candidate with one full forward pass over prompt + candidate (and, `ended`, the
    end-of-turn token after it), no cache, in the model's own dtype and (unless `attention`
    names another) attention implementation."""
    prompt_ids = model.tokenizer(prompt, add_special_tokens=False).input_ids
    candidate_ids = model.tokenizer(candidate, add_special_tokens=False).input_ids
    if ended:
        candidate_ids.append(model.tokenizer.convert_tokens_to_ids("<|im_end|>"))
    ids = torch.tensor([prompt_ids + candidate_ids], device=model.device)
    config = model.model.config
    default = config._attn_implementation
    config._attn_implementation = attention or default
    try:
        with torch.inference_mode():
            log_probs = model.model(input_ids=ids).logits[0].float().log_softmax(-1)
    finally:
        config._attn_implementation = default
    positions = range(len(prompt_ids) - 1, len(prompt_ids) + len(candidate_ids) - 1)
    return sum(float(log_probs[p, t]) for p, t in zip(positions, candidate_ids, strict=True))


#: How far float16 choice scores may lie from the same model's plain float16 forward pass.
HALF_TOLERANCE = 0.1


def plain_forward_differences(
    model: HFModel, conversations: list[list[ChatMessage]], choices: list[str]
) -> tuple[float, float]:
    """Largest difference between `model.choice_scores` and the plain forward pass, and the
    largest difference between two plain forward passes that differ only in their attention
    kernel (sdpa vs eager): how far the dtype's rounding alone moves a score."""
    scores = model.choice_scores(conversations, summed(choices))
    worst = spread = 0.0
    for conversation, row in zip(conversations, scores, strict=True):
        prompt = model._render(conversation)
        for choice, score in zip(choices, row, strict=True):
            plain = naive_log_likelihood(model, prompt, choice)
            other = naive_log_likelihood(model, prompt, choice, attention="eager")
            worst = max(worst, abs(score - plain))
            spread = max(spread, abs(other - plain))
    return worst, spread


@pytest.mark.slow
def test_chat_generation_returns_text(model: HFModel) -> None:
    [output] = model.generate([FRANCE])
    assert output.text.strip()
    assert output.finish_reason in ("stop", "length")
    assert output.error is None
    assert output.prompt_tokens > 10
    assert 0 < output.completion_tokens <= 12 + 1
    assert output.latency_s > 0


@pytest.mark.slow
def test_choice_mode_prefers_the_right_answer(model: HFModel) -> None:
    choices = ChoiceSet(options=("banana", "Paris"), rule="loglik")
    outputs = model.generate([FRANCE, FRANCE], choices=choices)
    assert [o.text for o in outputs] == ["Paris", "Paris"]
    assert all(o.finish_reason == "choice" for o in outputs)


def test_guided_choices_decode_one_option_of_the_models_own(model: HFModel) -> None:
    # Options sharing their first tokens: the trie lets the model stop or go on after "Paris".
    guided = ChoiceSet(options=("banana", "Paris", "Paris, France", "Lyon"), rule="guided")
    outputs = model.generate([FRANCE, GREETINGS[0]], choices=guided)
    assert all(o.text in guided.options and o.finish_reason == "choice" for o in outputs)
    assert outputs[0].text.startswith("Paris")


def test_guided_choices_are_refused_for_an_image_text_model(tmp_path: Path) -> None:
    from tiny_vlm import build_tiny_vlm

    from llm_agents.backends.embedded import embedded_model_dir

    vlm = HFModel(str(build_tiny_vlm(tmp_path, embedded_model_dir())), threads=1)
    with pytest.raises(UserError, match="cannot constrain"):
        vlm.check_choice_rule("guided")


@pytest.mark.slow
@pytest.mark.parametrize(
    "conversations",
    [
        # Prompts of different lengths: left padding of the prompt pass.
        [FRANCE, GREETINGS[0], GREETINGS[1]],
        # A long common prefix (the system message), encoded once for the batch.
        [FRANCE, PERU],
    ],
    ids=["padded", "shared-prefix"],
)
def test_choice_scores_equal_a_naive_forward_pass(
    model: HFModel, conversations: list[list[ChatMessage]]
) -> None:
    # Candidates sharing prefixes (and one a prefix of others) exercise the candidate trie.
    choices = [" Paris", "MAKE_WOOD_PICKAXE", "MAKE_STONE_PICKAXE", "MAKE", "DO", "banana split"]
    scores = model.choice_scores(conversations, summed(choices))
    for conversation, row in zip(conversations, scores, strict=True):
        prompt = model._render(conversation)
        expected = [naive_log_likelihood(model, prompt, choice) for choice in choices]
        assert row == pytest.approx(expected, abs=2e-3)
    # The scores really differ between candidates, so equality above is not trivial.
    assert max(scores[0]) - min(scores[0]) > 1.0


@pytest.mark.slow
def test_every_scoring_rule_is_its_formula_over_plain_forward_passes(model: HFModel) -> None:
    # "DO" is a token prefix of "DOWN" and "MAKE" of the pickaxe: under every rule but the
    # summed one the end of turn after the option is scored, so a prefix pays for stopping.
    options = ["DO", "DOWN", "MAKE", "MAKE_WOOD_PICKAXE", " Paris"]
    conversations = [FRANCE, PERU]
    rows = {
        rule: model.choice_scores(
            conversations, ChoiceSet(options=tuple(options), rule="loglik", scoring=rule)
        )
        for rule in ("sum", "mean", "bytes", "pmi")
    }
    for index, conversation in enumerate(conversations):
        prompt = model._render(conversation)
        free = model._render(content_free_conversation(conversation))
        for column, option in enumerate(options):
            tokens = len(model._encode(option))
            whole = naive_log_likelihood(model, prompt, option, ended=True)
            prior = naive_log_likelihood(model, free, option, ended=True)
            expected = {
                "sum": naive_log_likelihood(model, prompt, option),
                "mean": whole / (tokens + 1),
                "bytes": whole / len(option.encode()),
                "pmi": whole - prior,
            }
            got = {rule: rows[rule][index][column] for rule in rows}
            assert got == pytest.approx(expected, abs=2e-3), option
    # The content-free prompt is scored once for the two conversations (one system message).
    assert len(model._content_free._kept) == 1


@pytest.mark.parametrize("split_attention", [False, True], ids=["cache-copy", "split"])
def test_letters_are_read_off_one_pass_over_the_prompt_as_the_general_path_scores_them(
    model: HFModel, split_attention: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    from llm_agents.agents.answers.lettered import label_choices, lettered

    # A short lettered question (the agent's own step message is tested on the mock): every
    # pass below runs over the whole prompt, and the agent's prompt is a thousand tokens.
    listed = "\n".join(
        f"{line['label']}. {line['option']}"
        for line in lettered(["NOOP", "LEFT", "DO", "SLEEP"], 0, "one/1/0/0", 0).lines()
    )
    question = f"A tree is to your left.\n{listed}\nAnswer with the letter of one action."
    conversations = [[ChatMessage(role="user", content=question)], PERU]
    # Four of the step's 17 labels: the general path's cost grows with each.
    choices = label_choices(17).model_copy(update={"options": tuple("ABCD")})
    candidates = model._candidate_ids(choices.options)
    assert {len(ids) for ids in candidates} == {1}
    model.scorer.split_attention = split_attention
    passes = {"candidates": 0, "decoder": 0}

    def counted(name: str, function: Any) -> Any:
        def run(*args: Any, **kwargs: Any) -> Any:
            passes[name] += 1
            return function(*args, **kwargs)

        return run

    try:
        # The general path: each label and its end of turn through the candidate pass.
        general = model._option_logliks(model._prompt_ids(conversations), candidates)
        monkeypatch.setattr(
            scoring, "_candidate_pass", counted("candidates", scoring._candidate_pass)
        )
        monkeypatch.setattr(scoring, "_hidden_states", counted("decoder", scoring._hidden_states))
        letters = model.choice_scores(conversations, choices)
    finally:
        model.scorer.split_attention = True
    assert passes["candidates"] == 0
    # The split path: the prompts' own tokens once (their shared prefix is kept from above).
    assert passes["decoder"] == (1 if split_attention else 0)
    for row, general_row in zip(letters, general, strict=True):
        assert row == pytest.approx([score.option for score in general_row], abs=1e-4)
    prompt = model._render(conversations[0])
    assert letters[0][:2] == pytest.approx(
        [naive_log_likelihood(model, prompt, label) for label in "AB"], abs=2e-3
    )
    assert max(letters[0]) - min(letters[0]) > 1.0


def test_the_end_of_turn_token_is_the_chat_templates(model: HFModel) -> None:
    assert model.tokenizer.convert_ids_to_tokens(model._end_of_turn) == "<|im_end|>"


@pytest.mark.slow
def test_choice_scores_stay_exact_when_a_later_call_reuses_the_prompt_prefix(
    model: HFModel,
) -> None:
    choices = ["MAKE_WOOD_PICKAXE", "DO", " Lima"]
    # Each call keeps its prompt prefix; the next one starts from the part they share.
    sequence = [[FRANCE], [PERU], [PERU], [GREETINGS[0]], [FRANCE, PERU]]
    for conversations in sequence:
        scores = model.choice_scores(conversations, summed(choices))
        for conversation, row in zip(conversations, scores, strict=True):
            prompt = model._render(conversation)
            expected = [naive_log_likelihood(model, prompt, choice) for choice in choices]
            assert row == pytest.approx(expected, abs=2e-3)


@pytest.mark.slow
@pytest.mark.parametrize("split_attention", [False, True], ids=["cache-copy", "split"])
def test_both_choice_paths_give_the_same_scores(model: HFModel, split_attention: bool) -> None:
    # The split-attention path (shared prefix kept once) and the generic cache path agree.
    choices = ["MAKE_WOOD_PICKAXE", "DO", " Lima", "MAKE"]
    conversations = [FRANCE, PERU, GREETINGS[1]]
    model.scorer.split_attention = split_attention
    try:
        scores = model.choice_scores(conversations, summed(choices))
    finally:
        model.scorer.split_attention = True
    for conversation, row in zip(conversations, scores, strict=True):
        prompt = model._render(conversation)
        expected = [naive_log_likelihood(model, prompt, choice) for choice in choices]
        assert row == pytest.approx(expected, abs=2e-3)


HALF_CHOICES = ["MAKE_WOOD_PICKAXE", "DO", " Lima", "MAKE", "banana split"]


@pytest.fixture(scope="module")
def float16_model() -> HFModel:
    return HFModel("smollm2-135m", GenerateConfig(max_tokens=4), threads=1, dtype="float16")


@pytest.mark.slow
@pytest.mark.parametrize("split_attention", [True, False], ids=["split", "padded"])
def test_float16_choice_scores_match_a_plain_forward_pass(
    float16_model: HFModel, split_attention: bool
) -> None:
    float16_model.scorer.split_attention = split_attention
    try:
        # A batch with a shared prefix and one without, then a call reusing the prefix.
        worst, spread = 0.0, 0.0
        for conversations in ([FRANCE, PERU, GREETINGS[1]], [PERU], [FRANCE, PERU]):
            got = plain_forward_differences(float16_model, conversations, HALF_CHOICES)
            worst, spread = max(worst, got[0]), max(spread, got[1])
    finally:
        float16_model.scorer.split_attention = True
    print(f"float16: choice vs plain {worst:.3f}, plain sdpa vs eager {spread:.3f}")
    # Before the split path rounded once, float16 lost whole nats to merged half-precision
    # softmax parts (and bfloat16 crashed on CPU).
    assert worst <= HALF_TOLERANCE


@pytest.mark.slow
def test_the_off_cpu_attention_code_is_as_exact_in_float16(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # What a GPU runs (no CPU flash kernel), checked here on CPU.
    monkeypatch.setattr(scoring, "CPU_FLASH_KERNEL", False)
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=4), threads=1, dtype="float16")
    worst, _ = plain_forward_differences(model, [FRANCE, PERU, GREETINGS[1]], HALF_CHOICES)
    assert worst <= HALF_TOLERANCE


@pytest.mark.parametrize("split_attention", [True, False], ids=["split", "padded"])
def test_loglik_refuses_a_bfloat16_model_naming_the_alternative(split_attention: bool) -> None:
    # bfloat16's rounding alone moves a plain pass's scores by most of a nat (sdpa vs eager,
    # batch 1 vs 6: 0.4-0.85 on real prompts), so no path can match it within 0.1.
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=4), threads=1, dtype="bfloat16")
    model.scorer.split_attention = split_attention
    choices = ChoiceSet(options=("banana", "Paris"), rule="loglik")
    with pytest.raises(UserError, match=r"bfloat16.*dtype=float32") as refused:
        model.generate([FRANCE], choices=choices)
    assert "\n" not in str(refused.value)
    with pytest.raises(UserError, match="bfloat16"):
        model.choice_scores([FRANCE], summed(["banana", "Paris"]))
    # The refusal comes before any weights are loaded, and leaves the user's dtype alone.
    assert model._model is None and model.dtype == torch.bfloat16


def test_the_default_dtype_is_float32_on_cpu_and_bfloat16_elsewhere() -> None:
    assert hf_model._torch_dtype(None, torch.device("cpu")) == torch.float32
    assert hf_model._torch_dtype(None, torch.device("cuda")) == torch.bfloat16
    assert hf_model._torch_dtype("float16", torch.device("cuda")) == torch.float16


@pytest.mark.slow
def test_loglik_turns_a_defaulted_bfloat16_into_float32(monkeypatch: pytest.MonkeyPatch) -> None:
    # The GPU default (bfloat16), here on CPU: free generation runs in it; the first loglik
    # call reloads the model in float32 and then scores as a plain float32 pass does.
    monkeypatch.setattr(hf_model, "_torch_dtype", lambda name, device: torch.bfloat16)
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=2), threads=1)
    [free] = model.generate([GREETINGS[0]])
    assert free.finish_reason != "error" and model.model.dtype == torch.bfloat16
    choices = ChoiceSet(options=("banana", "Paris"), rule="loglik")
    [chosen] = model.generate([FRANCE], choices=choices)
    assert chosen.text == "Paris"
    assert model.dtype == model.model.dtype == torch.float32
    assert model.info()["dtype"] == "float32"
    [row] = model.choice_scores([FRANCE], summed(["banana", "Paris"]))
    prompt = model._render(FRANCE)
    expected = [naive_log_likelihood(model, prompt, choice) for choice in ("banana", "Paris")]
    assert row == pytest.approx(expected, abs=2e-3)


@pytest.mark.gpu
@pytest.mark.slow
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("dtype", ["float16", "float32"])
def test_cuda_choice_scores_match_a_plain_forward_pass(dtype: str) -> None:
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=4), device="cuda", dtype=dtype)
    for split_attention in (True, False):
        model.scorer.split_attention = split_attention
        # The second call reuses the first one's prompt prefix.
        for conversations in ([FRANCE, PERU, GREETINGS[1]], [PERU]):
            worst, spread = plain_forward_differences(model, conversations, HALF_CHOICES)
            bound = 2e-3 if dtype == "float32" else HALF_TOLERANCE
            assert worst <= bound, (dtype, split_attention, worst, spread)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_loglik_defaults_to_float32_and_refuses_bfloat16() -> None:
    model = HFModel("smollm2-135m", GenerateConfig(max_tokens=4), device="cuda")
    model.check_choice_rule("loglik")
    assert model.model.dtype == torch.float32
    refusing = HFModel("smollm2-135m", GenerateConfig(), device="cuda", dtype="bfloat16")
    with pytest.raises(UserError, match="bfloat16"):
        refusing.check_choice_rule("loglik")


def test_prompt_tokens_equal_encoding_each_prompt_whole(model: HFModel) -> None:
    # Same system prompt, other steps; no system message; a conversation of only a system one.
    later_steps = [
        [conversation[0], ChatMessage(role="user", content=f"Step {n}: you see a tree.")]
        for n, conversation in enumerate(REAL)
    ]
    alone = [REAL[0][:1]]
    batches = [REAL, later_steps, GREETINGS, alone, [*REAL[:2], *GREETINGS, *later_steps[:2]]]
    for conversations in batches * 2:
        got = model._prompt_ids(conversations)
        want = [model._encode(model._render(conversation)) for conversation in conversations]
        assert [ids.tolist() for ids in got] == want
    # The system prompts' tokens really were kept (the equality above is not the fallback's).
    kept = {system for system, head in model._heads.items() if head is not None}
    assert {conversation[0].content for conversation in REAL} <= kept
    assert all(len(model._heads[c[0].content][1]) > 500 for c in REAL)  # type: ignore[index]


def test_common_prefix_length_over_token_arrays() -> None:
    sequences = [np.array([1, 2, 3, 4, 5]), np.array([1, 2, 3, 9, 5, 6]), np.array([1, 2, 8, 4])]
    assert scoring._common_prefix_length(sequences) == 2
    assert scoring._common_prefix_length(sequences[:2]) == 3
    # Each sequence keeps `keep_own` tokens of its own.
    assert scoring._common_prefix_length([np.array([1, 2, 3]), np.array([1, 2, 3, 4])]) == 2
    assert (
        scoring._common_prefix_length([np.array([1, 2, 3]), np.array([1, 2, 3])], keep_own=0) == 3
    )
    assert scoring._common_prefix_length([np.array([1]), np.array([1, 2])]) == 0


def test_a_cut_that_would_change_the_tokens_is_never_used() -> None:
    tokenizing = HFModel("smollm2-135m", GenerateConfig(), threads=1)
    # Cutting before a letter splits words: each such head fails its check against the whole.
    tokenizing._cut_markers = ("e",)
    got = tokenizing._prompt_ids(REAL)
    assert [ids.tolist() for ids in got] == [
        tokenizing._encode(tokenizing._render(conversation)) for conversation in REAL
    ]
    assert set(tokenizing._heads.values()) == {None}
    assert tokenizing._model is None


@pytest.mark.slow
def test_reusing_prompt_tokens_changes_no_answer(model: HFModel) -> None:
    from llm_agents.agents.answers.actions import action_names

    # What the token-level check above cannot show: `generate` (choice and free) really goes
    # through the kept tokens. A few prompts suffice; more only re-run the same path.
    choices = ChoiceSet(options=tuple(action_names("classic")), rule="loglik")
    real = REAL[:3]
    answers = {}
    for reuse in (True, False):
        model.reuse_prompt_tokens = reuse
        try:
            chosen = model.generate(real, choices=choices)
            free = model.generate(real[:1])
        finally:
            model.reuse_prompt_tokens = True
        answers[reuse] = [(o.text, o.prompt_tokens, o.finish_reason) for o in chosen + free]
    assert answers[True] == answers[False]
    assert all(reason != "error" for _, _, reason in answers[True])


class _Layer(torch.nn.Module):
    layer_idx = 0


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
@pytest.mark.parametrize("cpu_kernel", [True, False], ids=["cpu-kernel", "generic"])
def test_split_attention_rounds_once_in_half_precision(
    monkeypatch: pytest.MonkeyPatch, dtype: torch.dtype, cpu_kernel: bool
) -> None:
    # Attention over a shared prefix plus own keys, merged, equals attention over both at
    # once computed exactly, up to one rounding to the model's dtype. Scores of realistic size
    # (tens) are where rounding them, or their log-sum-exp, to half precision costs nats.
    monkeypatch.setattr(scoring, "CPU_FLASH_KERNEL", cpu_kernel)
    torch.manual_seed(0)
    batch, heads, kv_heads, new, prefix_length, past_length, dim = 2, 6, 2, 5, 40, 7, 16
    query = (torch.randn(batch, heads, new, dim) * 2).to(dtype)
    keys, values = (
        (torch.randn(batch, kv_heads, new, dim) * 2).to(dtype),
        torch.randn(batch, kv_heads, new, dim).to(dtype),
    )
    prefix = [tuple((torch.randn(1, kv_heads, prefix_length, dim) * 2).to(dtype) for _ in "kv")]
    past = {0: tuple(torch.randn(batch, kv_heads, past_length, dim).to(dtype) for _ in "kv")}
    own_mask = torch.rand(batch, new, past_length + new) > 0.3
    own_mask[..., past_length:] |= torch.eye(new, dtype=torch.bool)
    causal = torch.ones(new, new, dtype=torch.bool).tril().expand(batch, new, new)
    cases = [
        (_SharedPrefixAttention(prefix), keys, values, causal),
        (
            _SharedPrefixAttention(prefix, past=past, mask=own_mask),
            torch.cat([past[0][0], keys], 2),
            torch.cat([past[0][1], values], 2),
            own_mask,
        ),
    ]
    for plan, own_keys, own_values, mask in cases:
        got, _ = _split_attention_forward(
            _Layer(), query, keys, values, None, scaling=0.3, split_attention=plan
        )
        assert got.dtype == dtype
        all_keys = torch.cat([prefix[0][0].expand(batch, -1, -1, -1), own_keys], 2).double()
        all_values = torch.cat([prefix[0][1].expand(batch, -1, -1, -1), own_values], 2).double()
        visible = torch.cat([torch.ones(batch, new, prefix_length, dtype=torch.bool), mask], -1)
        groups = heads // kv_heads
        scores = (query.double() @ all_keys.repeat_interleave(groups, 1).transpose(-1, -2)) * 0.3
        scores = scores.masked_fill(~visible[:, None], float("-inf"))
        want = (scores.softmax(-1) @ all_values.repeat_interleave(groups, 1)).transpose(1, 2)
        error = (got.double() - want).abs()
        assert (error <= want.abs() * torch.finfo(dtype).eps + 1e-6).all(), float(error.max())


def test_generic_attention_matches_the_cpu_kernel() -> None:
    # The matrix-product attention (used off CPU) equals the CPU flash kernel's, lse included.
    torch.manual_seed(0)
    query, keys, values = torch.randn(2, 6, 5, 8), torch.randn(2, 2, 7, 8), torch.randn(2, 2, 7, 8)
    shared_keys, shared_values = torch.randn(1, 2, 9, 8), torch.randn(1, 2, 9, 8)
    mask = torch.rand(2, 5, 7) > 0.3
    mask[..., 0] = True
    cases: list[tuple[dict[str, Any], torch.Tensor, torch.Tensor]] = [
        ({}, shared_keys, shared_values),
        ({"causal": True}, keys[:, :, :5], values[:, :, :5]),
        ({"mask": mask}, keys, values),
    ]
    for kwargs, k, v in cases:
        fused = _attend(query, k, v, 0.3, fused=True, **kwargs)
        generic = _attend(query, k, v, 0.3, fused=False, **kwargs)
        for got, want in zip(generic, fused, strict=True):
            assert got.shape == want.shape
            assert torch.allclose(got, want, atol=1e-5)


@pytest.mark.slow
def test_batched_greedy_equals_unbatched(model: HFModel) -> None:
    batched = model.generate(GREETINGS)
    single = [model.generate([conversation])[0] for conversation in GREETINGS]
    assert [o.text for o in batched] == [o.text for o in single]
    assert len({o.text for o in batched}) == len(GREETINGS)


@pytest.mark.slow
def test_stop_string_cuts_the_answer() -> None:
    counting = [ChatMessage(role="user", content="Count from 1 to 10, separated by commas.")]
    free = HFModel("smollm2-135m", GenerateConfig(max_tokens=30), threads=1)
    full = free.generate([counting])[0].text
    assert "4" in full
    free.config = GenerateConfig(max_tokens=30, stop=["4"])
    cut = free.generate([counting])[0]
    assert cut.finish_reason == "stop"
    assert "4" not in cut.text
    assert full.startswith(cut.text.rstrip())


def test_the_candidate_trie_stores_a_shared_prefix_once() -> None:
    trie = CandidateTrie([[5, 6, 7], [5, 6, 8], [5], [9, 6]])
    assert trie.tokens == [5, 6, 7, 8, 9, 6]
    assert trie.paths == [[0, 1, 2], [0, 1, 3], [0], [4, 5]]
    assert trie.depths == [0, 1, 2, 2, 0, 1]
    assert trie.ancestry() == [[0], [1, 0], [2, 1, 0], [3, 1, 0], [4], [5, 4]]


def test_thinking_budget_forces_the_closing_tag() -> None:
    budget = ThinkingBudgetLogitsProcessor(
        prompt_len=2,
        budget=3,
        open_ids=[7],
        close_ids=[8, 9],
        opened_in_prompt=[False, True, False],
    )
    input_ids = torch.tensor(
        [
            [0, 0, 7, 1, 1, 1],  # thought 3 tokens after <think>: must start closing
            [0, 0, 1, 1, 1, 8],  # prompt opened the block; closing tag half written
            [0, 0, 1, 1, 1, 1],  # never thinking
        ]
    )
    scores = torch.zeros(3, 10)
    forced = budget(input_ids, scores.clone())
    assert forced[0].argmax() == 8 and forced[0].max() > forced[0].min()
    assert forced[1].argmax() == 9 and forced[1].max() > forced[1].min()
    assert torch.equal(forced[2], scores[2])
    under_budget = budget(torch.tensor([[0, 0, 7, 1, 8]]), torch.zeros(1, 10))
    assert torch.equal(under_budget, torch.zeros(1, 10))


@pytest.mark.parametrize("backend", ["hf", "vllm"])
def test_missing_model_folder_is_a_user_error(tmp_path: Path, backend: str) -> None:
    with pytest.raises(UserError, match=f"{backend} model folder .* does not exist"):
        local_model_path(backend, str(tmp_path / "nope"))
    assert local_model_path(backend, str(tmp_path)) == tmp_path
    assert local_model_path(backend, "someone/some-model") is None
    assert local_model_path(backend, "Qwen/Qwen2.5-0.5B-Instruct") is None


@pytest.mark.parametrize(
    ("option", "value", "named"),
    [
        ("rows_per_forward", 0, "rows_per_forward"),
        ("threads", 0, "threads"),
        ("dtype", "float8", "dtype"),
        ("choice_scoring", "mean", "choice_scoring"),
        ("device", "gpu", "'gpu' is not a torch device"),
        ("rows_per_forwrd", 4, "did you mean 'rows_per_forward'"),
    ],
)
def test_bad_options_are_one_line_user_errors(option: str, value: Any, named: str) -> None:
    with pytest.raises(UserError, match=named) as refused:
        get_model("hf:smollm2-135m", **{option: value})
    assert "\n" not in str(refused.value)


def test_cache_folder_follows_the_environment(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv(embedded.CACHE_ENV_VAR, str(tmp_path))
    assert embedded.cache_root() == tmp_path


@pytest.mark.slow
def test_the_embedded_folder_is_a_complete_model(model: HFModel) -> None:
    folder = embedded.embedded_model_dir()
    assert model.model_path == folder
    names = {path.name for path in folder.iterdir()}
    assert {"config.json", "model.safetensors", "tokenizer.json"} <= names
    assert "quantization_config" not in (folder / "config.json").read_text()


def test_a_missing_gguf_reader_gives_the_install_command(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    real_find_spec = embedded.importlib.util.find_spec
    monkeypatch.setattr(
        embedded.importlib.util,
        "find_spec",
        lambda name, *args: None if name == "accelerate" else real_find_spec(name, *args),
    )
    with pytest.raises(UserError, match=r"'accelerate'.*craftext-llm\[hf\]"):
        embedded.convert_gguf(tmp_path / "model.gguf", tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "error",
    [
        torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"),
        RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate memory"),
        RuntimeError("MPS backend out of memory (MPS allocated: 1 GB)"),
        hf_model.ContextLengthError("a prompt of 9000 tokens is longer than the model's context"),
    ],
)  # fmt: skip
def test_running_out_of_memory_or_context_fails_the_batch_as_the_backends(
    error: Exception,
) -> None:
    def run(batch: Any) -> Any:
        raise error

    outputs = HFModel._in_batches(SimpleNamespace(), [FRANCE] * 3, run, 2)  # type: ignore[arg-type]
    assert [o.finish_reason for o in outputs] == ["error"] * 3
    assert all(type(error).__name__ in (o.error or "") for o in outputs)


@pytest.mark.parametrize(
    "error", [RuntimeError("The size of tensor a (3) must match"), ValueError("bad logits")]
)
def test_any_other_error_of_a_forward_pass_is_a_bug_and_raised(error: Exception) -> None:
    def run(batch: Any) -> Any:
        raise error

    with pytest.raises(type(error), match=str(error).split("(")[0]):
        HFModel._in_batches(SimpleNamespace(), [FRANCE], run, 2)  # type: ignore[arg-type]


@pytest.mark.slow
def test_a_prompt_over_the_context_length_is_a_backend_failure(model: HFModel) -> None:
    context = model.context_length
    assert context == model.model.config.max_position_embeddings
    long = [ChatMessage(role="user", content="wood " * (context + 10))]
    [output] = model.generate([long])
    assert output.finish_reason == "error" and "longer than the model's context" in (
        output.error or ""
    )
    [fine] = model.generate([FRANCE])
    assert fine.finish_reason != "error"
