"""The transformers backend: local models on CPU or GPU, no server.

Model names (`hf:<name>`): a named model (`smollm2-135m`, the embedded default,
`qwen2.5-coder-0.5b`, `qwen2.5-coder-1.5b`; see `embedded.py`) is fetched on first use; a path
loads any local model folder or GGUF file; any other name is a hub id (`ORG/NAME`, or
`ORG/NAME:FILE.gguf`), downloaded into the hub cache on first use at the `revision` option's
commit (`hub.py`). Transformers itself only ever reads local files.

Free generation renders each conversation with the model's chat template and decodes a batch at
once (left padding). `guided` choices decode the same way, held to the options' token trie
(`guided.py`; not for image-text models). `loglik` choices: every
candidate is scored by its log-likelihood after the prompt (`scoring.py`), with one prompt pass per batch: all
candidates then go through a single pass over the prompt's cached keys and values, side by side
in one sequence, each seeing only the prompt and its own earlier tokens (a block-diagonal
attention mask). Each candidate is scored with and without the chat template's end-of-turn
token after it (one trie: the two share their tokens), and `ranked_choices` makes the run's
`--choice-scoring` rule of them (`pmi` also scores the content-free prompt, once per run). A
rule that reads no end of turn (`sum`, `letters`: `base.needs_end`) scores the options alone,
and options of one token each (`letters`' labels) then cost no candidate pass at all: their
scores are the next-token distribution at the prompt's end. The answer is always one of the
choices.

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
from pydantic import ConfigDict, Field, ValidationError, field_validator
from transformers import AutoConfig, AutoModelForCausalLM, AutoTokenizer

from env.errors import UserError
from llm_agents.backends.base import (
    ANSWER_FIELDS,
    ChatMessage,
    ChoiceRule,
    ChoiceSet,
    ContentFreeScores,
    Conversation,
    FinishReason,
    GenerateConfig,
    ModelAPI,
    ModelOutput,
    OptionLoglik,
    OutputSchema,
    bad_options,
    content_free_conversation,
    end_of_turn_id,
    hub_info,
    locate_model,
    needs_end,
    ranked_choices,
    scored_choices,
)
from llm_agents.backends.embedded import NAMED_MODELS
from llm_agents.backends.hf import vision
from llm_agents.backends.hf.decode import decode, generation_processors, merge, prefill
from llm_agents.backends.hf.guided import MAX_KEPT_TRIES, OptionTrie, TrieLogitsProcessor
from llm_agents.backends.hf.prefix import (
    PrefixStore,
    keep_prompts,
    prepare_batch,
    supports_prefix_reuse,
)
from llm_agents.backends.hf.scoring import (
    LoglikScorer,
    supports_split_attention,
)
from llm_agents.backends.hf.structured import Grammars, SchemaLogitsProcessor
from llm_agents.backends.hf.thinking import ThinkingBudgetLogitsProcessor
from llm_agents.backends.hub import HubRevision
from llm_agents.backends.reasoning import (
    THINK_CLOSE,
    THINK_OPEN,
    resolve_truncated,
    with_reasoning_split,
)

DtypeName = Literal["float32", "bfloat16", "float16"]

logger = logging.getLogger(__name__)

#: Distinct system messages whose tokens are kept at once (an agent run has one or a few).
MAX_KEPT_HEADS = 16

#: Conversations per forward pass of `loglik` choices (one prompt pass shared by the batch).
CHOICE_ROWS_PER_FORWARD = 16
#: Conversations decoded together in free generation, by device type (others take cuda's),
#: and of them, prompts computed per forward pass (`decode.py`): measured by
#: benchmarks/bench_rows_per_forward.py (real zero-shot free-text Classic prompts, second step,
#: prefixes kept; float32, one torch thread; CPU seconds per request): Qwen2.5-Coder-0.5B, 16
#: requests of 256 computed and 13.5 answer tokens, rows x prompts per pass 1 x 1: 3.90 s,
#: 4 x 1: 3.34, 4 x 4: 3.55, 16 x 1: 2.78, 16 x 16: 3.43; Qwen2.5-Coder-1.5B 1 x 1: 12.08,
#: 16 x 1: 9.09 (2-core machine, load 3, 2026-11-27).
#: cuda: not measured (no lent GPU this stop); a whole batch per pass, as `generate` had it.
ROWS_PER_FORWARD = {"cpu": 16, "cuda": 16}
PREFILL_ROWS = {"cpu": 1, "cuda": 16}

#: Why `loglik` refuses a bfloat16 model, and what to use instead.
LOGLIK_BFLOAT16 = (
    "hf loglik choices cannot be scored in bfloat16: its rounding alone moves a score by most "
    "of a nat, so rankings would follow the rounding; set dtype=float32 (exact) or "
    "dtype=float16 (--backend-option dtype=float32), or leave dtype unset"
)


class HFOptions(HubRevision):
    """Options of the hf backend (keyword arguments of `get_model`)."""

    model_config = ConfigDict(extra="forbid")

    device: str | None = None
    """Torch device: cpu, cuda, cuda:1, ...; None: cuda when available, else cpu."""
    dtype: DtypeName | None = None
    """Weights' type; None: float32 on CPU, bfloat16 on GPU except float32 for `loglik` choices,
    which refuse bfloat16 (see the module docstring)."""
    threads: int | None = Field(None, ge=1)
    """Torch CPU threads; None: torch's own choice."""
    rows_per_forward: int | None = Field(None, ge=1)
    """Conversations per forward pass; None: `CHOICE_ROWS_PER_FORWARD` for choices, the
    device's `ROWS_PER_FORWARD` for free generation."""
    prefix_cache_tokens: int = Field(32768, ge=0)
    """Prompt tokens whose keys and values free generation keeps for later prompts that start
    the same way (`prefix.py`); 0 computes every prompt from its first token."""

    @field_validator("device")
    @classmethod
    def _known_device(cls, device: str | None) -> str | None:
        if device is not None:
            try:
                torch.device(device)
            except RuntimeError:
                raise ValueError(
                    f"{device!r} is not a torch device (cpu, cuda, cuda:1, ...)"
                ) from None
        return device


class ContextLengthError(ValueError):
    """A prompt longer than the model's context (`max_position_embeddings`)."""


#: How the allocators word running out of memory where they raise a plain RuntimeError (the
#: CPU's, cuBLAS's, Apple's MPS); CUDA's own is `torch.OutOfMemoryError`.
_OUT_OF_MEMORY = ("out of memory", "can't allocate memory", "CUBLAS_STATUS_ALLOC_FAILED")


def is_backend_failure(err: BaseException) -> bool:
    """Whether an error of a forward pass is the backend's failure (out of memory, or a prompt
    over the context length: the batch failed, the run goes on and retries it on resume)
    rather than a bug, which must surface."""
    if isinstance(err, ContextLengthError | torch.OutOfMemoryError):
        return True
    return isinstance(err, RuntimeError) and any(words in str(err) for words in _OUT_OF_MEMORY)


class HFModel(ModelAPI):
    """A transformers causal LM answering batches of chat conversations."""

    backend_name = "hf"
    options_model = HFOptions
    honoured_config = ANSWER_FIELDS
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"loglik", "guided"})
    # transformers' own annotations of its model classes do not type-check cleanly.
    _model: Any = None

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        super().__init__(model_name, config, **options)
        try:
            self.settings = HFOptions(**options)
        except ValidationError as err:
            raise bad_options("hf", err) from None
        if self.settings.threads is not None:
            torch.set_num_threads(self.settings.threads)
        default_device = "cuda" if torch.cuda.is_available() else "cpu"
        self.device = torch.device(self.settings.device or default_device)
        #: Conversations per forward pass of free generation.
        self.rows_per_forward = self.settings.rows_per_forward or ROWS_PER_FORWARD.get(
            self.device.type, ROWS_PER_FORWARD["cuda"]
        )
        #: Conversations per forward pass of `loglik` choices.
        self.choice_rows_per_forward = self.settings.rows_per_forward or CHOICE_ROWS_PER_FORWARD
        self.dtype = _torch_dtype(self.settings.dtype, self.device)
        self.dtype_given = self.settings.dtype is not None
        self.location = locate_model("hf", model_name, self.settings.revision)
        self.model_path = self.location.path
        # A GGUF file is read (and dequantized) by transformers from its folder.
        gguf = self.model_path.is_file()
        self._source = str(self.model_path.parent if gguf else self.model_path)
        self._files: dict[str, Any] = {"local_files_only": True}
        if gguf:
            self._files["gguf_file"] = self.model_path.name
        try:
            self.tokenizer = AutoTokenizer.from_pretrained(self._source, **self._files)
            model_config = AutoConfig.from_pretrained(self._source, **self._files)
        except OSError as err:
            raise _load_error(model_name, err) from err
        #: An image-text model (`vision.py`): every answer goes through its processor.
        self.processor: Any = None
        if vision.is_image_text(model_config):
            try:
                self.processor = vision.load_processor(self._source)
            except OSError as err:
                raise _load_error(model_name, err) from err
            self.tokenizer.chat_template = (
                self.tokenizer.chat_template or self.processor.chat_template
            )
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
        self.scorer = LoglikScorer(
            self.tokenizer.pad_token_id, split_attention=supports_split_attention(model_config)
        )
        plain_cache = supports_prefix_reuse(model_config)
        #: Of them, prompts computed per forward pass; a cache that is not plain per-token
        #: layers cannot be laid beside another (`decode.merge`), so its rows go in one.
        self.prefill_rows = (
            PREFILL_ROWS.get(self.device.type, PREFILL_ROWS["cuda"])
            if plain_cache
            else self.rows_per_forward
        )
        #: Keys and values of recent prompts' prefixes, for free generation (`prefix.py`).
        self.prefixes = PrefixStore(self.settings.prefix_cache_tokens if plain_cache else 0)
        self._end_of_turn = end_of_turn_id(self.tokenizer)
        self._content_free = ContentFreeScores()
        self._tries: dict[tuple[str, ...], OptionTrie] = {}
        self._grammars: Grammars | None = None
        # A longer prompt is a backend failure (`ContextLengthError`), read before the weights.
        positions = getattr(model_config, "max_position_embeddings", None)
        self.context_length: int | None = positions if isinstance(positions, int) else None

    @property
    def model(self) -> Any:
        """The transformers model in `self.dtype`, loaded on first use: the choice rule, known
        only after construction (`check_choice_rule`), may still change the default dtype."""
        if self._model is None:
            try:
                model: Any = (
                    vision.load_model(self._source, self.dtype)
                    if self.processor is not None
                    else AutoModelForCausalLM.from_pretrained(
                        self._source, dtype=self.dtype, **self._files
                    )
                )
            except OSError as err:
                raise _load_error(self.model_name, err) from err
            self._model = model.to(self.device).eval()
        return self._model

    def check_choice_rule(self, rule: ChoiceRule) -> None:
        """As `ModelAPI.check_choice_rule`; `loglik` also refuses a bfloat16 the user set and
        replaces a defaulted one by float32 (see the module docstring)."""
        super().check_choice_rule(rule)
        if rule == "guided" and self.processor is not None:
            raise UserError(
                f"hf model {self.model_name!r} is an image-text model, whose decoding the hf "
                "backend cannot constrain: --choice guided needs a text-only model here"
            )
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
            self.scorer.forget_prefix()
            self.prefixes.forget()
            if self.device.type == "cuda":
                torch.cuda.empty_cache()

    def check_images(self) -> None:
        if self.processor is None:
            raise UserError(
                f"hf model {self.model_name!r} is a text-only model (its config has no vision "
                "tower): it takes no images; use --observation text, or an image-text model"
            )

    def info(self) -> dict[str, str]:
        import transformers

        return {
            **super().info(),
            "model_path": str(self.model_path),
            **hub_info(self.location),
            "transformers": transformers.__version__,
            "torch": torch.__version__,
            "device": str(self.device),
            "dtype": str(self.dtype).removeprefix("torch."),
        }

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        if choices is not None and choices.rule == "guided":
            guided = choices
            return self._in_batches(
                conversations,
                lambda batch: self._generate_guided(batch, guided),
                self.rows_per_forward,
            )
        if choices is not None:
            candidates = self._candidate_ids(choices.options)
            return self._in_batches(
                conversations,
                lambda batch: self._choose(batch, choices, candidates),
                self.choice_rows_per_forward,
            )
        outputs = self._in_batches(conversations, self._generate_split, self.rows_per_forward)
        return resolve_truncated(
            conversations,
            outputs,
            lambda batch: self._in_batches(batch, self._generate_split, self.rows_per_forward),
        )

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        """Each answer decoded under `SchemaLogitsProcessor`: JSON that follows `schema`, or one
        cut short by `max_tokens`."""
        self.check_schema(schema)
        grammars = self._schema_grammars()

        def batch(rows: Sequence[Conversation]) -> list[ModelOutput]:
            guide = grammars.processor(schema, self._eos_ids())
            return self._generate_raw(self._prompt_ids(rows), [False] * len(rows), guide)

        return self._in_batches(conversations, batch, self.rows_per_forward)

    def check_schema(self, schema: OutputSchema) -> None:
        """llguidance installed, a text-only model, and a schema it compiles (`structured.py`)."""
        if self.processor is not None:
            raise UserError(
                f"hf model {self.model_name!r} is an image-text model, whose decoding the hf "
                "backend cannot constrain: --structured-output needs a text-only model here"
            )
        self._schema_grammars().grammar(schema)

    def _schema_grammars(self) -> Grammars:
        if self._grammars is None:
            self._grammars = Grammars(
                self.tokenizer, int(self.model.config.vocab_size), sorted(self._eos_ids())
            )
        return self._grammars

    def choice_scores(
        self, conversations: Sequence[Conversation], choices: ChoiceSet
    ) -> list[list[float]]:
        """Each option's score after each conversation's prompt, under `choices.scoring`."""
        self.check_choice_rule("loglik")
        prompts = self._prompt_ids(conversations)
        candidates = self._candidate_ids(choices.options)
        scores = self._option_logliks(prompts, candidates, with_end=needs_end(choices.scoring))
        return scored_choices(
            choices, candidates, scores, self._content_free_rows(conversations, choices, candidates)
        )

    # -- free generation ----------------------------------------------------------------------

    def _generate_split(self, conversations: Sequence[Conversation]) -> list[ModelOutput]:
        if self.processor is not None:
            return vision.generate(
                self.model, self.processor, conversations, self.config, self.device, self.dtype
            )
        texts = [self._render(conversation) for conversation in conversations]
        # Templates that open the thinking block themselves make the completion start inside it.
        opened = [text.rstrip().endswith(THINK_OPEN) for text in texts]
        raw = self._generate_raw(self._encode_prompts(conversations, texts), opened)
        return [
            with_reasoning_split(output, thinking_open_in_prompt=was_opened)
            for output, was_opened in zip(raw, opened, strict=True)
        ]

    def _generate_guided(
        self, conversations: Sequence[Conversation], choices: ChoiceSet
    ) -> list[ModelOutput]:
        """Each answer decoded under `TrieLogitsProcessor`: one of the options, or one cut short."""
        if choices.options not in self._tries:
            if len(self._tries) >= MAX_KEPT_TRIES:
                del self._tries[next(iter(self._tries))]
            self._tries[choices.options] = OptionTrie(self._candidate_ids(choices.options))
        guide = TrieLogitsProcessor(self._tries[choices.options], self._eos_ids())
        raw = self._generate_raw(
            self._prompt_ids(conversations), [False] * len(conversations), guide
        )
        return [
            output.model_copy(update={"finish_reason": "choice"})
            if output.text in choices.options
            else output
            for output in raw
        ]

    def _generate_raw(
        self,
        prompts: list[np.ndarray],
        opened: list[bool],
        guide: TrieLogitsProcessor | SchemaLogitsProcessor | None = None,
    ) -> list[ModelOutput]:
        config = self.config
        start = time.perf_counter()
        groups = []
        for begin in range(0, len(prompts), self.prefill_rows):
            rows = prompts[begin : begin + self.prefill_rows]
            batch = prepare_batch(self.model, self.prefixes, rows, self.tokenizer.pad_token_id)
            group = prefill(self.model, batch)
            keep_prompts(self.prefixes, rows, batch, group.cache)
            groups.append((group, batch.computed))
        computed_tokens = [count for _, counts in groups for count in counts]
        prefilled = merge([group for group, _ in groups], self.model, self.tokenizer.pad_token_id)
        prompt_width = prefilled.input_ids.shape[1]
        max_new = config.max_tokens
        processors: list[Any] = [guide] if guide is not None else []
        if config.reasoning_budget is not None and self._think_close_ids:
            # Thinking gets its own budget on top of the answer's max_tokens.
            max_new += config.reasoning_budget + len(self._think_close_ids)
            processors.append(
                ThinkingBudgetLogitsProcessor(
                    prompt_len=prompt_width,
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
        chain, sample = generation_processors(
            self.model,
            {**sampling, "max_new_tokens": max_new, "pad_token_id": self.tokenizer.pad_token_id},
            processors,
            prompt_width,
        )
        eos_ids = self._eos_ids()
        stops = config.stop

        def stopped(tokens: list[int]) -> bool:
            text = self.tokenizer.decode(tokens, skip_special_tokens=True)
            return any(stop in text for stop in stops)

        answers = decode(
            self.model,
            prefilled,
            max_new=max_new,
            processors=chain,
            sample=sample,
            ends=eos_ids,
            pad_id=self.tokenizer.pad_token_id,
            stopped=stopped if stops else None,
        )
        latency = time.perf_counter() - start
        outputs = []
        for tokens, prompt, computed in zip(answers, prompts, computed_tokens, strict=True):
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
                    computed_prompt_tokens=computed,
                    completion_tokens=len(tokens) + (ended is not None),
                    latency_s=latency,
                    finish_reason=finish,
                )
            )
        return outputs

    # -- choice mode --------------------------------------------------------------------------

    def _choose(
        self, conversations: Sequence[Conversation], choices: ChoiceSet, candidates: list[list[int]]
    ) -> list[ModelOutput]:
        start = time.perf_counter()
        prompts = self._prompt_ids(conversations)
        scores = self._option_logliks(prompts, candidates, with_end=needs_end(choices.scoring))
        content_free = self._content_free_rows(conversations, choices, candidates)
        return ranked_choices(
            choices, prompts, candidates, scores, time.perf_counter() - start, content_free
        )

    def _candidate_ids(self, options: Sequence[str]) -> list[list[int]]:
        candidates = [self._encode(option) for option in options]
        if empty := [option for option, ids in zip(options, candidates, strict=True) if not ids]:
            raise UserError(f"choices {empty!r} encode to no tokens; every choice needs text")
        return candidates

    def _option_logliks(
        self,
        prompts: Sequence[np.ndarray | Sequence[int]],
        candidates: list[list[int]],
        *,
        with_end: bool = True,
    ) -> list[list[OptionLoglik]]:
        """Each option's log-probability after each prompt, and its end of turn's after it:
        the options with and without the end token in one trie, which shares their tokens.
        Without the end (`with_end` False, its log-probability then 0), options of one token
        each (`letters`' labels) are all read off the prompt's last logits: one pass over the
        prompt, no candidate pass."""
        if not with_end:
            rows = self.scorer.log_likelihoods(self.model, prompts, candidates)
            return [[OptionLoglik(option=own, end=0.0) for own in row] for row in rows]
        ended = [[*ids, self._end_of_turn] for ids in candidates]
        rows = self.scorer.log_likelihoods(self.model, prompts, candidates + ended)
        width = len(candidates)
        return [
            [
                OptionLoglik(option=own, end=whole - own)
                for own, whole in zip(row[:width], row[width:], strict=True)
            ]
            for row in rows
        ]

    def _content_free_rows(
        self, conversations: Sequence[Conversation], choices: ChoiceSet, candidates: list[list[int]]
    ) -> list[list[OptionLoglik]] | None:
        if choices.scoring != "pmi":
            return None
        prompts = self._prompt_ids([content_free_conversation(c) for c in conversations])
        return self._content_free.rows(
            [list(prompt) for prompt in prompts],
            choices.options,
            lambda missing: self._option_logliks(missing, candidates),
        )

    # -- helpers ------------------------------------------------------------------------------

    def _in_batches(
        self,
        conversations: Sequence[Conversation],
        run: Callable[[Sequence[Conversation]], list[ModelOutput]],
        rows: int,
    ) -> list[ModelOutput]:
        outputs: list[ModelOutput] = []
        for begin in range(0, len(conversations), rows):
            batch = conversations[begin : begin + rows]
            try:
                outputs.extend(run(batch))
            except (RuntimeError, ValueError) as err:
                # Out of memory or a prompt over the context length fails this batch only, as
                # a backend failure; any other error is a bug, and raised.
                if not is_backend_failure(err):
                    raise
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
        """The token ids of each conversation's rendered `texts`, equal to encoding each whole
        (a `ContextLengthError` when one is longer than the model's context).

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
        prompts = [
            np.concatenate([head[1], np.asarray(ids, dtype=np.int64)])
            if head
            else np.asarray(ids, dtype=np.int64)
            for head, ids in zip(heads, encoded, strict=True)
        ]
        longest = max((len(prompt) for prompt in prompts), default=0)
        if self.context_length is not None and longest > self.context_length:
            raise ContextLengthError(
                f"a prompt of {longest} tokens is longer than the model's context "
                f"({self.context_length})"
            )
        return prompts

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


def _cut_at_stop(text: str, stops: list[str]) -> tuple[bool, str]:
    positions = [pos for stop in stops if (pos := text.find(stop)) != -1]
    if not positions:
        return False, text
    return True, text[: min(positions)]


def _load_error(model_name: str, err: OSError) -> UserError:
    names = ", ".join(f"hf:{name}" for name in NAMED_MODELS)
    return UserError(
        f"cannot load hf model {model_name!r}: {err}. Pass a local model folder "
        f"(hf:/path/to/model), a named model ({names}), or a hub id (hf:ORG/NAME)"
    )


def _torch_dtype(name: DtypeName | None, device: torch.device) -> torch.dtype:
    if name is None:
        return torch.float32 if device.type == "cpu" else torch.bfloat16
    dtype: torch.dtype = getattr(torch, name)
    return dtype
