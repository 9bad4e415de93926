"""Running one skill of the skills agent on the expert's controllers, step by step, until it
succeeds, fails (with the reason the model is shown next), or exhausts its step budget.

Prerequisites are not solved for the model: a skill whose materials, tools or station are
missing fails before its first step and says what is missing (`why_not`). They are craftax's own
(`craftax_classic/game_logic.py`, `craftax/game_logic.py`; `tests/test_skill_rules.py` steps the
env to hold them to it): a craft needs its materials and a table (an iron tool a furnace too)
among the 8 cells around the player, which the skill walks to; in full Craftax a tool is also
refused while one of its kind at that tier or better is held; a table needs 2 wood, a furnace 1
stone and nothing else, a stone 1 stone, a plant a sapling, each on a free cell. While it runs, the
controllers (`expert_controllers.Controller`, the scripted expert's own) choose each action; the
goal's forbidden achievements are not theirs to know, so nothing is held back for them.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Literal

from env.goals import CROSS_TYPES, SIDES
from env.variant import Variant
from llm_agents.agents.expert.controllers import Controller
from llm_agents.agents.expert.navigation import ExpertEpisode, neighbours
from llm_agents.agents.expert.plan import (
    FURNACE_STONE,
    INVENTORY_CAP,
    KILL_ACHIEVEMENT,
    MINING,
    PLACE_ACTION,
    RECIPES,
    TABLE_WOOD,
    TIER_OF_TOOL,
    Cell,
    ExpertTask,
    PlanContext,
    shape_offsets,
)
from llm_agents.agents.skills.catalogue import (
    MATERIAL_SOURCE,
    AnySkill,
    Attack,
    Build,
    Collect,
    Craft,
    GoTo,
    Place,
    Simple,
    SkillOffer,
)
from textualizer.observation import Observation

Outcome = Literal["succeeded", "failed", "out_of_steps", "interrupted", "invalid", "unfinished"]
"""How a decision ended: its skill did what it says, could not start or go on (`failed`, with
the reason), ran out of its step budget, was cut short by an attack, named no skill of the
catalogue (`invalid`), or was still running when the episode ended (`unfinished`)."""

#: Steps `explore` walks before handing back.
EXPLORE_STEPS = 12
#: A crafting table farther than this many path steps is not "nearby" (the expert's reach).
TABLE_REACH = 12
_PICKAXE = {1: "wood_pickaxe", 2: "stone_pickaxe", 3: "iron_pickaxe"}
_HOSTILE = frozenset({"zombie", "skeleton", "gnome_warrior", "orc_soldier", "orc_mage",
                      "lizard", "knight", "troll", "pigman", "frost_troll", "archer",
                      "gnome_archer", "kobold", "deep_thing", "fire_elemental",
                      "ice_elemental"})  # fmt: skip
#: How many of each material one placed block takes.
_COST = {
    "crafting_table": ("wood", TABLE_WOOD),
    "furnace": ("stone", FURNACE_STONE),
    "stone": ("stone", 1),
    "plant": ("sapling", 1),
}


@dataclass(frozen=True)
class Finished:
    """A skill's end: its outcome, and for anything but success the reason shown next."""

    outcome: Outcome
    reason: str | None = None


def _materials(obs: Observation) -> dict[str, int]:
    return dict(obs.inventory.materials)


def _tier(obs: Observation, tool: str) -> int:
    ctx = PlanContext((), (), obs, ExpertEpisode((), ()).world)
    return ctx.tier(tool)


def _held_better(obs: Observation, item: str) -> str | None:
    """Why full Craftax refuses to craft `item` (its inventory keeps one tier per tool kind,
    and a tool is made only above the tier held), or None (Classic counts each tool apart)."""
    if obs.variant is not Variant.FULL:
        return None
    tier_name, kind = item.split("_", 1)
    held = _tier(obs, kind)
    if held >= TIER_OF_TOOL[tier_name]:
        return f"craft {item}: a {kind} as good or better is already held"
    return None


def _station_near(episode: ExpertEpisode, obs: Observation, furnace: bool) -> str | None:
    """Why no crafting table (and furnace) is nearby, or None when one is."""
    step = Controller(episode, obs)
    ctx = PlanContext((), (), obs, episode.world, distances=step.dist)
    tables = ctx.near_cells(["crafting_table"], TABLE_REACH)
    if not tables:
        return f"no crafting table within {TABLE_REACH} steps (place table first)"
    if furnace:
        furnaces = episode.world.cells(["furnace"])
        if not any(
            abs(f[0] - t[0]) <= 2 and abs(f[1] - t[1]) <= 2 for t in tables for f in furnaces
        ):
            return "no furnace beside a nearby crafting table (place furnace there first)"
    return None


class SkillRun:
    """One skill in progress for one episode: `why_not` before it starts, then `advance` each
    step with the new observation, which answers the action to take or how it finished."""

    def __init__(self, skill: AnySkill, episode: ExpertEpisode, obs: Observation, budget: int):
        self.skill = skill
        self.episode = episode
        self.budget = budget
        self.steps = 0
        self.start = obs
        self.last = obs
        self.issued: str | None = None
        """The action taken at the previous step."""
        self.hit: str | None = None
        """The creature kind faced when the previous step was DO."""
        self.was_sleeping = False

    # ------------------------------------------------------------------ before the first step

    def why_not(self) -> str | None:
        """Why the skill cannot start now (a missing material, tool or station), or None."""
        skill, obs = self.skill, self.start
        have = _materials(obs)
        if isinstance(skill, Collect):
            block = MATERIAL_SOURCE[skill.material]
            if block in MINING:
                tier, _ = MINING[block]
                if _tier(obs, "pickaxe") < tier:
                    tool = _PICKAXE[tier]
                    article = "an" if tool[0] in "aeiou" else "a"
                    return f"collect {skill.material} needs {article} {tool} (craft it first)"
            if have.get(skill.material, 0) + skill.count > INVENTORY_CAP:
                return f"the inventory holds at most {INVENTORY_CAP} {skill.material}"
            return None
        if isinstance(skill, Craft):
            recipe = RECIPES[f"MAKE_{skill.item.upper()}"]
            missing = [
                f"{need} {material} (have {have.get(material, 0)})"
                for material in ("wood", "stone", "coal", "iron")
                if (need := getattr(recipe, material)) > have.get(material, 0)
            ]
            if missing:
                return f"craft {skill.item} needs " + ", ".join(missing)
            held = _held_better(obs, skill.item)
            if held is not None:
                return held
            return _station_near(self.episode, obs, recipe.furnace)
        if isinstance(skill, Place | Build):
            reference = skill.reference if isinstance(skill, Place) else None
            if reference is not None and not self.episode.world.cells([reference]):
                return f"no {reference} seen yet (find one first)"
            pieces = self._pieces()
            for block, count in pieces.items():
                material, each = _COST[block]
                if have.get(material, 0) < each * count:
                    return (
                        f"{skill.text} needs {each * count} {material} "
                        f"(have {have.get(material, 0)})"
                    )
            return None
        if skill.name == "sleep" and obs.vitals.energy >= obs.vitals.max_food:
            return "energy is full: sleep is refused until it drops"
        return None

    def _pieces(self) -> dict[str, int]:
        """The blocks a placing skill puts down, by kind."""
        skill = self.skill
        if isinstance(skill, Place) and skill.reference is None:
            return {skill.block: 1}
        self._set_goal()
        plan = Controller(self.episode, self.start)._plan(self._block())
        counts: dict[str, int] = {}
        for _, block in plan:
            counts[block] = counts.get(block, 0) + 1
        return counts

    def _block(self) -> str:
        skill = self.skill
        assert isinstance(skill, Place | Build)
        return skill.block

    def _set_goal(self) -> None:
        """Give the controllers a placing goal read off the skill (as a typed goal names it)."""
        skill, episode = self.skill, self.episode
        if isinstance(skill, Place):
            goal = SimpleNamespace(
                kind="localization_placing",
                place=skill.block,
                target=skill.reference,
                side=skill.side,
                distance=skill.distance,
            )
        else:
            assert isinstance(skill, Build)
            goal = SimpleNamespace(
                kind=f"build_{skill.shape}",
                block=skill.block,
                size=skill.size,
                diagonal=skill.diagonal,
                cross=skill.cross,
            )
        if episode.goal != goal:
            episode.goal, episode.site, episode.near = goal, None, []  # type: ignore[assignment]

    # ------------------------------------------------------------------ each step

    def advance(self, obs: Observation) -> str | Finished:
        """The action for this step, or how the skill finished (checked on `obs` first)."""
        finished = self._finished(obs)
        self.last = obs
        if finished is not None:
            return finished
        if self.steps >= self.budget:
            return Finished(
                "out_of_steps", f"{self.skill.text} did not finish in {self.budget} steps"
            )
        action = self._action(obs)
        if action is None:
            return Finished("failed", f"{self.skill.text}: nothing reachable to do it with")
        self.steps += 1
        self.issued = action
        return action

    def _finished(self, obs: Observation) -> Finished | None:
        skill, before, last = self.skill, self.start, self.last
        new = set(obs.achievements) - set(before.achievements)
        hostile = [m for m in obs.mobs if m.kind in _HOSTILE and abs(m.dx) + abs(m.dy) <= 1]
        attacked = obs.vitals.health < last.vitals.health and hostile
        if attacked and not (isinstance(skill, Attack) and skill.creature == hostile[0].kind):
            return Finished(
                "interrupted",
                f"a {hostile[0].kind} is attacking you "
                f"(health {last.vitals.health:g} -> {obs.vitals.health:g})",
            )
        have, had = _materials(obs), _materials(before)
        if isinstance(skill, Collect):
            if have.get(skill.material, 0) >= had.get(skill.material, 0) + skill.count:
                return Finished("succeeded")
            return None
        if isinstance(skill, Craft) or (isinstance(skill, Place) and skill.reference is None):
            spent = self.issued is not None and self.issued.startswith(("MAKE_", "PLACE_"))
            if spent and have != _materials(last):
                return Finished("succeeded")
            return None
        if isinstance(skill, Place | Build):
            return self._placed(obs)
        if isinstance(skill, GoTo):
            return Finished("succeeded") if self._beside(obs, skill.block) else None
        if isinstance(skill, Attack):
            return self._killed(obs, skill.creature, new)
        name = skill.name
        if name == "eat":
            fed = obs.vitals.food > last.vitals.food or new & {"EAT_COW", "EAT_PLANT"}
            return Finished("succeeded") if fed else None
        if name == "drink":
            # Drinking with a full thirst bar still counts (the achievement says so).
            drank = obs.vitals.drink > last.vitals.drink or "COLLECT_DRINK" in new
            return Finished("succeeded") if drank else None
        if name == "sleep":
            woke = self.was_sleeping and not obs.sleeping
            self.was_sleeping = self.was_sleeping or obs.sleeping
            return Finished("succeeded") if woke or "WAKE_UP" in new else None
        if name == "explore":
            return Finished("succeeded") if self.steps >= EXPLORE_STEPS else None
        return Finished("succeeded") if self.steps >= 1 else None  # noop

    def _placed(self, obs: Observation) -> Finished | None:
        self._set_goal()
        step = Controller(self.episode, obs)
        block = self._block()
        if not step._plan(block):
            # The official straight line of two asks for no block, only a place clear of them.
            return Finished("succeeded") if step._clear_of(block) is None else None
        if self.episode.site is not None and not step._remaining():
            return Finished("succeeded")
        return None

    def _beside(self, obs: Observation, block: str) -> bool:
        pos: Cell = (obs.position.x, obs.position.y)
        cells = set(self.episode.world.cells([block]))
        return pos in cells or any(n in cells for n in neighbours(pos))

    def _killed(self, obs: Observation, creature: str, new: set[str]) -> Finished | None:
        if KILL_ACHIEVEMENT.get(creature) in new:
            return Finished("succeeded")
        if creature == "cow" and obs.vitals.food > self.last.vitals.food:
            return Finished("succeeded")
        if self.hit == creature and not any(
            m.kind == creature and abs(m.dx) + abs(m.dy) <= 1 for m in obs.mobs
        ):
            return Finished("succeeded")  # the one it was hitting is gone
        return None

    def _action(self, obs: Observation) -> str | None:
        skill, step = self.skill, Controller(self.episode, obs)
        self.hit = None
        if isinstance(skill, Collect):
            block = MATERIAL_SOURCE[skill.material]
            if block == "grass":
                return step.perform(ExpertTask("forage", "grass")) or step.explore(None)
            return step.perform(ExpertTask("gather", block)) or step.explore(block)
        if isinstance(skill, Craft):
            make = f"MAKE_{skill.item.upper()}"
            return step.perform(ExpertTask("craft", make, needs_furnace=RECIPES[make].furnace))
        if isinstance(skill, Place) and skill.reference is None:
            return step.perform(ExpertTask("place", PLACE_ACTION[skill.block])) or step.explore(
                None
            )
        if isinstance(skill, Place | Build):
            self._set_goal()
            return step.perform(ExpertTask("build", skill.block)) or step.explore(None)
        if isinstance(skill, GoTo):
            cells = set(self.episode.world.cells([skill.block]))
            stands = {n for c in cells for n in neighbours(c)}
            return step.step_towards(stands) or step.explore(skill.block)
        if isinstance(skill, Attack) or skill.name == "eat":
            creature = skill.creature if isinstance(skill, Attack) else "cow"
            action = step.perform(ExpertTask("hunt", creature)) or step.explore(creature)
            if action == "DO" and step.mobs.get(step.facing_cell) == creature:
                self.hit = creature
            return action
        if skill.name == "drink":
            return step.perform(ExpertTask("gather", "water")) or step.explore("water")
        if skill.name == "sleep":
            return "NOOP" if obs.sleeping else "SLEEP"
        if skill.name == "explore":
            return step.explore(None) or "NOOP"
        return "NOOP"


#: The distances and sizes `--choice` offers for placing and building (the official goals'
#: ranges).
CHOICE_DISTANCES = range(1, 6)
CHOICE_SIZES = range(2, 8)


def valid_now(offer: SkillOffer, episode: ExpertEpisode, obs: Observation) -> list[str]:
    """The skills that can start on `obs` (`--choice`'s options), in the catalogue's order:
    placing and building at the official goals' distances and sizes that the inventory can
    pay for, beside blocks in view; `go to` a block in view; `attack` a creature in view."""
    have = _materials(obs)

    def affordable(block: str, pieces: int) -> bool:
        material, each = _COST[block]
        return have.get(material, 0) >= each * pieces

    in_view = [block for block in offer.blocks if block in obs.blocks]
    candidates: list[AnySkill] = [Collect(material=m) for m in offer.materials]
    candidates += [Place(block=b) for b in offer.placeable]
    options = [c.text for c in candidates if SkillRun(c, episode, obs, 1).why_not() is None]
    placing = [b for b in offer.placeable if affordable(b, 1) and b != "furnace"]
    if offer.place_at:
        options += [
            Place(block=b, side=side, distance=d, reference=ref).text
            for b in placing
            for ref in in_view
            for side in SIDES
            for d in CHOICE_DISTANCES
        ]
    for shape in offer.shapes:
        for b in placing:
            for size in CHOICE_SIZES:
                forms = {
                    "line": [
                        Build(shape="line", block=b, size=size, diagonal=d) for d in (False, True)
                    ],
                    "square": [Build(shape="square", block=b, size=size)],
                    "star": [Build(shape="star", block=b, size=size, cross=c) for c in CROSS_TYPES],
                }[shape]
                options += [
                    f.text
                    for f in forms
                    if affordable(
                        b, len(shape_offsets(f"build_{shape}", size, f.diagonal, f.cross))
                    )
                ]
    later: list[AnySkill] = [Craft(item=i) for i in offer.items]
    later += [GoTo(block=b) for b in in_view]
    kinds = dict.fromkeys(m.kind for m in obs.mobs if m.kind in offer.creatures)
    later += [Attack(creature=kind) for kind in kinds]
    later += [Simple(name=n) for n in ("eat", "drink", "sleep", "explore", "noop")]
    options += [c.text for c in later if SkillRun(c, episode, obs, 1).why_not() is None]
    return options
