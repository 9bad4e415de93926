"""Prefix reuse for free generation: the keys and values of prompt prefixes computed once and
kept, so a batch computes only what its prompts do not share with earlier ones.

An agent's prompts are mostly the same text: the system prompt (every step of every episode),
then the instruction (every step of one episode). `PrefixStore` keeps, by token prefix, the
keys and values of recent prompts (least recently used first out, within a token budget);
each new prompt starts from the longest kept token prefix it begins with. Prefixes are matched
on the prompts' token ids, already encoded whole (`HFModel._encode_prompts`), so a split never
falls inside a word's tokens: the keys and values of a token prefix depend on those tokens
alone (causal attention), whatever follows them.

A batch (`prepare_batch`) first computes its prompts' common prefix once where no kept prefix
covers it (the system prompt, once per run), then lays every row out as its reused prefix,
padding, then its own tokens, left-padded so all rows end in one column: the padding is masked
out and the positions count real tokens only (derived from the mask), so every row computes
what it would alone. Once the prompts are computed, each row's keys and values are kept
(`keep_prompts`): the next step of that episode reuses them through its instruction.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from transformers import DynamicCache
from transformers.cache_utils import DynamicLayer

from llm_agents.backends.hf.scoring import padded, to_torch

#: Per layer, keys and values (1, kv_heads, tokens, head_dim) of one token prefix.
LayerStates = list[tuple[torch.Tensor, torch.Tensor]]


def _cache_field() -> str:
    """The name a model's key-value cache goes by, as an argument of `forward` and `generate`
    and a field of generation's output: transformers renamed `past_key_values`
    to `cache` (5.2x); a GPU image may carry an older release."""
    from transformers.generation.utils import GenerateDecoderOnlyOutput

    fields = getattr(GenerateDecoderOnlyOutput, "__dataclass_fields__", {})
    return "cache" if "cache" in fields else "past_key_values"


CACHE_FIELD = _cache_field()


def common_length(first: np.ndarray, second: np.ndarray) -> int:
    """How many tokens the two id arrays start with in common."""
    limit = min(len(first), len(second))
    differ = np.flatnonzero(first[:limit] != second[:limit])
    return int(differ[0]) if differ.size else limit


@dataclass
class KeptPrefix:
    """A token prefix and its keys and values."""

    ids: np.ndarray
    states: LayerStates


class PrefixStore:
    """Keys and values of recent prompts, by token prefix, at most `budget_tokens` tokens in
    all (least recently used dropped first); a budget of 0 keeps nothing."""

    def __init__(self, budget_tokens: int):
        self.budget_tokens = budget_tokens
        self._kept: OrderedDict[bytes, KeptPrefix] = OrderedDict()
        self._tokens = 0

    @property
    def tokens(self) -> int:
        """Tokens kept now, over every prefix."""
        return self._tokens

    def __len__(self) -> int:
        return len(self._kept)

    def copy(self) -> PrefixStore:
        """Another store holding the same prefixes (their tensors shared, never written)."""
        other = PrefixStore(self.budget_tokens)
        other._kept = OrderedDict(self._kept)
        other._tokens = self._tokens
        return other

    def forget(self) -> None:
        """Drop everything (the keys and values belong to the model that computed them)."""
        self._kept.clear()
        self._tokens = 0

    def longest(self, prompt: np.ndarray) -> tuple[int, KeptPrefix | None]:
        """The kept prefix sharing most tokens with `prompt`, and how many it shares, leaving
        the prompt at least its last token to compute (its logits start the answer)."""
        limit = len(prompt) - 1
        best_length, best_key = 0, None
        for key, kept in self._kept.items():
            length = min(common_length(kept.ids, prompt), limit)
            if length > best_length:
                best_length, best_key = length, key
        if best_key is None:
            return 0, None
        self._kept.move_to_end(best_key)
        return best_length, self._kept[best_key]

    def keep(self, ids: np.ndarray, states: LayerStates) -> None:
        """Keep `states`, the keys and values of `ids`, unless a kept prefix already starts
        with all of `ids`."""
        if not self.budget_tokens or len(ids) > self.budget_tokens or not len(ids):
            return
        key = ids.tobytes()
        if key in self._kept or any(
            len(kept.ids) >= len(ids) and common_length(kept.ids, ids) == len(ids)
            for kept in self._kept.values()
        ):
            return
        self._kept[key] = KeptPrefix(ids=ids, states=states)
        self._tokens += len(ids)
        while self._tokens > self.budget_tokens:
            _, dropped = self._kept.popitem(last=False)
            self._tokens -= len(dropped.ids)


@dataclass
class PreparedBatch:
    """A batch laid out over reused prefixes, for `decode.prefill`."""

    input_ids: torch.Tensor
    """(rows, width): each row's reused prefix (ids only for show: the cache holds it),
    padding, its own tokens; left-padded so every row's prompt ends in the last column."""
    attention_mask: torch.Tensor
    cache: Any
    """A `DynamicCache` holding the reused prefixes (`prefix_width` columns), or None."""
    prefix_width: int
    reused: list[int]
    """Each row's reused prompt tokens."""
    computed: list[int]
    """Each row's prompt tokens computed for this batch (the first row's count includes the
    batch's common prefix, computed once for all)."""


def prepare_batch(
    model: Any, store: PrefixStore, prompts: Sequence[np.ndarray], pad_id: int
) -> PreparedBatch:
    """`prompts` laid out for `decode.prefill`, each starting from the longest kept prefix it
    begins with; the batch's common prefix is computed (once) and kept first where no kept
    prefix covers it."""
    device = model.device
    shared_computed = 0
    if len(prompts) > 1:
        shared_computed = _keep_common_prefix(model, store, prompts)
    found = [store.longest(prompt) for prompt in prompts]
    reused = [length for length, _ in found]
    width = max(reused, default=0)
    tails = [prompt[length:] for prompt, length in zip(prompts, reused, strict=True)]
    tail_ids, tail_mask = padded(tails, pad_id, left=True)
    cache = None
    if width:
        cache = _batched_cache(model, [kept for _, kept in found], reused, width)
    prefix_ids = np.full((len(prompts), width), pad_id, dtype=np.int64)
    prefix_mask = np.zeros((len(prompts), width), dtype=np.int64)
    for row, ((length, kept), prompt) in enumerate(zip(found, prompts, strict=True)):
        if kept is not None:
            prefix_ids[row, :length] = prompt[:length]
            prefix_mask[row, :length] = 1
    computed = [len(tail) for tail in tails]
    computed[0] += shared_computed
    return PreparedBatch(
        input_ids=to_torch(np.concatenate([prefix_ids, tail_ids], 1), device),
        attention_mask=to_torch(np.concatenate([prefix_mask, tail_mask], 1), device),
        cache=cache,
        prefix_width=width,
        reused=reused,
        computed=computed,
    )


def keep_prompts(
    store: PrefixStore, prompts: Sequence[np.ndarray], batch: PreparedBatch, cache: Any
) -> None:
    """Keep every row's prompt keys and values from `cache`, the cache `decode.prefill` filled
    (its columns are those `batch` laid out)."""
    if not store.budget_tokens or cache is None:
        return
    layers = _plain_layers(cache)
    if layers is None:
        return
    end = batch.input_ids.shape[1]
    device = batch.input_ids.device
    for row, (prompt, reused) in enumerate(zip(prompts, batch.reused, strict=True)):
        columns = torch.cat(
            [
                torch.arange(reused, device=device),
                torch.arange(end - (len(prompt) - reused), end, device=device),
            ]
        )
        store.keep(
            prompt,
            [
                (keys[row : row + 1, :, columns], values[row : row + 1, :, columns])
                for keys, values in layers
            ],
        )


def _keep_common_prefix(model: Any, store: PrefixStore, prompts: Sequence[np.ndarray]) -> int:
    """Compute and keep the prompts' common prefix where no kept prefix covers it; the tokens
    computed for it."""
    shared = min(
        [len(prompts[0]) - 1]
        + [common_length(prompts[0], prompt) for prompt in prompts[1:]]
        + [len(prompt) - 1 for prompt in prompts[1:]]
    )
    if shared <= 0 or not store.budget_tokens:
        return 0
    prefix = prompts[0][:shared]
    reused, kept = store.longest(prompts[0])
    reused = min(reused, shared)
    if reused == shared:
        return 0
    cache = DynamicCache(config=model.config)
    if kept is not None and reused:
        for index, (keys, values) in enumerate(kept.states):
            cache.update(keys[:, :, :reused], values[:, :, :reused], index)
    with torch.inference_mode():
        model(
            input_ids=to_torch(prefix[None, reused:], model.device),
            **{CACHE_FIELD: cache},
            use_cache=True,
            logits_to_keep=1,
        )
    layers = _plain_layers(cache)
    if layers is not None:
        store.keep(prefix, layers)
    return shared - reused


def _batched_cache(
    model: Any, kept: list[KeptPrefix | None], lengths: list[int], width: int
) -> Any:
    """A cache of `width` columns, row i holding the first `lengths[i]` keys and values of
    `kept[i]` (then zeros, masked out)."""
    cache = DynamicCache(config=model.config)
    template = next(prefix for prefix in kept if prefix is not None).states
    rows = len(kept)
    for index, (keys, values) in enumerate(template):
        batch_keys = keys.new_zeros((rows, keys.shape[1], width, keys.shape[3]))
        batch_values = values.new_zeros((rows, values.shape[1], width, values.shape[3]))
        for row, (prefix, length) in enumerate(zip(kept, lengths, strict=True)):
            if prefix is not None and length:
                row_keys, row_values = prefix.states[index]
                batch_keys[row, :, :length] = row_keys[0, :, :length]
                batch_values[row, :, :length] = row_values[0, :, :length]
        cache.update(batch_keys, batch_values, index)
    return cache


def _plain_layers(cache: Any) -> LayerStates | None:
    """Per layer, the keys and values of a cache of plain per-token layers; None for another
    kind (sliding windows, ...), whose columns cannot be kept."""
    states = []
    for layer in cache.layers:
        if type(layer) is not DynamicLayer or layer.keys is None or layer.values is None:
            return None
        states.append((layer.keys, layer.values))
    return states


def supports_prefix_reuse(config: Any) -> bool:
    """Whether the model's cache is plain per-token layers (no sliding window)."""
    window = getattr(config, "sliding_window", None)
    if window and getattr(config, "use_sliding_window", True):
        return False
    layer_types = getattr(config, "layer_types", None) or []
    return all(kind == "full_attention" for kind in layer_types)
