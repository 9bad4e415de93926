"""The transformers backend: local models on CPU or GPU, no server.

Model names (`hf:<name>`): `smollm2-135m` is the embedded default (see `embedded.py`); a path
loads any local model folder; any other name is a hub id, loaded only from the local hub cache
(the hub is never contacted, so nothing hangs offline).

Free generation renders each conversation with the model's chat template and decodes a batch at
once (left padding). Choices follow the `loglik` rule only (`guided` is refused): every
candidate is scored by its log-likelihood after the prompt, with one prompt pass per batch: all
candidates then go through a single pass over the prompt's cached keys and values, side by side
in one sequence, each seeing only the prompt and its own earlier tokens (a block-diagonal
attention mask). The answer is always one of the choices.

`loglik` scores equal a plain forward pass over prompt + option in float32 (to float rounding)
and in float16 (to hundredths of a nat: the split path's attention runs in float32 and rounds
once). bfloat16 is refused for `loglik`: its rounding alone moves a score by most of a nat
(two plain bfloat16 passes that differ only in their attention kernel, or only in batch size,
disagree that much on the embedded model), so no batched or cached scorer can match the plain
pass within 0.1 nats, and rankings would follow the rounding. Left unset, the dtype is
float32 for `loglik` on a GPU too (bfloat16 otherwise); benchmarks/bench_choice_dtypes.py
measures every dtype and path.

Reasoning models: the thinking is split from the answer (`reasoning.py`). With
`reasoning_budget` set, a row that has thought for that many tokens has its closing tag forced,
and a completion may run to `reasoning_budget + max_tokens` tokens (thinking, then answer); an
answer still cut off gets one "answer only" follow-up.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Literal

import numpy as np
import torch
from jinja2 import TemplateError
from transformers import (
    AutoConfig,
    AutoModelForCausalLM,
    AutoTokenizer,
    DynamicCache,
    LogitsProcessorList,
)
from transformers.cache_utils import DynamicLayer

from env.errors import UserError
from llm_agents.backends.base import (
    ANSWER_FIELDS,
    ChatMessage,
    ChoiceRule,
    ChoiceSet,
    Conversation,
    FinishReason,
    GenerateConfig,
    ModelAPI,
    ModelOutput,
    local_model_path,
    ranked_choices,
)
from llm_agents.backends.embedded import EMBEDDED_MODEL_NAME
from llm_agents.backends.hf.scoring import (
    MAX_KEPT_HEADS,
    SPLIT_ATTENTION,
    CandidateTrie,
    _common_prefix_length,
    _padded,
    _SharedPrefixAttention,
    _supports_split_attention,
    _to_torch,
    _trie_and_pairs,
)
from llm_agents.backends.hf.thinking import ThinkingBudget
from llm_agents.backends.reasoning import (
    THINK_CLOSE,
    THINK_OPEN,
    resolve_truncated,
    with_reasoning_split,
)

ChoiceScoring = Literal["sum", "mean"]

logger = logging.getLogger(__name__)

#: Why `loglik` refuses a bfloat16 model, and what to use instead.
LOGLIK_BFLOAT16 = (
    "hf loglik choices cannot be scored in bfloat16: its rounding alone moves a score by most "
    "of a nat, so rankings would follow the rounding; set dtype=float32 (exact) or "
    "dtype=float16 (--backend-option dtype=float32), or leave dtype unset"
)


class HFModel(ModelAPI):
    """A transformers causal LM answering batches of chat conversations.

    Options: `device` ("cpu", "cuda", ...; default: cuda when available), `dtype` ("float32",
    "bfloat16", "float16"; default float32 on CPU, bfloat16 on GPU except float32 for `loglik`
    choices, which refuse bfloat16: see the module docstring), `threads` (torch CPU
    threads; default: torch's own choice), `rows_per_forward` (conversations per forward pass),
    `choice_scoring` ("sum": total log-likelihood; "mean": per token, which favours long
    candidates less).
    """

    backend_name = "hf"
    honoured_config = ANSWER_FIELDS
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"loglik"})
    choice_rule_gaps: ClassVar[dict[ChoiceRule, str]] = {
        "guided": "it ranks whole options by log-likelihood (loglik); guided decoding needs "
        "the vllm or openai backend"
    }
    # transformers' own annotations of its model classes do not type-check cleanly.
    _model: Any = None

    def __init__(
        self,
        model_name: str,
        config: GenerateConfig | None = None,
        *,
        device: str | None = None,
        dtype: str | None = None,
        threads: int | None = None,
        rows_per_forward: int = 16,
        choice_scoring: ChoiceScoring = "sum",
        **options: Any,
    ):
        super().__init__(model_name, config, **options)
        if rows_per_forward < 1:
            raise UserError(f"hf rows_per_forward must be at least 1, got {rows_per_forward}")
        if choice_scoring not in ("sum", "mean"):
            raise UserError(f"hf choice_scoring must be 'sum' or 'mean', got {choice_scoring!r}")
        if threads is not None:
            if threads < 1:
                raise UserError(f"hf threads must be at least 1, got {threads}")
            torch.set_num_threads(threads)
        self.rows_per_forward = rows_per_forward
        self.choice_scoring: ChoiceScoring = choice_scoring
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.dtype = _torch_dtype(dtype, self.device)
        self.dtype_given = dtype is not None
        self.model_path = local_model_path("hf", model_name)
        self._source = str(self.model_path) if self.model_path is not None else model_name
        try:
            self.tokenizer = AutoTokenizer.from_pretrained(self._source, local_files_only=True)
            model_config = AutoConfig.from_pretrained(self._source, local_files_only=True)
        except OSError as err:
            raise _load_error(model_name, err) from err
        if not self.tokenizer.chat_template:
            raise UserError(f"hf model {model_name!r} has no chat template in its tokenizer")
        self.tokenizer.padding_side = "left"
        if self.tokenizer.pad_token_id is None:
            self.tokenizer.pad_token = self.tokenizer.eos_token
        self._think_close_ids: list[int] = self._encode(THINK_CLOSE)
        # Special tokens a text may be cut before without changing its tokens (see _head).
        self._cut_markers = tuple(
            token.content
            for token in self.tokenizer.added_tokens_decoder.values()
            if token.special and not token.lstrip and not token.normalized
        )
        # System message -> its rendered text and token ids, or None where it cannot be cut off.
        self._heads: dict[str, tuple[str, np.ndarray] | None] = {}
        #: Whether prompts reuse their system message's tokens (`_encode_prompts`); False
        #: encodes every prompt whole (the benchmarks compare the two).
        self.reuse_prompt_tokens = True
        # Key/value states of the last choice-mode prompt prefix, per layer (see _prefix_cache).
        self._prefix_ids = np.zeros(0, dtype=np.int64)
        self._prefix_states: list[tuple[torch.Tensor, torch.Tensor]] = []
        # Choice mode's own attention (see _SharedPrefixAttention) where the model allows it.
        self.split_attention = _supports_split_attention(model_config)

    @property
    def model(self) -> Any:
        """The transformers model in `self.dtype`, loaded on first use: the choice rule, known
        only after construction (`check_choice_rule`), may still change the default dtype."""
        if self._model is None:
            try:
                model: Any = AutoModelForCausalLM.from_pretrained(
                    self._source, local_files_only=True, dtype=self.dtype
                )
            except OSError as err:
                raise _load_error(self.model_name, err) from err
            self._model = model.to(self.device).eval()
        return self._model

    def check_choice_rule(self, rule: ChoiceRule) -> None:
        """As `ModelAPI.check_choice_rule`; `loglik` also refuses a bfloat16 the user set and
        replaces a defaulted one by float32 (see the module docstring)."""
        super().check_choice_rule(rule)
        if rule != "loglik" or self.dtype != torch.bfloat16:
            return
        if self.dtype_given:
            raise UserError(LOGLIK_BFLOAT16)
        logger.info("hf: loglik choices score in float32 (bfloat16 cannot score them exactly)")
        self.dtype = torch.float32
        if self._model is not None:
            # Loaded by free generation before the first choice; reloaded from the checkpoint
            # rather than upcast, so the weights are those a float32 load gives.
            self._model = None
            self._prefix_ids, self._prefix_states = np.zeros(0, dtype=np.int64), []
            if self.device.type == "cuda":
                torch.cuda.empty_cache()

    def info(self) -> dict[str, str]:
        import transformers

        return {
            **super().info(),
            "model_path": str(self.model_path or self.model_name),
            "transformers": transformers.__version__,
            "torch": torch.__version__,
            "device": str(self.device),
            "dtype": str(self.dtype).removeprefix("torch."),
            "choice_scoring": self.choice_scoring,
        }

    def generate(
        self,
        conversations: Sequence[Conversation],
        choices: ChoiceSet | None = None,
    ) -> list[ModelOutput]:
        if choices is not None:
            self.check_choice_rule(choices.rule)
            options = list(choices.options)
            candidates = [self._encode(option) for option in options]
            if empty := [
                option for option, ids in zip(options, candidates, strict=True) if not ids
            ]:
                raise UserError(f"choices {empty!r} encode to no tokens; every choice needs text")
            return self._in_batches(
                conversations, lambda batch: self._choose(batch, options, candidates)
            )
        outputs = self._in_batches(conversations, self._generate_split)
        return resolve_truncated(
            conversations, outputs, lambda batch: self._in_batches(batch, self._generate_split)
        )

    def choice_scores(
        self, conversations: Sequence[Conversation], choices: Sequence[str]
    ) -> list[list[float]]:
        """Log-likelihood (summed over tokens) of each choice after each conversation's prompt."""
        self.check_choice_rule("loglik")
        prompts = self._prompt_ids(conversations)
        candidates = [self._encode(choice) for choice in choices]
        with torch.inference_mode():
            return self._candidate_log_likelihoods(prompts, candidates)

    # -- free generation ----------------------------------------------------------------------

    def _generate_split(self, conversations: Sequence[Conversation]) -> list[ModelOutput]:
        texts = [self._render(conversation) for conversation in conversations]
        # Templates that open the thinking block themselves make the completion start inside it.
        opened = [text.rstrip().endswith(THINK_OPEN) for text in texts]
        raw = self._generate_raw(self._encode_prompts(conversations, texts), opened)
        return [
            with_reasoning_split(output, thinking_open_in_prompt=was_opened)
            for output, was_opened in zip(raw, opened, strict=True)
        ]

    def _generate_raw(self, prompts: list[np.ndarray], opened: list[bool]) -> list[ModelOutput]:
        config = self.config
        start = time.perf_counter()
        # Left padding, as the tokenizer pads a batch for generation.
        ids, mask = _padded(prompts, self.tokenizer.pad_token_id, left=True)
        input_ids, attention_mask = _to_torch(ids, self.device), _to_torch(mask, self.device)
        prompt_len = input_ids.shape[1]
        max_new = config.max_tokens
        processors = []
        if config.reasoning_budget is not None and self._think_close_ids:
            # Thinking gets its own budget on top of the answer's max_tokens.
            max_new += config.reasoning_budget + len(self._think_close_ids)
            processors.append(
                ThinkingBudget(
                    prompt_len=prompt_len,
                    budget=config.reasoning_budget,
                    open_ids=self._encode(THINK_OPEN),
                    close_ids=self._think_close_ids,
                    opened_in_prompt=opened,
                )
            )
        sampling: dict[str, Any] = {"do_sample": False}
        if config.temperature > 0:
            sampling = {"do_sample": True, "temperature": config.temperature, "top_p": config.top_p}
            if config.sampling_seed is not None:
                torch.manual_seed(config.sampling_seed)
        with torch.inference_mode():
            generated = self.model.generate(
                input_ids=input_ids,
                attention_mask=attention_mask,
                max_new_tokens=max_new,
                pad_token_id=self.tokenizer.pad_token_id,
                logits_processor=LogitsProcessorList(processors),
                stop_strings=config.stop or None,
                tokenizer=self.tokenizer if config.stop else None,
                **sampling,
            )
        latency = time.perf_counter() - start
        eos_ids = self._eos_ids()
        outputs = []
        for row, prompt in zip(generated[:, prompt_len:], prompts, strict=True):
            tokens = row.tolist()
            ended = next((i for i, tok in enumerate(tokens) if tok in eos_ids), None)
            if ended is not None:
                tokens = tokens[:ended]
            text = str(self.tokenizer.decode(tokens, skip_special_tokens=True))
            stopped_by_string, text = _cut_at_stop(text, config.stop)
            finish: FinishReason = "stop" if ended is not None or stopped_by_string else "length"
            outputs.append(
                ModelOutput(
                    text=text,
                    prompt_tokens=len(prompt),
                    completion_tokens=len(tokens) + (ended is not None),
                    latency_s=latency,
                    finish_reason=finish,
                )
            )
        return outputs

    # -- choice mode --------------------------------------------------------------------------

    def _choose(
        self, conversations: Sequence[Conversation], choices: list[str], candidates: list[list[int]]
    ) -> list[ModelOutput]:
        start = time.perf_counter()
        prompts = self._prompt_ids(conversations)
        with torch.inference_mode():
            scores = self._candidate_log_likelihoods(prompts, candidates)
        if self.choice_scoring == "mean":
            scores = [
                [score / len(ids) for score, ids in zip(row, candidates, strict=True)]
                for row in scores
            ]
        return ranked_choices(choices, prompts, candidates, scores, time.perf_counter() - start)

    def _candidate_log_likelihoods(
        self, token_ids: Sequence[np.ndarray | Sequence[int]], candidates: list[list[int]]
    ) -> list[list[float]]:
        """Summed log-probability of every candidate after every prompt (token ids).

        The prompts' common prefix (in an agent, the system prompt) is encoded once and shared
        by the batch; then one pass over the rest of every prompt, one over the candidates.
        """
        prompts = [np.asarray(ids, dtype=np.int64) for ids in token_ids]
        if self.split_attention:
            return self._split_log_likelihoods(prompts, candidates)
        device = self.device
        pad = self.tokenizer.pad_token_id
        batch = len(prompts)
        # Every prompt keeps at least one own token: its last one predicts the first candidate
        # token.
        shared = _common_prefix_length(prompts)
        cache = None
        if shared:
            cache = self._prefix_cache(prompts[0][:shared])
            cache.batch_repeat_interleave(batch)
        # Left padding (after the shared prefix) puts every prompt's last token in one column.
        padded_ids, padded_mask = _padded([p[shared:] for p in prompts], pad, left=True)
        rest_ids, rest_mask = _to_torch(padded_ids, device), _to_torch(padded_mask, device)
        prompt_mask = torch.cat(
            [torch.ones(batch, shared, dtype=rest_mask.dtype, device=device), rest_mask], dim=-1
        )
        first = self.model(
            input_ids=rest_ids,
            attention_mask=prompt_mask,
            position_ids=shared + (rest_mask.cumsum(-1) - 1).clamp(min=0),
            past_key_values=cache,
            use_cache=True,
            logits_to_keep=1,
        )
        first_tokens = torch.tensor([ids[0] for ids in candidates], device=device)
        scores = first.logits[:, -1].float().log_softmax(-1)[:, first_tokens]
        # The logits at a candidate's token j predict its token j + 1; single-token candidates
        # are fully scored by the prompt pass.
        trie, pairs = _trie_and_pairs(candidates)
        if pairs:
            predicting = sorted({node for _, node, _ in pairs})
            row_of = {node: row for row, node in enumerate(predicting)}
            later = self._candidate_pass(first.past_key_values, prompt_mask, trie, predicting)
            rows = torch.tensor([row_of[node] for _, node, _ in pairs], device=device)
            targets = torch.tensor([token for _, _, token in pairs], device=device)
            owners = torch.tensor([k for k, _, _ in pairs], device=device)
            scores = scores.index_add(1, owners, later[:, rows, targets])
        return [[float(score) for score in row] for row in scores]

    def _prefix_cache(self, prefix: np.ndarray) -> Any:
        """A batch-1 cache of `prefix`, starting from the previous call's prefix where they agree.

        Successive agent steps share their system prompt, so most of it is encoded only once.
        """
        reuse = _common_prefix_length([self._prefix_ids, prefix], keep_own=0)
        cache = DynamicCache(config=self.model.config)
        if reuse:
            for index, (keys, values) in enumerate(self._prefix_states):
                cache.update(keys[:, :, :reuse], values[:, :, :reuse], index)
        if reuse < len(prefix):
            self.model(
                input_ids=_to_torch(prefix[None, reuse:], self.device),
                past_key_values=cache,
                use_cache=True,
                logits_to_keep=1,
            )
        states = []
        for layer in cache.layers:
            # Only plain per-token layers can be cut to a shorter prefix later.
            if type(layer) is not DynamicLayer or layer.keys is None or layer.values is None:
                return cache
            states.append((layer.keys, layer.values))
        self._prefix_ids, self._prefix_states = prefix, states
        return cache

    def _candidate_pass(
        self,
        prompt_cache: Any,
        prompt_mask: torch.Tensor,
        trie: CandidateTrie,
        predicting: list[int],
    ) -> torch.Tensor:
        """Log-probabilities at the `predicting` nodes of the candidate trie, in one pass.

        A trie node sees the (unpadded) prompt and its own ancestors only, so one pass over the
        prompt cache scores every candidate, and a prefix shared by candidates is computed once.
        """
        device = self.device
        batch, width = prompt_mask.shape
        total = len(trie.tokens)
        own = torch.zeros(total, total, dtype=torch.bool, device=device)
        for node, seen in enumerate(trie.ancestry()):
            own[node, seen] = True
        allowed = torch.cat(
            [
                prompt_mask.bool()[:, None, :].expand(batch, total, width),
                own[None].expand(batch, total, total),
            ],
            dim=-1,
        )
        dtype = self.model.dtype
        mask = torch.zeros(allowed.shape, dtype=dtype, device=device)
        mask.masked_fill_(~allowed, torch.finfo(dtype).min)
        depths = torch.tensor(trie.depths, device=device)
        output = self.model(
            input_ids=torch.tensor([trie.tokens] * batch, device=device),
            attention_mask=mask[:, None],
            position_ids=prompt_mask.sum(-1, keepdim=True) + depths[None],
            past_key_values=prompt_cache,
            use_cache=True,
            logits_to_keep=torch.tensor(predicting, device=device),
        )
        log_probs: torch.Tensor = output.logits.float().log_softmax(-1)
        return log_probs

    # -- choice mode with split attention -----------------------------------------------------

    def _split_log_likelihoods(
        self, prompts: list[np.ndarray], candidates: list[list[int]]
    ) -> list[list[float]]:
        """`_candidate_log_likelihoods` without copying the shared prefix per prompt.

        The prefix's keys and values are kept once (batch 1) and every prompt's queries attend
        to them in one batched product; each prompt's own tokens (right-padded, so no row is
        masked out) and then the candidate trie attend to their own keys separately, and the
        two softmax parts are merged by their log-sum-exp. Only trie nodes with children are
        fed: a leaf's token is scored by its parent's logits.
        """
        device = self.device
        pad = self.tokenizer.pad_token_id
        batch = len(prompts)
        shared = _common_prefix_length(prompts)
        prefix = self._split_prefix(prompts[0][:shared]) if shared else None
        padded_ids, padded_mask = _padded([p[shared:] for p in prompts], pad, left=False)
        rest_ids = _to_torch(padded_ids, device)
        lengths = _to_torch(padded_mask.sum(1), device)
        width = rest_ids.shape[1]
        positions = shared + torch.arange(width, device=device)
        rest_plan = _SharedPrefixAttention(prefix, store=True)
        hidden = self._hidden_states(rest_ids, positions.expand(batch, width), rest_plan)
        last = hidden[torch.arange(batch, device=device), lengths - 1]
        first_tokens = torch.tensor([ids[0] for ids in candidates], device=device)
        scores = self._log_probs(last)[:, first_tokens]
        trie, pairs = _trie_and_pairs(candidates)
        if pairs:
            # Nodes with children; their ancestors have children too, so the set is closed.
            fed = sorted({node for _, node, _ in pairs})
            row_of = {node: row for row, node in enumerate(fed)}
            ancestry = trie.ancestry()
            own = torch.zeros(len(fed), len(fed), dtype=torch.bool, device=device)
            for row, node in enumerate(fed):
                own[row, [row_of[seen] for seen in ancestry[node]]] = True
            past_mask = torch.arange(width, device=device)[None, None] < lengths[:, None, None]
            depths = torch.tensor([trie.depths[node] for node in fed], device=device)
            trie_plan = _SharedPrefixAttention(
                prefix,
                past=rest_plan.stored,
                mask=torch.cat(
                    [past_mask.expand(batch, len(fed), width), own.expand(batch, -1, -1)], -1
                ),
            )
            trie_ids = torch.tensor([[trie.tokens[node] for node in fed]] * batch, device=device)
            trie_hidden = self._hidden_states(
                trie_ids, shared + lengths[:, None] + depths[None], trie_plan
            )
            later = self._log_probs(trie_hidden)
            rows = torch.tensor([row_of[node] for _, node, _ in pairs], device=device)
            targets = torch.tensor([token for _, _, token in pairs], device=device)
            owners = torch.tensor([k for k, _, _ in pairs], device=device)
            scores = scores.index_add(1, owners, later[:, rows, targets])
        return [[float(score) for score in row] for row in scores]

    def _split_prefix(self, prefix: np.ndarray) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Keys and values (batch 1, per layer) of `prefix`, reusing the previous call's."""
        reuse = _common_prefix_length([self._prefix_ids, prefix], keep_own=0)
        kept = [(keys[:, :, :reuse], values[:, :, :reuse]) for keys, values in self._prefix_states]
        states = kept
        if reuse < len(prefix):
            plan = _SharedPrefixAttention(kept if reuse else None, store=True)
            ids = _to_torch(prefix[None, reuse:], self.device)
            positions = torch.arange(reuse, len(prefix), device=self.device)[None]
            self._hidden_states(ids, positions, plan)
            new = [plan.stored[layer] for layer in range(len(plan.stored))]
            states = (
                [
                    (torch.cat([k, new_k], 2), torch.cat([v, new_v], 2))
                    for (k, v), (new_k, new_v) in zip(kept, new, strict=True)
                ]
                if reuse
                else new
            )
        self._prefix_ids, self._prefix_states = prefix, states
        return states

    def _hidden_states(
        self, ids: torch.Tensor, positions: torch.Tensor, plan: _SharedPrefixAttention
    ) -> torch.Tensor:
        """The decoder's final hidden states, attending as `plan` says."""
        config = self.model.config
        default = config._attn_implementation
        config._attn_implementation = SPLIT_ATTENTION
        try:
            output = self.model.get_decoder()(
                input_ids=ids, position_ids=positions, use_cache=False, split_attention=plan
            )
        finally:
            config._attn_implementation = default
        hidden: torch.Tensor = output.last_hidden_state
        return hidden

    def _log_probs(self, hidden: torch.Tensor) -> torch.Tensor:
        log_probs: torch.Tensor = self.model.get_output_embeddings()(hidden).float().log_softmax(-1)
        return log_probs

    # -- helpers ------------------------------------------------------------------------------

    def _in_batches(
        self,
        conversations: Sequence[Conversation],
        run: Callable[[Sequence[Conversation]], list[ModelOutput]],
    ) -> list[ModelOutput]:
        outputs: list[ModelOutput] = []
        for begin in range(0, len(conversations), self.rows_per_forward):
            batch = conversations[begin : begin + self.rows_per_forward]
            try:
                outputs.extend(run(batch))
            except (RuntimeError, ValueError) as err:
                # Out of memory or a prompt over the context length fails this batch only.
                outputs.extend(
                    ModelOutput(
                        text="", finish_reason="error", error=f"{type(err).__name__}: {err}"
                    )
                    for _ in batch
                )
        return outputs

    def _render(self, conversation: Sequence[ChatMessage]) -> str:
        messages = [{"role": m.role, "content": m.content} for m in conversation]
        text = self.tokenizer.apply_chat_template(
            messages, add_generation_prompt=True, tokenize=False
        )
        return str(text)

    def _encode(self, text: str) -> list[int]:
        return list(self.tokenizer(text, add_special_tokens=False).input_ids)

    def _prompt_ids(self, conversations: Sequence[Conversation]) -> list[np.ndarray]:
        """Each conversation's prompt tokens (chat template, generation prompt added)."""
        texts = [self._render(conversation) for conversation in conversations]
        return self._encode_prompts(conversations, texts)

    def _encode_prompts(
        self, conversations: Sequence[Conversation], texts: list[str]
    ) -> list[np.ndarray]:
        """The token ids of each conversation's rendered `texts`, equal to encoding each whole.

        A system message (an agent's is the same every step, and most of every prompt) is
        encoded once and its tokens kept (`_head`); each call encodes only the rest of every
        text, all in one batched tokenizer call.
        """
        heads = [
            self._head(conversation, text) if self.reuse_prompt_tokens else None
            for conversation, text in zip(conversations, texts, strict=True)
        ]
        rests = [
            text[len(head[0]) :] if head else text for head, text in zip(heads, texts, strict=True)
        ]
        encoded = self.tokenizer(rests, add_special_tokens=False).input_ids
        return [
            np.concatenate([head[1], np.asarray(ids, dtype=np.int64)])
            if head
            else np.asarray(ids, dtype=np.int64)
            for head, ids in zip(heads, encoded, strict=True)
        ]

    def _head(self, conversation: Conversation, text: str) -> tuple[str, np.ndarray] | None:
        """The start of `text` whose tokens are kept for its system message, with the tokens.

        The cut lies where a special token begins (the template's next turn marker):
        tokenizers split a text at special tokens before anything else, so the two sides
        encode as they do inside the whole text. Each new head is checked once against the
        whole text's encoding, and not used where they differ.
        """
        if not conversation or conversation[0].role != "system":
            return None
        system = conversation[0].content
        if system not in self._heads:
            if len(self._heads) >= MAX_KEPT_HEADS:
                del self._heads[next(iter(self._heads))]
            self._heads[system] = self._new_head(system, text)
        head = self._heads[system]
        if head is None or not text.startswith(head[0]):
            return None
        if not text.startswith(self._cut_markers, len(head[0])):
            return None
        return head

    def _new_head(self, system: str, text: str) -> tuple[str, np.ndarray] | None:
        try:
            alone = str(
                self.tokenizer.apply_chat_template(
                    [{"role": "system", "content": system}], tokenize=False
                )
            )
        except (TemplateError, ValueError):
            # Some templates refuse a lone system message (or one that is not first).
            return None
        agreed = next(
            (i for i, (a, b) in enumerate(zip(alone, text, strict=False)) if a != b),
            min(len(alone), len(text)),
        )
        cut = max(
            (text.rfind(marker, 0, agreed + len(marker)) for marker in self._cut_markers),
            default=-1,
        )
        if cut <= 0:
            return None
        ids = self._encode(text[:cut])
        if ids + self._encode(text[cut:]) != self._encode(text):
            return None
        return text[:cut], np.asarray(ids, dtype=np.int64)

    def _eos_ids(self) -> set[int]:
        configured = self.model.generation_config.eos_token_id
        ids = configured if isinstance(configured, list) else [configured]
        return {i for i in [*ids, self.tokenizer.eos_token_id] if i is not None}


#: Model types whose logits are the decoder's last hidden state times the output embeddings,
#: with every layer attending to all earlier tokens (no sliding window, no soft-capping).


def _cut_at_stop(text: str, stops: list[str]) -> tuple[bool, str]:
    positions = [pos for stop in stops if (pos := text.find(stop)) != -1]
    if not positions:
        return False, text
    return True, text[: min(positions)]


def _load_error(model_name: str, err: OSError) -> UserError:
    return UserError(
        f"cannot load hf model {model_name!r}: {err}. Pass a local model folder "
        f"(hf:/path/to/model), hf:{EMBEDDED_MODEL_NAME}, or a hub id already in the local hub "
        "cache"
    )


def _torch_dtype(name: str | None, device: torch.device) -> torch.dtype:
    if name is None:
        return torch.float32 if device.type == "cpu" else torch.bfloat16
    dtypes = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}
    if name not in dtypes:
        raise UserError(f"hf dtype {name!r} is not one of {', '.join(dtypes)}")
    return dtypes[name]
