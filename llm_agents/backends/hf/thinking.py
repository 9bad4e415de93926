"""A reasoning model's thinking budget: the closing tag forced once a row has thought long
enough."""

from __future__ import annotations

import torch
from transformers import LogitsProcessor


class ThinkingBudgetLogitsProcessor(LogitsProcessor):
    """Forces the thinking block closed once a row has thought for `budget` tokens.

    A row thinks from its opening tag (or from the start, when the prompt opened the block)
    until its closing tag; at the budget the closing tag's tokens are forced one by one.
    """

    def __init__(
        self,
        *,
        prompt_len: int,
        budget: int,
        open_ids: list[int],
        close_ids: list[int],
        opened_in_prompt: list[bool],
    ):
        self.prompt_len = prompt_len
        self.budget = budget
        self.open_ids = open_ids
        self.close_ids = close_ids
        self.opened_in_prompt = opened_in_prompt

    def __call__(self, input_ids: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
        for row, tokens in enumerate(input_ids[:, self.prompt_len :].tolist()):
            forced = self._forced_token(tokens, self.opened_in_prompt[row])
            if forced is not None:
                scores[row] = torch.finfo(scores.dtype).min
                scores[row, forced] = 0.0
        return scores

    def _forced_token(self, tokens: list[int], opened_in_prompt: bool) -> int | None:
        think_start = 0 if opened_in_prompt else find_subsequence(tokens, self.open_ids)
        if think_start is None:
            return None
        if not opened_in_prompt:
            think_start += len(self.open_ids)
        if find_subsequence(tokens[think_start:], self.close_ids) is not None:
            return None
        thought = tokens[think_start:]
        if len(thought) < self.budget:
            return None
        # Continue a closing tag already begun (forced or not).
        for done in range(len(self.close_ids) - 1, 0, -1):
            if thought[-done:] == self.close_ids[:done]:
                return self.close_ids[done]
        return self.close_ids[0]


def find_subsequence(tokens: list[int], pattern: list[int]) -> int | None:
    size = len(pattern)
    for start in range(len(tokens) - size + 1):
        if tokens[start : start + size] == pattern:
            return start
    return None
