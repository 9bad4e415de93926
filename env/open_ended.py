"""The open-ended Crafter task (BALROG's): no instruction, as many achievements as possible.

It is played as a goal of our own, so it flows through the dataset, schedule, runner and agents
like any CrafText goal: an achievements goal requiring all 22 Classic achievements. Reaching it
would end the episode, but only after every achievement is unlocked, when no score (progression,
the Crafter score, craftaxlm's) can rise further; until then the episode runs to death or the
step cap, as BALROG's does. The three scores judge it, not its success.
"""

from __future__ import annotations

from typing import Literal

from env.achievements import ACHIEVEMENTS
from env.goals import Dataset, DatasetSource, Goal, split_digest

Task = Literal["craftext", "open_ended"]
"""What a run plays: CrafText's instructions, or the open-ended task."""

OPEN_ENDED_ID = "OPEN_ENDED_CRAFTER"
OPEN_ENDED_TEXT = (
    "Survive and unlock as many of the game's achievements as you can: collect resources, "
    "craft tools, place objects, eat and drink, defeat enemies. There is no other goal."
)

OPEN_ENDED_GOAL = Goal(
    id=OPEN_ENDED_ID,
    split="easy_train",
    instruction=OPEN_ENDED_TEXT,
    paraphrases=(),
    category="combo",
    required=ACHIEVEMENTS,
)


def open_ended_dataset() -> Dataset:
    """The one-goal dataset the open-ended task plays."""
    digest = split_digest([OPEN_ENDED_GOAL])
    source = DatasetSource(kind="json", path="open-ended Crafter task", sha256=digest)
    return Dataset(source=source, goals=(OPEN_ENDED_GOAL,))
