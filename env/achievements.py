"""The 22 achievements CrafText goals are written in.

Craftax-Classic has exactly these, with these ids; full Craftax has 67 and its first 22 are the
same ids with the same meaning, so one checker serves both variants.
"""

from env.craftax_names import CLASSIC_ACHIEVEMENTS

ACHIEVEMENTS: tuple[str, ...] = CLASSIC_ACHIEVEMENTS
NUM_ACHIEVEMENTS = len(ACHIEVEMENTS)
ACHIEVEMENT_IDS: dict[str, int] = {name: i for i, name in enumerate(ACHIEVEMENTS)}
