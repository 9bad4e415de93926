"""Lettered options (`--choice-scoring letters`): the options listed under one-character labels,
`A`-`Z` then `a`-`z` (full Craftax's 43 actions fit), in an order drawn afresh at each step, and
the backend asked for a label; the label chosen is mapped back to its option.

A model prefers some labels whatever they stand for (`A` most); a fixed list would hand that
preference to whichever option is listed first. The order is drawn from the run seed, the
episode and the step, by hashing, so a run replays the same orders whatever its scheduling or
batching, and each step's order is recorded with it (`StepRecord.options_shown`).
"""

from __future__ import annotations

import hashlib
import string
from collections.abc import Sequence

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from llm_agents.backends.base import ChoiceSet

#: The labels, in the order options are listed under them.
LABELS = string.ascii_uppercase + string.ascii_lowercase


class LetteredOptions(BaseModel):
    """One step's options in the order shown, the i-th under `LABELS[i]`."""

    model_config = ConfigDict(frozen=True)

    order: tuple[str, ...]
    """The options as listed, first under `A`."""

    @property
    def labels(self) -> str:
        return LABELS[: len(self.order)]

    def lines(self) -> list[dict[str, str]]:
        """What the templates list: `[{label, option}]` in the order shown."""
        return [
            {"label": label, "option": option}
            for label, option in zip(self.labels, self.order, strict=True)
        ]

    def option_of(self, answer: str) -> str | None:
        """The option an answer's label stands for; None when the answer is no label shown."""
        label = answer.strip()
        index = self.labels.find(label) if len(label) == 1 else -1
        return self.order[index] if index >= 0 else None


def label_choices(count: int) -> ChoiceSet:
    """The backend's options for a list of `count` lettered options: the labels, scored as
    one token each (`llm_agents.backends.base.choice_score`'s `letters`)."""
    check_count(count)
    return ChoiceSet(options=tuple(LABELS[:count]), rule="loglik", scoring="letters")


def check_count(count: int) -> None:
    if count > len(LABELS):
        raise UserError(
            f"--choice-scoring letters labels at most {len(LABELS)} options, not {count}"
        )


def lettered(options: Sequence[str], seed: int, episode: str, step: int) -> LetteredOptions:
    """`options` in the order drawn for (`seed`, `episode`, `step`): sorted by a hash of that
    key and each option's place in `options`, a uniformly drawn permutation that depends on
    nothing else (no library's random stream, whose algorithm may change)."""
    check_count(len(options))
    key = f"{seed}\x1f{episode}\x1f{step}"

    def rank(index: int) -> bytes:
        return hashlib.blake2b(f"{key}\x1f{index}".encode(), digest_size=16).digest()

    return LetteredOptions(order=tuple(options[i] for i in sorted(range(len(options)), key=rank)))
