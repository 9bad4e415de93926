"""`--choice guided` for the hf backend: greedy (or sampled) decoding held to the options'
token trie.

Each option is encoded as the prompt's continuation (`HFModel._encode`), and the options'
token sequences make one trie. At every generated position a row may take only the tokens that
continue its path through the trie, and an end-of-turn token only where its path spells a whole
option; every other token's logit is set to minus infinity before the model's own choice among
the rest. The answer is therefore always an option, chosen by the model's own distribution over
the options' tokens (never ranked or picked for it), unless `max_tokens` cuts it short: then it
is the option's first tokens, and the agent reads it as the invalid answer it is.

An llguidance grammar of the same options (as `--structured-output` uses, `structured.py`) is
exact too, but slower per answer on a CPU (`benchmarks/bench_structured.py`), so options keep
the trie.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch

_END = -1
"""The trie key that marks a whole option."""
#: Distinct option lists whose tries a backend keeps at once (a run asks under one or a few;
#: the skills catalogue's grammar has thousands of options on Medium, encoded once).
MAX_KEPT_TRIES = 8


class OptionTrie:
    """The options' token sequences as a trie of nested dicts."""

    def __init__(self, sequences: Iterable[Sequence[int]]):
        self.root: dict[int, dict] = {}
        for ids in sequences:
            node = self.root
            for token in ids:
                node = node.setdefault(int(token), {})
            node[_END] = {}

    def node(self, prefix: Sequence[int]) -> dict[int, dict] | None:
        """The trie node `prefix` leads to; None where it leaves the trie."""
        node = self.root
        for token in prefix:
            child = node.get(int(token))
            if child is None:
                return None
            node = child
        return node


class TrieLogitsProcessor:
    """A transformers logits processor holding every row of a batch to `trie`; a row that has
    ended (an end token) is left alone, as generation pads it from then on.

    The prompt's length is read from the first call (its `input_ids` are the prompts alone), so
    one processor serves one `generate` call."""

    def __init__(self, trie: OptionTrie, end_ids: Iterable[int]):
        self.trie = trie
        self.end_ids = sorted(set(end_ids))
        self._start: int | None = None

    def __call__(self, input_ids: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
        if self._start is None:
            self._start = input_ids.shape[1]
        banned = torch.full_like(scores, float("-inf"))
        ends = set(self.end_ids)
        for row, tokens in enumerate(input_ids[:, self._start :].tolist()):
            if any(token in ends for token in tokens):
                banned[row] = 0.0
                continue
            node = self.trie.node(tokens)
            allowed = [token for token in node or {} if token != _END]
            if node is not None and _END in node:
                allowed += self.end_ids
            if not allowed:
                # Off the trie (cannot happen under this processor): end the answer there.
                allowed = self.end_ids
            banned[row, allowed] = 0.0
        return scores + banned
