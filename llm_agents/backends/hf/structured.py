"""Answers held to a JSON schema on the hf backend (`--structured-output`), through llguidance.

llguidance compiles the schema into a grammar over the model's tokenizer (`Grammars`, one
compiled grammar per schema for the backend's life); during decoding each row keeps its own
matcher, which consumes the row's tokens as they are chosen and fills the row's mask of the
tokens that keep the answer inside the grammar (`SchemaLogitsProcessor`). The end-of-turn token
is allowed only where the JSON so far is a whole answer, so an answer that ends is always JSON
that follows the schema; only `max_tokens` can cut one short, and the agent then reads the
invalid answer it is.

llguidance is imported here alone, with an install hint where it is missing.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import torch

from env.errors import UserError
from llm_agents.backends.base import OutputSchema

INSTALL_HINT = "pip install 'craftext-llm[hf]' (or pip install llguidance)"
#: JSON laid out as `json.dumps` writes it, the form the prompts' worked examples show: a model
#: free to put whitespace anywhere can spend its whole budget on newlines.
LAYOUT = {"whitespace_flexible": False, "item_separator": ", ", "key_separator": ": "}


def _llguidance() -> Any:
    try:
        import llguidance
        import llguidance.hf
        import llguidance.torch
    except ImportError:
        raise UserError(
            f"the hf backend holds answers to a JSON schema through llguidance, which is not "
            f"installed: {INSTALL_HINT}"
        ) from None
    return llguidance


class Grammars:
    """The tokenizer as llguidance reads it, and each schema's compiled grammar, kept."""

    def __init__(self, tokenizer: Any, vocab_size: int, end_ids: list[int]):
        self._llg = _llguidance()
        # The logits may be wider than the tokenizer's vocabulary (padded embeddings): the
        # masks are as wide as the logits, the tokens past the vocabulary never allowed.
        self.tokenizer = self._llg.hf.from_tokenizer(
            tokenizer, n_vocab=vocab_size, eos_token=end_ids
        )
        self._grammars: dict[str, str] = {}

    def grammar(self, schema: OutputSchema) -> str:
        """The schema's grammar; a `UserError` naming the backend where llguidance refuses it."""
        kept = self._grammars.get(schema.json_schema)
        if kept is not None:
            return kept
        llg = self._llg
        grammar: str = ""
        try:
            grammar = llg.LLMatcher.grammar_from_json_schema(schema.json_schema, defaults=LAYOUT)
            error = llg.LLMatcher.validate_grammar(grammar, self.tokenizer)
        except (ValueError, RuntimeError) as err:
            error = str(err)
        if error:
            raise UserError(
                f"the hf backend cannot take the {schema.name} JSON schema: "
                f"{' '.join(str(error).split())}"
            )
        self._grammars[schema.json_schema] = grammar
        return grammar

    def processor(self, schema: OutputSchema, end_ids: Iterable[int]) -> SchemaLogitsProcessor:
        """A processor for one `generate` call under `schema`."""
        return SchemaLogitsProcessor(self._llg, self.tokenizer, self.grammar(schema), end_ids)


class SchemaLogitsProcessor:
    """A transformers logits processor holding every row of a batch to one grammar; a row that
    has ended (an end token) is left alone, as decoding pads it from then on.

    The prompt's length is read from the first call (its `input_ids` are the prompts alone), so
    one processor serves one `generate` call."""

    def __init__(self, llg: Any, tokenizer: Any, grammar: str, end_ids: Iterable[int]):
        self._llg = llg
        self._tokenizer = tokenizer
        self._grammar = grammar
        self._ends = frozenset(end_ids)
        self._start: int | None = None
        self._matchers: list[Any] = []
        self._consumed: list[int] = []
        self._ended: list[bool] = []
        self._mask: torch.Tensor | None = None

    def __call__(self, input_ids: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
        rows = input_ids.shape[0]
        if self._start is None:
            self._start = input_ids.shape[1]
            self._matchers = [
                self._llg.LLMatcher(self._tokenizer, self._grammar) for _ in range(rows)
            ]
            self._consumed = [0] * rows
            self._ended = [False] * rows
            self._mask = self._llg.torch.allocate_token_bitmask(rows, scores.shape[1])
        mask = self._mask
        assert mask is not None
        generated = input_ids[:, self._start :].tolist()
        for row, tokens in enumerate(generated):
            if self._ended[row]:
                continue
            matcher = self._matchers[row]
            for token in tokens[self._consumed[row] :]:
                if token in self._ends:
                    self._ended[row] = True
                    break
                matcher.consume_token(token)
            self._consumed[row] = len(tokens)
            if self._ended[row]:
                mask[row] = -1  # every bit set: the padded row's scores stay as they are
                continue
            self._llg.torch.fill_next_token_bitmask(matcher, mask, row)
        scores = scores.clone()
        self._llg.torch.apply_token_bitmask_inplace(scores, mask.to(scores.device))
        return scores
