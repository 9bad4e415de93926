"""The scripted expert (`expert`): its rules (survival, the goal's task now, what is never done)
and the agent that plays them, from the typed observations alone, with no model.

It sees exactly the `textualizer.Observation` sequence an LLM agent's prompts are rendered from,
remembers the blocks it has seen (`WorldMap`), and knows the game's fixed rules (recipes, tools,
dangers; `expert_plan`). The goal comes from the dataset record's required and forbidden
achievements, or for the Medium/Hard placing goals the block, shape, side and distance, and
the item to collect: the instruction text is never read. Each step it:

1. keeps itself alive: fights (or, when that is forbidden, flees) a zombie next to it, drinks and
   eats when low, never walks into lava;
2. asks the planner for the current task and walks to it by the shortest path over known cells
   (Dijkstra; stone costs an extra step to mine through once it has a pickaxe), exploring towards
   unseen cells when what it needs has not been seen, and, walled in with every reachable cell
   seen, making a wood pickaxe first (stone then opens a way out);
3. never takes an action that could unlock a forbidden achievement;
4. for a placing goal, once the materials are in hand, chooses the cells to fill (the shape on
   free ground, or beside the reference block, placing that too when none stands) and fills
   them, each from the cell before it; for a conditional goal it then holds the item's count
   and spends the item until the count falls below it, as the official check wants.

Its episodes give the reference row of a report, prove a goal solvable through our observation,
and are the demonstrations of the `few-shot` agent. The rules are here; the planner and game
knowledge in `expert_plan`, walking the map in `expert_navigation`, and carrying out one task
(the controllers the `skills` agent reuses) in `expert_controllers`.
"""

from __future__ import annotations

import importlib
from collections import Counter
from typing import TYPE_CHECKING, Any, ClassVar

from env.errors import UserError
from env.variant import Variant, as_variant
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.answers.parser import ParseResult
from llm_agents.agents.expert.controllers import Controller
from llm_agents.agents.expert.navigation import MOVES, ExpertEpisode, add, neighbours
from llm_agents.agents.expert.plan import (
    DO_BLOCK_ACHIEVEMENT,
    KILL_ACHIEVEMENT,
    PLACE_ACTION,
    SPEND_ACTION,
    WALKABLE,
    Cell,
    ExpertTask,
    gather_task,
    next_task,
    spend_task,
    supply_task,
    way_out_task,
)
from llm_agents.agents.protocol import AGENT_PROTOCOL_VERSION
from llm_agents.agents.types import Decision, EpisodeStart, StepPrompt, messages_hash
from llm_agents.backends.base import ModelOutput
from textualizer.observation import Observation

if TYPE_CHECKING:
    from env.dataset import Goal
    from llm_agents.agents.registry import AgentSettings
    from llm_agents.run_data.readings import GoalReading

_HOSTILE = frozenset({"zombie", "skeleton"})
_DRINK_LOW, _FOOD_LOW = 4, 3
_GATHER_DETOUR = 8
_MATERIALS = {"tree": "wood", "stone": "stone", "coal": "coal", "iron": "iron"}
_ORES = frozenset({"coal", "iron", "diamond"})


class ExpertAgent:
    """A rule-based player: the planner's task, walked to by shortest paths, nothing forbidden."""

    protocol_version: ClassVar[int] = AGENT_PROTOCOL_VERSION
    needs_model: ClassVar[bool] = False
    templates: ClassVar[tuple[str, ...]] = ()
    choices: ClassVar[None] = None

    def __init__(
        self,
        variant: Variant | str = Variant.FULL,
        renderer: str = "objects",
        fallback_action: str = "NOOP",
    ):
        self.variant = as_variant(variant)
        self.fallback_id = action_id(fallback_action, self.variant)
        self.renderer = renderer
        self._render = importlib.import_module("textualizer").render
        self._episodes: dict[int, ExpertEpisode] = {}

    @classmethod
    def from_config(cls, config: AgentSettings) -> ExpertAgent:
        """The expert of an evaluation config (it uses only the variant and renderer)."""
        return cls(config.variant, renderer=config.renderer, fallback_action=config.fallback_action)

    def start_episode(self, slot: int, start: EpisodeStart) -> None:
        """Begin an episode; `goal` (the dataset record) is required, the text is ignored."""
        goal = start.goal
        if goal is None:
            raise UserError("the expert agent needs the goal record, not only the instruction text")
        required, forbidden = getattr(goal, "required", ()), getattr(goal, "forbidden", ())
        self._episodes[slot] = ExpertEpisode(required, forbidden, goal)

    def start_goal(self, slot: int, reading: GoalReading) -> None:
        """Begin an episode towards a goal as another agent read it (its typed parameters are
        named as the dataset goal's, so the expert plays it as it would the record)."""
        required, forbidden = getattr(reading, "required", ()), getattr(reading, "forbidden", ())
        self._episodes[slot] = ExpertEpisode(required, forbidden, reading)

    def end_episode(self, slot: int) -> None:
        self._episodes.pop(slot, None)

    def check_templates(
        self, instruction: str, plan: str | None = None, goal: Goal | None = None
    ) -> None:
        """The expert renders no prompt: nothing to check."""

    def task(self, slot: int) -> ExpertTask | None:
        """The task the slot worked on at its last step (for reports of why it failed)."""
        return self._episode(slot).last_task

    def _episode(self, slot: int) -> ExpertEpisode:
        if slot not in self._episodes:
            raise UserError(f"slot {slot} has no episode; call start_episode({slot}, ...) first")
        return self._episodes[slot]

    def prepare(self, slot: int, observation: Any) -> StepPrompt:
        """The slot's step, rendered as the model would see it; there is no prompt to send."""
        return StepPrompt(
            slot=slot,
            observation=observation,
            messages=[],
            text=str(self._render(observation, self.renderer)),
        )

    def decide(self, prompt: StepPrompt, output: ModelOutput) -> Decision:
        """The expert's action for the prepared step; `output` (the no-model's) is ignored."""
        name, task = self.choose(prompt.slot, prompt.observation)
        note = f"{task.kind} {task.target or ''}".strip() if task else ""
        action = action_id(name, self.variant)
        return Decision(
            slot=prompt.slot,
            action=action,
            name=name,
            parse=ParseResult(action=action, name=name, stage="exact", raw=name),
            output=ModelOutput(text=name, reasoning=note or None),
            observation_text=prompt.text,
            prompt_hash=messages_hash([]),
            fallback_used=False,
        )

    # ------------------------------------------------------------------ one step of one slot

    def choose(self, slot: int, obs: Observation) -> tuple[str, ExpertTask | None]:
        """The action for one slot's observation, and the task it serves."""
        episode = self._episode(slot)
        episode.world.update(obs)
        if obs.sleeping:
            return "NOOP", episode.last_task
        step = _Step(episode, obs)
        name, task = step.decide()
        if not step.safe(name):
            name = "NOOP"
        if name == "DO" and obs.facing_block in ("stone", "coal", "iron", "diamond"):
            episode.mined.add(step.facing_cell)
        episode.last_task = task
        return name, task


class _Step(Controller):
    """The reasoning of one step: survival, the goal's task now, and what is never done."""

    def safe(self, name: str) -> bool:
        """False when the action could unlock a forbidden achievement."""
        if name.startswith(("MAKE_", "PLACE_")) and self.forbidden(name):
            return False
        if name == "SLEEP":
            return not self.forbidden("WAKE_UP")
        if name != "DO":
            return True
        mob = self.mobs.get(self.facing_cell)
        if mob is not None:
            return not self.forbidden(KILL_ACHIEVEMENT.get(mob))
        block = self.obs.facing_block or ""
        return not self.forbidden(DO_BLOCK_ACHIEVEMENT.get(block))

    def decide(self) -> tuple[str, ExpertTask | None]:
        urgent = self._survive()
        if urgent is not None:
            return urgent
        task = self._keep_gathering() or self._goal_task()
        action = self.perform(task)
        if action is None and not self._frontier():
            # Nothing left to see from here: the reachable ground is walled in. A goal's
            # creatures may spawn only beyond the walls, so breaking out comes first.
            way_out = way_out_task(self.context())
            if way_out is not None:
                task, action = way_out, self.perform(way_out)
        if action is None:
            action = self.explore(task.target if task.kind in ("explore", "hunt") else None)
            if action is None:
                action = "NOOP"
        return action, task

    def _goal_task(self) -> ExpertTask:
        goal = self.episode.goal
        kind = getattr(goal, "kind", "achievements")
        if kind == "achievements":
            return next_task(self.context())
        if kind == "conditional_placing":
            return self._conditional_task()
        block = str(getattr(goal, "place", None) or getattr(goal, "block", "")).lower()
        if block not in PLACE_ACTION:
            return ExpertTask("idle", note=f"no way to place {block}")
        ctx = self.context()
        if kind == "localization_placing" and self._reference() in _ORES and self.pickaxe < 1:
            # Ores sit inside stone: the cell beside one is usually mined free first.
            return gather_task(ctx, "stone", 1)
        if self.episode.site:
            pieces = Counter(name for _, name in self._remaining())
        else:
            pieces = Counter(name for _, name in self._plan(block))
        for name, count in pieces.items():
            if task := supply_task(ctx, name, count):
                return task
        return ExpertTask("build", block)

    def _conditional_task(self) -> ExpertTask:
        """Blocks first, then the item: the official check succeeds on the step the item's count
        falls from at least `collect_count` to below it (it is spent) while the map already held
        `place_count` blocks on the step before. So: place the blocks, hold `collect_count` of the
        item, then spend it until the count crosses."""
        goal = self.episode.goal
        block = str(getattr(goal, "place", "")).lower()
        wanted = int(getattr(goal, "place_count", 0))
        item = str(getattr(goal, "collect", ""))
        threshold = int(getattr(goal, "collect_count", 0))
        if threshold < 1:
            return ExpertTask("idle", note="a count of 0 can never be fallen below")
        if item not in SPEND_ACTION:
            return ExpertTask("idle", note=f"nothing in Craftax-Classic spends {item}")
        # The check counts the whole map, so blocks of the kind already there (stone) count too.
        standing = len(self.world.cells([block]))
        if standing < wanted:
            if block not in PLACE_ACTION:
                return ExpertTask("idle", note=f"no way to place {block}")
            site = self.episode.site
            pieces = wanted - standing if site is None else len(self._remaining())
            return supply_task(self.context(), block, pieces) or ExpertTask("build", block)
        if self.obs.inventory.materials.get(item, 0) < threshold:
            if item == "sapling":
                return ExpertTask("forage", "grass")
            return gather_task(self.context(), {"wood": "tree"}.get(item, item), threshold)
        return spend_task(self.context(), item)

    def _keep_gathering(self) -> ExpertTask | None:
        """The last gathering task while its amount is not reached and its block is close:
        the planner asks only for what the next craft needs, the amount is what the whole
        plan will use, and collecting it in one visit saves coming back."""
        last = self.episode.last_task
        if last is None or last.kind != "gather" or last.target not in _MATERIALS:
            return None
        material = _MATERIALS[last.target]
        if self.obs.inventory.materials.get(material, 0) >= last.amount:
            return None
        blocks = self.world.cells([last.target])
        stands = {n for b in blocks for n in neighbours(b)}
        near = [self.dist[c] for c in stands if c in self.dist]
        return last if near and min(near) <= _GATHER_DETOUR else None

    def _survive(self) -> tuple[str, ExpertTask] | None:
        """Fight or flee an adjacent zombie; drink or eat when low."""
        health = self.obs.vitals.health
        for cell, kind in sorted(self.mobs.items(), key=lambda item: self._steps_to(item[0])):
            distance = self._steps_to(cell)
            if kind not in _HOSTILE or distance > 2:
                continue
            # Fleeing rarely shakes a zombie off, and skeletons shoot: fight unless forbidden.
            # Skeletons back off, so they are only fought when next to the player.
            chase = health > 4 and kind == "zombie"
            if not self.forbidden(KILL_ACHIEVEMENT[kind]) and (distance == 1 or chase):
                fight = ExpertTask("hunt", kind, note=f"{kind} next to the player")
                return (self.interact({cell}) or "DO"), fight
            if distance > 1:
                continue
            away = self._flee(cell)
            if away is not None:
                return away, ExpertTask("hunt", kind, note="keeping away from a zombie")
        vitals = self.obs.vitals
        facing_water = self.obs.facing_block == "water"
        topping_up = facing_water and vitals.drink < vitals.max_food
        if (vitals.drink <= _DRINK_LOW or topping_up) and not self.forbidden("COLLECT_DRINK"):
            water = set(self.world.cells(["water"]))
            if water and (action := self.interact(water)):
                return action, ExpertTask("gather", "water", note="thirsty")
        if vitals.food <= _FOOD_LOW and not self.forbidden("EAT_COW"):
            cows = {cell for cell, kind in self.mobs.items() if kind == "cow"}
            if cows and (action := self.interact(cows)):
                return action, ExpertTask("hunt", "cow", note="hungry")
        return None

    def _flee(self, threat: Cell) -> str | None:
        options = [
            ((n[0] - threat[0]) ** 2 + (n[1] - threat[1]) ** 2, name)
            for name, step in MOVES.items()
            if (n := add(self.pos, step)) and self.world.get(n) in WALKABLE and n not in self.mobs
        ]
        return max(options)[1] if options else None
