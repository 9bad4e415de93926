"""What a failed episode of the `skills` agent got wrong, read from its decision records: the
ladder's table of errors.

One label per failed episode, the first that applies:
- `forbidden_unlocked`: it unlocked an achievement the goal forbids;
- `invalid_answers`: the agent stopped asking after invalid answers in a row;
- `stuck_repeating`: the agent stopped asking after the model chose the same skill
  `stuck_after` times, each ending before a step (failed, or nothing to do), no step between (`model_calls_saved` counts the
  calls a stop saved);
- `goal_misread`: no decision ever named the skill the goal asks for (the required
  achievement's, or the placing goal's block with its side, distance and reference, or its
  shape and size);
- `missing_prerequisite`: the goal's skill was chosen but its last try could not start (a
  material, tool or station missing), never fixed;
- `wrong_order`: some skill was chosen before what it needs and the model recovered, but the
  steps were spent;
- `died`: the player died;
- `out_of_steps`: it ran out of steps with the goal's skill chosen and nothing done out of order.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Literal, get_args

from env.goals import AnyGoal, Difficulty
from env.variant import Variant
from llm_agents.agents.skills.catalogue import (
    AnySkill,
    Attack,
    Build,
    Collect,
    Craft,
    Place,
    read_skill,
    skill_offer,
)
from llm_agents.agents.strategies.skills import STOPPED
from llm_agents.run_data.records import EpisodeRecord, SkillRecord

SkillError = Literal[
    "forbidden_unlocked", "invalid_answers", "stuck_repeating", "goal_misread",
    "missing_prerequisite", "wrong_order", "died", "out_of_steps",
]  # fmt: skip
SKILL_ERRORS: tuple[SkillError, ...] = get_args(SkillError)
#: Each label as the ladder's table writes it.
SKILL_ERROR_TITLES: dict[str, str] = {
    "forbidden_unlocked": "a forbidden achievement unlocked",
    "invalid_answers": "invalid answers in a row",
    "stuck_repeating": "stuck repeating a skill that does nothing",
    "goal_misread": "the goal misread",
    "missing_prerequisite": "a missing prerequisite",
    "wrong_order": "wrong order",
    "died": "died",
    "out_of_steps": "out of steps",
}

_FINAL_SKILL = {
    "COLLECT_DRINK": "drink",
    "EAT_COW": "eat",
    "EAT_PLANT": "eat",
    "WAKE_UP": "sleep",
    "DEFEAT_ZOMBIE": "attack zombie",
    "DEFEAT_SKELETON": "attack skeleton",
    "PLACE_TABLE": "place crafting_table",
    "PLACE_FURNACE": "place furnace",
    "PLACE_STONE": "place stone",
    "PLACE_PLANT": "place plant",
}


def _serves(skill: AnySkill, goal: AnyGoal, achievement: str | None = None) -> bool:
    """Whether `skill` is the one the goal (or one of its required achievements) asks for."""
    kind = goal.kind
    if achievement is not None:
        if achievement.startswith("COLLECT_") and achievement != "COLLECT_DRINK":
            material = achievement.removeprefix("COLLECT_").lower()
            return isinstance(skill, Collect) and skill.material == material
        if achievement.startswith("MAKE_"):
            return isinstance(skill, Craft) and skill.item == achievement[5:].lower()
        wanted = _FINAL_SKILL.get(achievement, "")
        if isinstance(skill, Attack) and achievement == "EAT_COW":
            return skill.creature == "cow"
        if wanted.startswith("place "):
            return isinstance(skill, Place | Build) and skill.block == wanted[6:]
        return skill.label == wanted
    if kind == "localization_placing":
        return isinstance(skill, Place) and (
            skill.block,
            skill.reference,
            skill.side,
            skill.distance,
        ) == (goal.place.lower(), goal.target.lower(), goal.side, goal.distance)  # type: ignore[union-attr]
    if kind == "conditional_placing":
        return isinstance(skill, Place | Build) and skill.block == goal.place.lower()  # type: ignore[union-attr]
    if not isinstance(skill, Build) or skill.shape != kind.removeprefix("build_"):
        return False
    same = (skill.block, skill.size) == (goal.block.lower(), goal.size)  # type: ignore[union-attr]
    if kind == "build_line":
        return same and skill.diagonal == goal.diagonal  # type: ignore[union-attr]
    if kind == "build_star":
        return same and skill.cross == goal.cross  # type: ignore[union-attr]
    return same


def _chosen(
    records: Iterable[SkillRecord], variant: Variant, difficulty: Difficulty
) -> list[tuple[SkillRecord, AnySkill]]:
    offer = skill_offer(variant, difficulty)
    chosen = []
    for record in records:
        if record.skill is not None:
            chosen.append((record, read_skill(record.skill, offer)))
    return chosen


def skill_error(
    episode: EpisodeRecord, goal: AnyGoal, variant: Variant, difficulty: Difficulty
) -> SkillError | None:
    """What a `skills` episode got wrong (the module's labels); None for a success."""
    if episode.success:
        return None
    records = episode.skills or []
    forbidden = set(getattr(goal, "forbidden", ()))
    if forbidden & set(episode.achievements):
        return "forbidden_unlocked"
    if stopped_asking(episode):
        return "invalid_answers" if records[-1].outcome == "invalid" else "stuck_repeating"
    chosen = _chosen(records, variant, difficulty)
    targets: list[str | None] = (
        [a for a in goal.required if a not in episode.achievements]
        if goal.kind == "achievements"
        else [None]
    )
    for target in targets:
        tries = [record for record, skill in chosen if _serves(skill, goal, target)]
        if not tries:
            return "goal_misread"
        if tries[-1].prerequisite:
            return "missing_prerequisite"
    if any(record.prerequisite for record, _ in chosen):
        return "wrong_order"
    if episode.termination == "death":
        return "died"
    return "out_of_steps"


def skill_error_table(
    episodes: Iterable[EpisodeRecord],
    goals: Mapping[tuple[str, str], AnyGoal],
    variant: Variant,
    difficulty: Difficulty,
) -> dict[SkillError, int]:
    """Failed episodes per label, every label listed; `goals` by (category, goal id)."""
    counts = Counter(
        skill_error(episode, goals[(episode.category, episode.goal_id)], variant, difficulty)
        for episode in episodes
    )
    return {label: counts[label] for label in SKILL_ERRORS}


def model_calls_saved(episode: EpisodeRecord) -> int:
    """The model calls an episode did not make because the agent stopped asking
    (`invalid_answers`, `stuck_repeating`): one per step it had left, as many as a model that
    goes on answering what cannot start (one `NOOP` step each) would have made."""
    if not stopped_asking(episode):
        return 0
    return max(episode.steps - (episode.skills or [])[-1].step - 1, 0)


def stopped_asking(episode: EpisodeRecord) -> bool:
    """Whether the agent stopped asking the model in `episode` (its last decision says so)."""
    records = episode.skills or []
    return bool(records) and STOPPED in (records[-1].reason or "")
