"""The `loglik` choice-scoring engine: a prompt's keys and values computed once and shared,
every candidate scored in one pass through a block-diagonal (split) attention over them, the
candidates' shared tokens held in a trie."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from transformers.modeling_utils import AttentionInterface

SPLIT_ATTENTION_MODELS = frozenset({"llama", "mistral", "qwen2", "qwen3"})
SPLIT_ATTENTION = "craftext_split_prefix"
#: Distinct system messages whose tokens are kept at once (an agent run has one or a few).
MAX_KEPT_HEADS = 16
#: Whether split attention on CPU uses torch's CPU flash kernel; off, it runs the matrix-product
#: code that other devices run (tests use this to check that code's arithmetic on CPU).
CPU_FLASH_KERNEL = True


def _supports_split_attention(config: Any) -> bool:
    if config.model_type not in SPLIT_ATTENTION_MODELS:
        return False
    window = getattr(config, "sliding_window", None)
    return not (window and getattr(config, "use_sliding_window", True))


class _SharedPrefixAttention:
    """What choice mode's attention sees in one forward pass besides the new tokens.

    `prefix`: per layer, keys and values of a prefix shared by the whole batch (batch 1), seen
    by every new token. `past`: per layer, the batch's own earlier keys and values, seen as
    `mask` says. `mask` (batch, new, past + new): which own keys each new token sees; None
    means causal over the new tokens (and no `past`). `store` keeps the new keys and values.
    """

    def __init__(
        self,
        prefix: list[tuple[torch.Tensor, torch.Tensor]] | None,
        *,
        past: dict[int, tuple[torch.Tensor, torch.Tensor]] | None = None,
        mask: torch.Tensor | None = None,
        store: bool = False,
    ):
        self.prefix = prefix
        self.past = past
        self.mask = mask
        self.store = store
        self.stored: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}


def _split_attention_forward(
    module: torch.nn.Module,
    query: torch.Tensor,
    key: torch.Tensor,
    value: torch.Tensor,
    attention_mask: torch.Tensor | None,
    dropout: float = 0.0,
    scaling: float | None = None,
    split_attention: _SharedPrefixAttention | None = None,
    **kwargs: Any,
) -> tuple[torch.Tensor, None]:
    """Attention over a shared prefix and the tokens' own keys, merged exactly (fp rounding).

    Everything between the projections runs in float32 and is rounded to the model's dtype
    once, at the end: merging two half-precision softmax parts by their (rounded) log-sum-exp
    is off by whole nats after a few dozen layers.
    """
    plan = split_attention
    if plan is None:
        raise RuntimeError("split attention runs only inside the hf backend's choice mode")
    layer = int(getattr(module, "layer_idx", 0))
    scale = scaling if scaling is not None else query.shape[-1] ** -0.5
    if plan.store:
        plan.stored[layer] = (key, value)
    if plan.past is not None and plan.mask is not None:
        past_keys, past_values = plan.past[layer]
        keys, values = torch.cat([past_keys, key], 2), torch.cat([past_values, value], 2)
        out, lse = _attend(query, keys, values, scale, mask=plan.mask)
    else:
        out, lse = _attend(query, key, value, scale, causal=True)
    if plan.prefix is not None:
        prefix_keys, prefix_values = plan.prefix[layer]
        prefix_out, prefix_lse = _attend(query, prefix_keys, prefix_values, scale)
        total = torch.logaddexp(lse, prefix_lse)
        out = (
            out * (lse - total).exp()[..., None]
            + prefix_out * (prefix_lse - total).exp()[..., None]
        )
    return out.to(query.dtype).transpose(1, 2).contiguous(), None


def _attend(
    query: torch.Tensor,
    keys: torch.Tensor,
    values: torch.Tensor,
    scale: float,
    *,
    causal: bool = False,
    mask: torch.Tensor | None = None,
    fused: bool | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Softmax attention and its log-sum-exp: (batch, heads, new, dim), (batch, heads, new).

    Computed and returned in float32 whatever the inputs' dtype. `keys` may have fewer heads
    (grouped queries) and batch 1 (shared by the batch). `mask` (batch, new, keys) marks
    visible keys; `causal`: the keys are the new tokens' own, in order. `fused`: use the CPU
    flash kernel where it applies (default: on CPU).
    """
    query, keys, values = query.float(), keys.float(), values.float()
    batch, heads, length, dim = query.shape
    kv_batch, kv_heads, kv_length, _ = keys.shape
    groups = heads // kv_heads
    cpu = (query.device.type == "cpu" and CPU_FLASH_KERNEL) if fused is None else fused
    if mask is None and not causal:
        # Every query sees every key: fold the query groups (and a shared batch) into rows.
        rows = query.reshape(batch, kv_heads, groups * length, dim)
        if kv_batch == 1 and batch > 1:
            rows = rows.transpose(0, 1).reshape(1, kv_heads, batch * groups * length, dim)
        if cpu:
            out, lse = torch.ops.aten._scaled_dot_product_flash_attention_for_cpu(
                rows, keys, values, 0.0, False, scale=scale
            )
        else:
            scores = (rows @ keys.transpose(-1, -2)) * scale
            lse = scores.logsumexp(-1)
            out = (scores - lse[..., None]).exp() @ values
        if kv_batch == 1 and batch > 1:
            out = out.reshape(kv_heads, batch, groups * length, dim).transpose(0, 1)
            lse = lse.reshape(kv_heads, batch, groups * length).transpose(0, 1)
        return out.reshape(batch, heads, length, dim), lse.reshape(batch, heads, length)
    if causal and cpu:
        out, lse = torch.ops.aten._scaled_dot_product_flash_attention_for_cpu(
            query,
            keys.repeat_interleave(groups, 1),
            values.repeat_interleave(groups, 1),
            0.0,
            True,
            scale=scale,
        )
        return out, lse
    if mask is None:
        mask = torch.ones(length, kv_length, dtype=torch.bool, device=query.device).tril()[None]
    grouped = query.reshape(batch, kv_heads, groups, length, dim)
    scores = (grouped @ keys[:, :, None].transpose(-1, -2)) * scale
    scores = scores.masked_fill(~mask[:, None, None], float("-inf"))
    lse = scores.logsumexp(-1)
    out = (scores - lse[..., None]).exp() @ values[:, :, None]
    return out.reshape(batch, heads, length, dim), lse.reshape(batch, heads, length)


AttentionInterface.register(SPLIT_ATTENTION, _split_attention_forward)


def _trie_and_pairs(
    candidates: list[list[int]],
) -> tuple[CandidateTrie, list[tuple[int, int, int]]]:
    """The candidates' token trie, and for every candidate token after the first the triple
    (candidate, trie node whose logits predict it, token id)."""
    trie = CandidateTrie(candidates)
    pairs = [
        (k, path[j - 1], candidates[k][j])
        for k, path in enumerate(trie.paths)
        for j in range(1, len(path))
    ]
    return trie, pairs


class CandidateTrie:
    """Candidates' token sequences merged on common prefixes, parents before children."""

    def __init__(self, candidates: list[list[int]]):
        self.tokens: list[int] = []
        """Token of each node."""
        self.parents: list[int] = []
        """Parent node of each node; -1 for a candidate's first token."""
        self.depths: list[int] = []
        """Index of each node's token within its candidates."""
        self.paths: list[list[int]] = []
        """Node of every token of every candidate."""
        nodes: dict[tuple[int, int], int] = {}
        for ids in candidates:
            parent = -1
            path: list[int] = []
            for token in ids:
                node = nodes.get((parent, token))
                if node is None:
                    node = nodes[parent, token] = len(self.tokens)
                    self.tokens.append(token)
                    self.parents.append(parent)
                    self.depths.append(len(path))
                path.append(node)
                parent = node
            self.paths.append(path)

    def ancestry(self) -> list[list[int]]:
        """For each node: itself and its ancestors, the tokens it attends to."""
        seen: list[list[int]] = []
        for node, parent in enumerate(self.parents):
            seen.append([node, *(seen[parent] if parent >= 0 else [])])
        return seen


def _common_prefix_length(sequences: Sequence[np.ndarray], keep_own: int = 1) -> int:
    """Tokens all sequences start with, leaving each at least `keep_own` tokens of its own."""
    limit = min(len(sequence) for sequence in sequences) - keep_own
    if limit <= 0:
        return 0
    first = sequences[0]
    for sequence in sequences[1:]:
        differ = np.flatnonzero(sequence[:limit] != first[:limit])
        if differ.size:
            limit = int(differ[0])
    return limit


def _padded(rows: Sequence[np.ndarray], pad: int, *, left: bool) -> tuple[np.ndarray, np.ndarray]:
    """`rows` as one (rows, longest) id matrix padded with `pad`, and its mask of real tokens."""
    width = max(len(row) for row in rows)
    ids = np.full((len(rows), width), pad, dtype=np.int64)
    mask = np.zeros((len(rows), width), dtype=np.int64)
    for index, row in enumerate(rows):
        begin = width - len(row) if left else 0
        ids[index, begin : begin + len(row)] = row
        mask[index, begin : begin + len(row)] = 1
    return ids, mask


def _to_torch(array: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).to(device)
