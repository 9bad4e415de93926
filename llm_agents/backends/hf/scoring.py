"""The `loglik` choice-scoring engine: a prompt's keys and values computed once and shared,
every candidate scored in one pass through a block-diagonal (split) attention over them, the
candidates' shared tokens held in a trie.

Two paths compute the same scores. The split path (`SPLIT_ATTENTION_MODELS`) keeps the prompts'
shared prefix once and runs its own attention (`_split_attention_forward`); the cache-copy path
works on any causal LM through transformers' own cache and masks, copying the prefix's keys and
values per prompt.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from transformers import DynamicCache
from transformers.cache_utils import DynamicLayer
from transformers.modeling_utils import AttentionInterface

#: Model types whose logits are the decoder's last hidden state times the output embeddings,
#: with every layer attending to all earlier tokens (no sliding window, no soft-capping).
SPLIT_ATTENTION_MODELS = frozenset({"llama", "mistral", "qwen2", "qwen3"})
SPLIT_ATTENTION = "craftext_split_prefix"
#: Whether split attention on CPU uses torch's CPU flash kernel; off, it runs the matrix-product
#: code that other devices run (tests use this to check that code's arithmetic on CPU).
CPU_FLASH_KERNEL = True


def supports_split_attention(config: Any) -> bool:
    """Whether the split path can run this model (see `SPLIT_ATTENTION_MODELS`)."""
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


#: Per layer, the keys and values of a batch-1 token prefix.
PrefixStates = list[tuple[torch.Tensor, torch.Tensor]]


class LoglikScorer:
    """Summed log-probability of candidate token sequences after prompts, for one causal LM.

    The prompts' common prefix (in an agent, the system prompt) is encoded once and shared by
    the batch, and kept for the next call, which starts from the part its prefix shares with it;
    then one pass over the rest of every prompt, one over the candidates' trie.
    """

    def __init__(self, pad_id: int, *, split_attention: bool):
        self.pad_id = pad_id
        #: Whether the split path runs (else the cache-copy path; the benchmarks compare them).
        self.split_attention = split_attention
        self._prefix_ids = np.zeros(0, dtype=np.int64)
        self._prefix_states: PrefixStates = []

    def forget_prefix(self) -> None:
        """Drop the kept prefix (its keys and values belong to the model that computed them)."""
        self._prefix_ids, self._prefix_states = np.zeros(0, dtype=np.int64), []

    def log_likelihoods(
        self,
        model: Any,
        token_ids: Sequence[np.ndarray | Sequence[int]],
        candidates: list[list[int]],
    ) -> list[list[float]]:
        """Summed log-probability of every candidate after every prompt (token ids)."""
        prompts = [np.asarray(ids, dtype=np.int64) for ids in token_ids]
        with torch.inference_mode():
            if self.split_attention:
                return self._split_log_likelihoods(model, prompts, candidates)
            return self._cached_log_likelihoods(model, prompts, candidates)

    def _kept_prefix(self, prefix: np.ndarray) -> tuple[int, PrefixStates]:
        """How many tokens `prefix` shares with the kept one, and their keys and values."""
        reuse = _common_prefix_length([self._prefix_ids, prefix], keep_own=0)
        return reuse, [
            (keys[:, :, :reuse], values[:, :, :reuse]) for keys, values in self._prefix_states
        ]

    # -- the cache-copy path ------------------------------------------------------------------

    def _cached_log_likelihoods(
        self, model: Any, prompts: list[np.ndarray], candidates: list[list[int]]
    ) -> list[list[float]]:
        device = model.device
        batch = len(prompts)
        # Every prompt keeps at least one own token: its last one predicts the first candidate
        # token.
        shared = _common_prefix_length(prompts)
        cache = None
        if shared:
            cache = self._prefix_cache(model, prompts[0][:shared])
            cache.batch_repeat_interleave(batch)
        # Left padding (after the shared prefix) puts every prompt's last token in one column.
        padded_ids, padded_mask = padded([p[shared:] for p in prompts], self.pad_id, left=True)
        rest_ids, rest_mask = to_torch(padded_ids, device), to_torch(padded_mask, device)
        prompt_mask = torch.cat(
            [torch.ones(batch, shared, dtype=rest_mask.dtype, device=device), rest_mask], dim=-1
        )
        first = model(
            input_ids=rest_ids,
            attention_mask=prompt_mask,
            position_ids=shared + (rest_mask.cumsum(-1) - 1).clamp(min=0),
            past_key_values=cache,
            use_cache=True,
            logits_to_keep=1,
        )
        return _summed_scores(
            first.logits[:, -1].float().log_softmax(-1),
            candidates,
            lambda trie, fed: _candidate_pass(model, first.past_key_values, prompt_mask, trie, fed),
        )

    def _prefix_cache(self, model: Any, prefix: np.ndarray) -> Any:
        """A batch-1 cache of `prefix`, starting from the kept prefix where they agree."""
        reuse, kept = self._kept_prefix(prefix)
        cache = DynamicCache(config=model.config)
        if reuse:
            for index, (keys, values) in enumerate(kept):
                cache.update(keys, values, index)
        if reuse < len(prefix):
            model(
                input_ids=to_torch(prefix[None, reuse:], model.device),
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

    # -- the split path -----------------------------------------------------------------------

    def _split_log_likelihoods(
        self, model: Any, prompts: list[np.ndarray], candidates: list[list[int]]
    ) -> list[list[float]]:
        """The scores without copying the shared prefix per prompt.

        The prefix's keys and values are kept once (batch 1) and every prompt's queries attend
        to them in one batched product; each prompt's own tokens (right-padded, so no row is
        masked out) and then the candidate trie attend to their own keys separately, and the
        two softmax parts are merged by their log-sum-exp. Only trie nodes with children are
        fed: a leaf's token is scored by its parent's logits.
        """
        device = model.device
        batch = len(prompts)
        shared = _common_prefix_length(prompts)
        prefix = self._split_prefix(model, prompts[0][:shared]) if shared else None
        padded_ids, padded_mask = padded([p[shared:] for p in prompts], self.pad_id, left=False)
        rest_ids = to_torch(padded_ids, device)
        lengths = to_torch(padded_mask.sum(1), device)
        width = rest_ids.shape[1]
        positions = shared + torch.arange(width, device=device)
        rest_plan = _SharedPrefixAttention(prefix, store=True)
        hidden = _hidden_states(model, rest_ids, positions.expand(batch, width), rest_plan)
        last = hidden[torch.arange(batch, device=device), lengths - 1]

        def trie_log_probs(trie: CandidateTrie, fed: list[int]) -> torch.Tensor:
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
            trie_hidden = _hidden_states(
                model, trie_ids, shared + lengths[:, None] + depths[None], trie_plan
            )
            return _log_probs(model, trie_hidden)

        return _summed_scores(_log_probs(model, last), candidates, trie_log_probs)

    def _split_prefix(self, model: Any, prefix: np.ndarray) -> PrefixStates:
        """Keys and values (batch 1, per layer) of `prefix`, starting from the kept prefix."""
        reuse, kept = self._kept_prefix(prefix)
        states = kept
        if reuse < len(prefix):
            plan = _SharedPrefixAttention(kept if reuse else None, store=True)
            ids = to_torch(prefix[None, reuse:], model.device)
            positions = torch.arange(reuse, len(prefix), device=model.device)[None]
            _hidden_states(model, ids, positions, plan)
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


def _summed_scores(
    first_log_probs: torch.Tensor,
    candidates: list[list[int]],
    later_log_probs: Callable[[CandidateTrie, list[int]], torch.Tensor],
) -> list[list[float]]:
    """Each candidate's summed log-probability after each prompt, the tail both paths share.

    `first_log_probs` (batch, vocab): at each prompt's last token, which predicts a candidate's
    first token. `later_log_probs(trie, fed)` (batch, len(fed), vocab): at the trie nodes `fed`,
    those with children (parents before children, so every ancestor is there too); the logits
    at a candidate's token j predict its token j + 1, and single-token candidates need none.
    """
    device = first_log_probs.device
    first_tokens = torch.tensor([ids[0] for ids in candidates], device=device)
    scores = first_log_probs[:, first_tokens]
    trie = CandidateTrie(candidates)
    # (candidate, trie node whose logits predict the token, token) for every token after a first.
    pairs = [
        (k, path[j - 1], candidates[k][j])
        for k, path in enumerate(trie.paths)
        for j in range(1, len(path))
    ]
    if pairs:
        fed = sorted({node for _, node, _ in pairs})
        row_of = {node: row for row, node in enumerate(fed)}
        later = later_log_probs(trie, fed)
        rows = torch.tensor([row_of[node] for _, node, _ in pairs], device=device)
        targets = torch.tensor([token for _, _, token in pairs], device=device)
        owners = torch.tensor([k for k, _, _ in pairs], device=device)
        scores = scores.index_add(1, owners, later[:, rows, targets])
    return [[float(score) for score in row] for row in scores]


def _candidate_pass(
    model: Any,
    prompt_cache: Any,
    prompt_mask: torch.Tensor,
    trie: CandidateTrie,
    predicting: list[int],
) -> torch.Tensor:
    """Log-probabilities at the `predicting` nodes of the candidate trie, in one pass.

    A trie node sees the (unpadded) prompt and its own ancestors only, so one pass over the
    prompt cache scores every candidate, and a prefix shared by candidates is computed once.
    """
    device = model.device
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
    dtype = model.dtype
    mask = torch.zeros(allowed.shape, dtype=dtype, device=device)
    mask.masked_fill_(~allowed, torch.finfo(dtype).min)
    depths = torch.tensor(trie.depths, device=device)
    output = model(
        input_ids=torch.tensor([trie.tokens] * batch, device=device),
        attention_mask=mask[:, None],
        position_ids=prompt_mask.sum(-1, keepdim=True) + depths[None],
        past_key_values=prompt_cache,
        use_cache=True,
        logits_to_keep=torch.tensor(predicting, device=device),
    )
    log_probs: torch.Tensor = output.logits.float().log_softmax(-1)
    return log_probs


def _hidden_states(
    model: Any, ids: torch.Tensor, positions: torch.Tensor, plan: _SharedPrefixAttention
) -> torch.Tensor:
    """The decoder's final hidden states, attending as `plan` says."""
    config = model.config
    default = config._attn_implementation
    config._attn_implementation = SPLIT_ATTENTION
    try:
        output = model.get_decoder()(
            input_ids=ids, position_ids=positions, use_cache=False, split_attention=plan
        )
    finally:
        config._attn_implementation = default
    hidden: torch.Tensor = output.last_hidden_state
    return hidden


def _log_probs(model: Any, hidden: torch.Tensor) -> torch.Tensor:
    log_probs: torch.Tensor = model.get_output_embeddings()(hidden).float().log_softmax(-1)
    return log_probs


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


def padded(rows: Sequence[np.ndarray], pad: int, *, left: bool) -> tuple[np.ndarray, np.ndarray]:
    """`rows` as one (rows, longest) id matrix padded with `pad`, and its mask of real tokens."""
    width = max(len(row) for row in rows)
    ids = np.full((len(rows), width), pad, dtype=np.int64)
    mask = np.zeros((len(rows), width), dtype=np.int64)
    for index, row in enumerate(rows):
        begin = width - len(row) if left else 0
        ids[index, begin : begin + len(row)] = row
        mask[index, begin : begin + len(row)] = 1
    return ids, mask


def to_torch(array: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).to(device)
