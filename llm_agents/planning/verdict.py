"""A plan's verdict beyond the episodes it won: whether its steps, played or not, break the
instruction's "do not", and whether it is empty.

An episode ends as soon as the checker sees the goal met, so steps after that point never play:
"Craft a wooden pickaxe but avoid planting anything" is met by a plan that plants after its
pickaxe, whose last steps would break the instruction had they played. The steps say what they
would earn, so the verdict is read from them: every skill's achievement (`earned_by`) against
the goal's forbidden ones.
"""

from __future__ import annotations

from collections.abc import Sequence

from llm_agents.agents.expert.plan import KILL_ACHIEVEMENT
from llm_agents.agents.skills.catalogue import (
    AnySkill,
    Attack,
    Build,
    Collect,
    Craft,
    Place,
    SkillOffer,
    read_skill,
)
from llm_agents.planning.records import StepReading

#: The achievement placing each block earns.
PLACED: dict[str, str] = {
    "crafting_table": "PLACE_TABLE",
    "furnace": "PLACE_FURNACE",
    "stone": "PLACE_STONE",
    "plant": "PLACE_PLANT",
}
#: The achievements the skills without parameters earn.
SIMPLE: dict[str, str] = {"eat": "EAT_COW", "drink": "COLLECT_DRINK", "sleep": "WAKE_UP"}


def earned_by(skill: AnySkill) -> str | None:
    """The achievement a skill earns when it succeeds (craftax's name), None for one that
    earns none (`go to`, `explore`, `noop`)."""
    if isinstance(skill, Collect):
        return f"COLLECT_{skill.material.upper()}"
    if isinstance(skill, Craft):
        return f"MAKE_{skill.item.upper()}"
    if isinstance(skill, Place | Build):
        return PLACED.get(skill.block)
    if isinstance(skill, Attack):
        return KILL_ACHIEVEMENT.get(skill.creature)
    return SIMPLE.get(skill.name)


def breaking_steps(
    steps: Sequence[StepReading], forbidden: Sequence[str], offer: SkillOffer
) -> list[str]:
    """Each read step skill that earns an achievement the instruction forbids, as
    `step N: SKILL earns ACHIEVEMENT`, in plan order."""
    banned = set(forbidden)
    found = []
    for step in steps:
        for text in step.skills:
            achievement = earned_by(read_skill(text, offer))
            if achievement in banned:
                found.append(f"step {step.number}: {text} earns {achievement}")
    return found


def goal_part_reached(required: Sequence[str], reached: Sequence[str], success: bool) -> float:
    """The share of the goal's required achievements an episode reached; a goal without
    required achievements (a placing goal) counts whole or not at all."""
    if not required:
        return float(success)
    return sum(1 for name in required if name in reached) / len(required)
