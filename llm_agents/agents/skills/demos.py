"""Worked skill sequences for the skills agent (`--skill-demos K`): how the expert's planner
chains skills for the difficulty's training goals, written in the catalogue's words.

Each demonstration is one training goal's original instruction and the skills the expert's
planner (`expert_plan.next_task`, the same one the scripted expert follows) works through for
it, from an empty inventory in a world where every block is in view: each task it names becomes
the catalogue skill that carries it out (gather -> `collect wood 3`, craft -> `craft
wood_pickaxe`, place -> `place crafting_table`, hunt -> `eat` or `attack zombie`, sleep ->
`sleep`, ...), and the task's effect (materials gathered and spent, tools made, achievements
unlocked, a table placed nearby) is applied before the planner is asked again. A placing goal's
demonstration gathers the materials the planner asks for (`supply_task`) and ends with the
placing skill that names the goal's block, side, distance and reference, or its shape. Goals
whose plan no skill sequence expresses (a plant that must ripen, an item to hold while placing,
a goal the expert cannot reach) and plans of a single skill (nothing chained) give none.

The list is offered in the grounding examples' order (`grounding.training_examples`: goal kinds
and categories in turn), and an episode is shown its first K under grounding's rule
(`grounding.examples_for`): never a demonstration whose goal the evaluated text phrases or whose
canonical reading is the text's own.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence

from pydantic import BaseModel, ConfigDict

from env.errors import UserError
from env.goals import AnyGoal, Difficulty
from env.variant import Variant
from llm_agents.agents.expert.plan import (
    DO_BLOCK_ACHIEVEMENT,
    FURNACE_STONE,
    KILL_ACHIEVEMENT,
    RECIPES,
    TABLE_WOOD,
    Cell,
    ExpertTask,
    PlanContext,
    WorldMap,
    next_task,
    shape_offsets,
    supply_task,
)
from llm_agents.agents.grounding import GroundingExample, examples_for
from llm_agents.agents.skills.catalogue import (
    AnySkill,
    Attack,
    Build,
    Collect,
    Place,
    SkillOffer,
    read_skill,
    skill_offer,
)
from llm_agents.run_data.readings import (
    AchievementsReading,
    BuildLineReading,
    BuildSquareReading,
    BuildStarReading,
    GoalReading,
    LocalizationReading,
    reading_of,
)
from textualizer.observation import Inventory, Observation, Position, Vitals

#: Where the planner's world keeps each block it may send the player to (all in view, so it
#: never explores), and where a placed table, furnace and plant stand.
_SEEN: dict[Cell, str] = {
    (3, 0): "tree",
    (-3, 0): "water",
    (0, 3): "stone",
    (0, -3): "coal",
    (3, 3): "iron",
    (-3, -3): "diamond",
    (1, 1): "grass",
}
_PLACED: dict[str, Cell] = {"crafting_table": (1, 0), "furnace": (2, 0), "plant": (-1, 1)}
_REACH = 8
#: The block a gathering task's material comes from, as `collect` names it.
_GATHERED = {"tree": "wood", "stone": "stone", "coal": "coal", "iron": "iron", "diamond": "diamond"}
#: The block a placing action puts down, and what it costs.
_PLACES: dict[str, tuple[str, str, int]] = {
    "PLACE_TABLE": ("crafting_table", "wood", TABLE_WOOD),
    "PLACE_FURNACE": ("furnace", "stone", FURNACE_STONE),
    "PLACE_STONE": ("stone", "stone", 1),
    "PLACE_PLANT": ("plant", "sapling", 1),
}
#: More planner tasks than any training goal's plan takes: a plan still going is not expressed.
_MAX_TASKS = 40


class SkillDemo(BaseModel):
    """One worked skill sequence: a training goal's instruction and the expert's skills for it."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    instruction: str
    """The goal's original instruction."""
    skills: tuple[str, ...]
    """The skills, in the catalogue's form, in the order the planner works through them."""
    reading: GoalReading
    """The goal as a reading: a text whose own reading equals it is not shown this demo."""
    texts: frozenset[str]
    """Every phrasing of the goal: a text among them is not shown this demo."""


class _World:
    """The planner's view of a world where everything is in sight: what it holds, and the
    skills that got it there."""

    def __init__(self, offer: SkillOffer):
        self.offer = offer
        self.materials: dict[str, int] = {}
        self.tools: list[str] = []
        self.achievements: list[str] = []
        self.map = WorldMap()
        self.map.blocks.update(_SEEN)
        self.skills: list[AnySkill] = []

    def context(
        self, required: tuple[str, ...] = (), forbidden: tuple[str, ...] = ()
    ) -> PlanContext:
        # Energy below its cap: a goal that asks to sleep is planned to sleep at once.
        vitals = Vitals(
            health=9.0, food=9, drink=9, energy=8, mana=None, max_health=9, max_food=9,
            max_mana=None, hunger=0.0, thirst=0.0, fatigue=0.0, recover=0.0,
        )  # fmt: skip
        inventory = Inventory(
            materials={k: v for k, v in self.materials.items() if v},
            tools=list(self.tools),
            enchantments={},
        )
        obs = Observation(
            variant=self.offer.variant, step=0, position=Position(x=0, y=0), floor=None,
            facing="up", facing_block=None, vitals=vitals, attributes=None, sleeping=False,
            resting=False, daylight=1.0, night=False, inventory=inventory, spells=[],
            achievements=list(self.achievements), view_size=(9, 11), blocks={}, items={},
            mobs=[], unlit=[],
        )  # fmt: skip
        distances = {
            (x, y): abs(x) + abs(y)
            for x in range(-_REACH, _REACH + 1)
            for y in range(-_REACH, _REACH + 1)
        }
        return PlanContext(required, forbidden, obs, self.map, distances=distances)

    def unlock(self, achievement: str | None) -> None:
        if achievement is not None and achievement not in self.achievements:
            self.achievements.append(achievement)

    def _collect(self, material: str, count: int) -> None:
        # The planner raises a gathering target as the plan grows (a table's wood, then a
        # pickaxe's): one skill gathers it all.
        last = self.skills[-1] if self.skills else None
        if isinstance(last, Collect) and last.material == material:
            count += last.count
            self.skills.pop()
        self.skills.append(Collect(material=material, count=count))

    def carry_out(self, task: ExpertTask) -> bool:
        """Apply `task` as the skill that carries it out; False where no skill does."""
        kind, target = task.kind, task.target or ""
        if kind == "gather" and target in _GATHERED:
            material = _GATHERED[target]
            more = task.amount - self.materials.get(material, 0)
            if more < 1:
                return False
            self._collect(material, more)
            self.materials[material] = task.amount
            self.unlock(DO_BLOCK_ACHIEVEMENT[target])
            return True
        if kind == "gather" and target == "water":
            self.skills.append(read_skill("drink", self.offer))
            self.unlock("COLLECT_DRINK")
            return True
        if kind == "forage":
            self._collect("sapling", 1)
            self.materials["sapling"] = self.materials.get("sapling", 0) + 1
            self.unlock("COLLECT_SAPLING")
            return True
        if kind == "craft" and target in RECIPES:
            recipe = RECIPES[target]
            for material in ("wood", "stone", "coal", "iron"):
                self.materials[material] = self.materials.get(material, 0) - getattr(
                    recipe, material
                )
            item = target.removeprefix("MAKE_").lower()
            self.skills.append(read_skill(f"craft {item}", self.offer))
            self.tools.append(item)
            self.unlock(target)
            return True
        if kind == "place" and target in _PLACES:
            block, material, cost = _PLACES[target]
            self.materials[material] = self.materials.get(material, 0) - cost
            self.skills.append(Place(block=block))
            if block in _PLACED:
                self.map.blocks[_PLACED[block]] = block
            self.unlock(target)
            return True
        if kind == "hunt" and target in KILL_ACHIEVEMENT:
            self.skills.append(
                read_skill("eat", self.offer) if target == "cow" else Attack(creature=target)
            )
            self.unlock(KILL_ACHIEVEMENT[target])
            return True
        if kind == "sleep":
            self.skills.append(read_skill("sleep", self.offer))
            self.unlock("WAKE_UP")
            return True
        return False


def planned_skills(reading: GoalReading, offer: SkillOffer) -> tuple[str, ...] | None:
    """The skills the expert's planner works through for `reading`, in the catalogue's form;
    None where no skill sequence of `offer` expresses its plan."""
    world = _World(offer)
    try:
        if isinstance(reading, AchievementsReading):
            done = _achievements(world, reading)
        else:
            done = _placing(world, reading)
        texts = tuple(skill.text for skill in world.skills)
        # Every skill must be one the catalogue offers, read back as itself.
        if not done or any(read_skill(text, offer).text != text for text in texts):
            return None
    except ValueError:
        return None
    return texts


def _achievements(world: _World, reading: AchievementsReading) -> bool:
    for _ in range(_MAX_TASKS):
        if set(reading.required) <= set(world.achievements):
            return True
        if not world.carry_out(next_task(world.context(reading.required, reading.forbidden))):
            return False
    return False


def _placing(world: _World, reading: GoalReading) -> bool:
    final: AnySkill
    if isinstance(reading, LocalizationReading):
        block, pieces = reading.place.lower(), 1
        final = Place(
            block=block,
            side=reading.side,
            distance=reading.distance,
            reference=reading.target.lower(),
        )
    elif isinstance(reading, BuildLineReading | BuildSquareReading | BuildStarReading):
        block = reading.block.lower()
        diagonal = getattr(reading, "diagonal", False)
        cross = getattr(reading, "cross", "straight")
        pieces = len(shape_offsets(reading.kind, reading.size, diagonal, cross))
        shape = reading.kind.removeprefix("build_")
        final = Build.model_validate(
            {
                "shape": shape,
                "block": block,
                "size": reading.size,
                "diagonal": diagonal,
                "cross": cross,
            }
        )
    else:
        return False
    for _ in range(_MAX_TASKS):
        task = supply_task(world.context(), block, pieces)
        if task is None:
            world.skills.append(final)
            return True
        if not world.carry_out(task):
            return False
    return False


def skill_demos(
    examples: Iterable[GroundingExample], variant: Variant, difficulty: Difficulty
) -> tuple[SkillDemo, ...]:
    """The demonstrations of a difficulty's training goals (`examples`, in their order): each
    goal whose plan chains two skills or more."""
    offer = skill_offer(variant, difficulty)
    demos = []
    for example in examples:
        skills = planned_skills(example.reading, offer)
        if skills is not None and len(skills) >= 2:
            demos.append(
                SkillDemo(
                    instruction=example.instruction,
                    skills=skills,
                    reading=example.reading,
                    texts=example.texts,
                )
            )
    return tuple(demos)


def demos_digest(demos: Sequence[SkillDemo]) -> str:
    """SHA-256 of a demonstration list as it is offered (order, instructions, skills and the
    phrasings each is withheld from): part of the identity of a run that shows them."""
    content = [[demo.instruction, list(demo.skills), sorted(demo.texts)] for demo in demos]
    text = json.dumps(content, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def demos_for(
    text: str, goal: AnyGoal, demos: Sequence[SkillDemo], k: int
) -> tuple[SkillDemo, ...]:
    """The first `k` demonstrations `text` (a phrasing of `goal`) may be shown."""
    return examples_for(text, reading_of(goal), demos, k)


def check_demo_count(
    demos: Sequence[SkillDemo], k: int, texts: Iterable[tuple[str, AnyGoal]], difficulty: str
) -> None:
    """A `UserError` unless every (text, goal) of the run can be shown `k` demonstrations."""
    short = [
        (len(demos_for(text, goal, demos, k)), text)
        for text, goal in texts
        if len(demos_for(text, goal, demos, k)) < k
    ]
    if short:
        most, text = min(short)
        raise UserError(
            f"--skill-demos {k}: the {difficulty} training split gives {len(demos)} skill "
            f"demonstrations, and {text!r} may be shown only {most} of them (none of its own "
            f"goal); use --skill-demos {most} or fewer"
        )
