"""Free generation after the prompt: prompts computed in groups, then every row decoded
together, each row leaving the batch as soon as it ends.

transformers' `generate` keeps a finished row in its batch until the last row ends, and on a
CPU a batch's padding costs as much as real tokens: there a wider batch did not pay
(`benchmarks/bench_rows_per_forward.py`). Yet a decoding step reads all the weights for one
token per row, so its cost barely grows with the rows (Qwen2.5-Coder-0.5B, float32, one
thread: 123 ms for 1 row, 569 ms for 16). So prompts are computed in groups of
`prefill_rows` (`prefill`: one row each on a CPU, where padding costs as much as a token),
their caches are laid side by side (`merge`), and every row is decoded in one batch from which
a finished row is dropped (`decode`).

The scores go through the logits processors transformers' `generate` builds from the model's
generation config and the call's settings (temperature, top-p, repetition penalty, ...), then
the caller's; each is called with every row's tokens (finished rows padded), so a row's index
never changes under a processor that keeps per-row state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, cast

import torch
import torch.nn.functional as F
from transformers import DynamicCache, LogitsProcessorList

from llm_agents.backends.hf.prefix import CACHE_FIELD, PreparedBatch


@dataclass
class Prefilled:
    """Prompts computed: their layout, the cache holding them and the logits after each."""

    input_ids: torch.Tensor
    """(rows, width): each row's prompt, left-padded so all end in the last column (a kept
    prefix, then padding, then the rest, as `prepare_batch` lays them out)."""
    attention_mask: torch.Tensor
    cache: Any
    logits: torch.Tensor
    """(rows, vocabulary) float32: the scores of each answer's first token."""


def prefill(model: Any, batch: PreparedBatch) -> Prefilled:
    """Compute what `batch` does not take from its kept prefixes, in one forward pass."""
    cache = batch.cache if batch.cache is not None else DynamicCache(config=model.config)
    # Positions count real tokens only, as `generate` derives them from the mask.
    positions = (batch.attention_mask.cumsum(-1) - 1).clamp(min=0)
    width = batch.prefix_width
    with torch.inference_mode():
        out = model(
            input_ids=batch.input_ids[:, width:],
            attention_mask=batch.attention_mask,
            position_ids=positions[:, width:],
            **{CACHE_FIELD: cache},
            use_cache=True,
            logits_to_keep=1,
        )
    return Prefilled(
        batch.input_ids, batch.attention_mask, cache, out.logits[:, -1].to(torch.float32)
    )


def merge(groups: Sequence[Prefilled], model: Any, pad_id: int) -> Prefilled:
    """The groups as one batch: each left-padded to the widest (padding masked out)."""
    if len(groups) == 1:
        return groups[0]
    width = max(group.input_ids.shape[1] for group in groups)

    def left_pad(tensor: torch.Tensor, dim: int, value: int | float) -> torch.Tensor:
        missing = width - tensor.shape[dim]
        if not missing:
            return tensor
        shape = list(tensor.shape)
        shape[dim] = missing
        return torch.cat([tensor.new_full(shape, value), tensor], dim)

    cache = DynamicCache(config=model.config)
    for index in range(len(groups[0].cache.layers)):
        layers = [group.cache.layers[index] for group in groups]
        keys = torch.cat([left_pad(layer.keys, 2, 0.0) for layer in layers])
        values = torch.cat([left_pad(layer.values, 2, 0.0) for layer in layers])
        cache.update(keys, values, index)
    return Prefilled(
        input_ids=torch.cat([left_pad(group.input_ids, 1, pad_id) for group in groups]),
        attention_mask=torch.cat([left_pad(group.attention_mask, 1, 0) for group in groups]),
        cache=cache,
        logits=torch.cat([group.logits for group in groups]),
    )


def decode(
    model: Any,
    start: Prefilled,
    *,
    max_new: int,
    processors: LogitsProcessorList,
    sample: bool,
    ends: set[int],
    pad_id: int,
    stopped: Callable[[list[int]], bool] | None = None,
) -> list[list[int]]:
    """Each row's answer tokens (its end token included where it ended), decoded from
    `start` until an end token, `stopped` or `max_new` tokens."""
    rows = start.input_ids.shape[0]
    device = start.input_ids.device
    answers: list[list[int]] = [[] for _ in range(rows)]
    active = torch.arange(rows, device=device)  # rows still decoding, in the cache's order
    mask, logits, cache = start.attention_mask, start.logits, start.cache
    positions = mask.sum(-1)
    # Every row's tokens so far, finished rows padded: a processor sees the whole batch.
    sequences = start.input_ids
    for _ in range(max_new):
        scores = logits
        if processors:
            full = logits.new_zeros((rows, logits.shape[1]))
            full[active] = logits
            scores = processors(cast(torch.LongTensor, sequences), full)[active]
        if sample:
            chosen = torch.multinomial(F.softmax(scores, dim=-1), num_samples=1).squeeze(1)
        else:
            chosen = torch.argmax(scores, dim=-1)
        if processors:
            column = sequences.new_full((rows, 1), pad_id)
            column[active, 0] = chosen
            sequences = torch.cat([sequences, column], 1)
        going = []
        for place, (row, token) in enumerate(zip(active.tolist(), chosen.tolist(), strict=True)):
            answer = answers[row]
            answer.append(token)
            if token in ends or len(answer) >= max_new or (stopped and stopped(answer)):
                continue
            going.append(place)
        if not going:
            break
        if len(going) < len(active):
            kept = torch.tensor(going, device=device)
            for layer in cache.layers:
                layer.batch_select_indices(kept)
            active, chosen, mask, positions = (
                active[kept],
                chosen[kept],
                mask[kept],
                positions[kept],
            )
        mask = torch.cat([mask, mask.new_ones((len(going), 1))], 1)
        with torch.inference_mode():
            out = model(
                input_ids=chosen[:, None],
                attention_mask=mask,
                position_ids=positions[:, None],
                **{CACHE_FIELD: cache},
                use_cache=True,
            )
        positions = positions + 1
        logits = out.logits[:, -1].to(torch.float32)
    return answers


def generation_processors(
    model: Any, settings: dict[str, Any], ours: Sequence[Any], prompt_width: int
) -> tuple[LogitsProcessorList, bool]:
    """The processors `generate` would apply under `settings` (its keyword arguments), ours
    included, and whether it would sample."""
    config, model_kwargs = model._prepare_generation_config(None, **settings)
    processors = model._get_logits_processor(
        generation_config=config,
        input_ids_seq_length=prompt_width,
        logits_processor=LogitsProcessorList(ours),
        device=model.device,
        model_kwargs=model_kwargs,
    )
    return processors, bool(config.do_sample)
