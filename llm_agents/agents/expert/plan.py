"""The scripted expert's game knowledge and planner: what to do next for a goal.

Fixed Craftax knowledge (recipes, which tool mines what, what each action can unlock) plus a
memory of the world built from past observations (`WorldMap`). `next_task` reads the goal's
required and forbidden achievements (from the dataset record, never the instruction text), the
current `Observation` and the map, and names the one task to work on now: gather a block, craft,
place, hunt, forage, sleep or explore for something not seen yet. It never chooses a task whose
action would unlock a forbidden achievement; `infeasible` says when a goal cannot be reached
without one.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

from textualizer.observation import Observation

Cell = tuple[int, int]
TaskKind = Literal[
    "gather", "craft", "place", "build", "hunt", "forage", "sleep", "explore", "wait", "idle"
]

#: Blocks the player can stand on (lava too, but it kills: never planned).
WALKABLE = frozenset({"grass", "sand", "path", "fire_grass", "ice_grass"})
#: Blocks PLACE_TABLE / PLACE_FURNACE / PLACE_PLANT can go on (plants: grass only).
FREE_GROUND = frozenset({"grass", "sand", "path"})
#: Blocks PLACE_STONE can go on.
STONE_GROUND = frozenset({"grass", "sand", "path", "water", "lava"})

#: Pickaxe tier needed to mine a block, and the achievement mining it unlocks.
MINING: dict[str, tuple[int, str]] = {
    "stone": (1, "COLLECT_STONE"),
    "coal": (1, "COLLECT_COAL"),
    "iron": (2, "COLLECT_IRON"),
    "diamond": (3, "COLLECT_DIAMOND"),
}
#: Achievement unlocked by DO on a block (collecting, drinking, eating).
DO_BLOCK_ACHIEVEMENT: dict[str, str] = {
    "tree": "COLLECT_WOOD",
    "water": "COLLECT_DRINK",
    "ripe_plant": "EAT_PLANT",
    "grass": "COLLECT_SAPLING",
    **{block: achievement for block, (_, achievement) in MINING.items()},
}
#: Achievement unlocked by killing a creature.
KILL_ACHIEVEMENT: dict[str, str] = {
    "cow": "EAT_COW",
    "zombie": "DEFEAT_ZOMBIE",
    "skeleton": "DEFEAT_SKELETON",
}
TIER_OF_TOOL: dict[str, int] = {"wood": 1, "stone": 2, "iron": 3, "diamond": 4}


@dataclass(frozen=True)
class Recipe:
    """A crafting action: its inputs and whether it needs a furnace beside the table."""

    wood: int = 0
    stone: int = 0
    coal: int = 0
    iron: int = 0
    furnace: bool = False


RECIPES: dict[str, Recipe] = {
    "MAKE_WOOD_PICKAXE": Recipe(wood=1),
    "MAKE_WOOD_SWORD": Recipe(wood=1),
    "MAKE_STONE_PICKAXE": Recipe(wood=1, stone=1),
    "MAKE_STONE_SWORD": Recipe(wood=1, stone=1),
    "MAKE_IRON_PICKAXE": Recipe(wood=1, stone=1, coal=1, iron=1, furnace=True),
    "MAKE_IRON_SWORD": Recipe(wood=1, stone=1, coal=1, iron=1, furnace=True),
}
TABLE_WOOD = 2
FURNACE_STONE = 1
#: The most of one material the inventory holds (craftax caps every count at 9): a gathering
#: target above it would never be reached.
INVENTORY_CAP = 9

#: The achievements each one needs unlocked first (on the only route to it).
PREREQUISITES: dict[str, tuple[str, ...]] = {
    "PLACE_TABLE": ("COLLECT_WOOD",),
    "MAKE_WOOD_PICKAXE": ("COLLECT_WOOD", "PLACE_TABLE"),
    "MAKE_WOOD_SWORD": ("COLLECT_WOOD", "PLACE_TABLE"),
    "COLLECT_STONE": ("MAKE_WOOD_PICKAXE",),
    "COLLECT_COAL": ("MAKE_WOOD_PICKAXE",),
    "PLACE_STONE": ("COLLECT_STONE",),
    "PLACE_FURNACE": ("COLLECT_STONE", "PLACE_TABLE"),
    "MAKE_STONE_PICKAXE": ("COLLECT_STONE", "PLACE_TABLE"),
    "MAKE_STONE_SWORD": ("COLLECT_STONE", "PLACE_TABLE"),
    "COLLECT_IRON": ("MAKE_STONE_PICKAXE",),
    "MAKE_IRON_PICKAXE": ("PLACE_FURNACE", "COLLECT_COAL", "COLLECT_IRON"),
    "MAKE_IRON_SWORD": ("PLACE_FURNACE", "COLLECT_COAL", "COLLECT_IRON"),
    "COLLECT_DIAMOND": ("MAKE_IRON_PICKAXE",),
    "PLACE_PLANT": ("COLLECT_SAPLING",),
    "EAT_PLANT": ("PLACE_PLANT",),
}

#: The order required achievements are worked on: cheap and enabling ones first.
ORDER: tuple[str, ...] = (
    "COLLECT_DRINK",
    "COLLECT_SAPLING",
    "PLACE_PLANT",
    "EAT_COW",
    "COLLECT_WOOD",
    "PLACE_TABLE",
    "MAKE_WOOD_SWORD",
    "MAKE_WOOD_PICKAXE",
    "COLLECT_STONE",
    "PLACE_STONE",
    "MAKE_STONE_SWORD",
    "MAKE_STONE_PICKAXE",
    "COLLECT_COAL",
    "PLACE_FURNACE",
    "COLLECT_IRON",
    "MAKE_IRON_SWORD",
    "MAKE_IRON_PICKAXE",
    "COLLECT_DIAMOND",
    "DEFEAT_ZOMBIE",
    "DEFEAT_SKELETON",
    "EAT_PLANT",
    "WAKE_UP",
)

#: Plants ripen this many steps after planting (craftax), far beyond the 250-step episodes.
PLANT_RIPENS_AFTER = 600


def closure(achievements: Iterable[str]) -> set[str]:
    """The achievements and everything that must be unlocked before them."""
    seen: set[str] = set()
    stack = list(achievements)
    while stack:
        name = stack.pop()
        if name not in seen:
            seen.add(name)
            stack.extend(PREREQUISITES.get(name, ()))
    return seen


def infeasible(required: Iterable[str], forbidden: Iterable[str]) -> str | None:
    """Why the goal cannot be reached without a forbidden achievement, or None."""
    banned = set(forbidden)
    for name in required:
        blocked = sorted(closure([name]) & banned)
        if blocked:
            return f"{name} needs {', '.join(blocked)} first, which the goal forbids"
    return None


def plan_order(required: Iterable[str], forbidden: Iterable[str] = ()) -> list[str]:
    """Every achievement the plan unlocks (prerequisites included), in the order worked on.

    Raises ValueError when that would unlock a forbidden achievement.
    """
    reason = infeasible(required, forbidden)
    if reason is not None:
        raise ValueError(reason)
    needed = closure(required)
    return [name for name in ORDER if name in needed]


class WorldMap:
    """Blocks seen so far, by world position, per floor (full Craftax has several)."""

    def __init__(self) -> None:
        self.floors: dict[int, dict[Cell, str]] = {}
        self.level = 0

    @property
    def blocks(self) -> dict[Cell, str]:
        return self.floors.setdefault(self.level, {})

    def update(self, obs: Observation) -> None:
        self.level = obs.floor.level if obs.floor is not None else 0
        known = self.blocks
        x, y = obs.position.x, obs.position.y
        for name, offsets in obs.blocks.items():
            for dx, dy in offsets:
                known[(x + dx, y + dy)] = name

    def cells(self, names: Iterable[str]) -> list[Cell]:
        wanted = set(names)
        return [cell for cell, name in self.blocks.items() if name in wanted]

    def get(self, cell: Cell) -> str | None:
        return self.blocks.get(cell)


@dataclass
class ExpertTask:
    """What the expert works on now."""

    kind: TaskKind
    """gather: DO on a block; craft/place: that action (near a table / on free ground); build:
    fill the episode's chosen cells with `target` blocks; hunt:
    kill a creature; forage: DO on grass for a sapling; sleep; explore: walk to unseen cells
    looking for `target`; wait: stay around `target` cells; idle: nothing left to do."""
    target: str | None = None
    """The block, creature or action the task is about."""
    achievement: str | None = None
    """The required achievement the task serves."""
    amount: int = 1
    """gather: how many the inventory should hold when done."""
    needs_furnace: bool = False
    """craft: the spot must have a furnace nearby as well as a table."""
    note: str = ""


@dataclass
class PlanContext:
    """Everything the planner reads."""

    required: tuple[str, ...]
    forbidden: tuple[str, ...]
    obs: Observation
    world: WorldMap
    table_reach: int = 12
    """A known table farther than this many steps is replaced by a new one when wood allows."""
    distances: Mapping[Cell, int] = field(default_factory=dict)
    """Path steps from the player to known cells (the navigator's), for `table_reach`."""

    @property
    def achieved(self) -> set[str]:
        return set(self.obs.achievements)

    def allowed(self, achievement: str | None) -> bool:
        return achievement is None or achievement not in self.forbidden

    def count(self, item: str) -> int:
        return self.obs.inventory.materials.get(item, 0)

    def tier(self, tool: str) -> int:
        tiers = [
            TIER_OF_TOOL.get(name.split("_")[0], 0)
            for name in self.obs.inventory.tools
            if name.endswith(f"_{tool}")
        ]
        return max(tiers, default=0)

    def near_cells(self, names: Iterable[str], reach: int) -> list[Cell]:
        return [c for c in self.world.cells(names) if self._distance(c) <= reach]

    def _distance(self, cell: Cell) -> float:
        # A block itself is not walkable: its distance is the best of its walkable neighbours.
        x, y = cell
        best = min(
            (
                self.distances.get(n, 10**6)
                for n in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1))
            ),
            default=10**6,
        )
        return best + 1


#: Tools that make a hunt much easier (skeletons hide in tunnels behind stone), made first
#: when allowed.
AIDS: dict[str, tuple[str, ...]] = {"DEFEAT_SKELETON": ("MAKE_WOOD_PICKAXE",)}


def aids(ctx: PlanContext) -> list[str]:
    """The helpful tools for the unfinished required achievements that may be made."""
    wanted = []
    for name in ctx.required:
        if name in ctx.achieved:
            continue
        for tool in AIDS.get(name, ()):
            if not (closure([tool]) & set(ctx.forbidden)) and tool not in wanted:
                wanted.append(tool)
    return wanted


def _tools_to_make(ctx: PlanContext) -> list[str]:
    """The crafting actions the rest of the plan needs, in order."""
    todo = [name for name in plan_order(ctx.required, ctx.forbidden) if name not in ctx.achieved]
    todo += [name for name in aids(ctx) if name not in todo]
    makes = []
    for name in todo:
        if name in RECIPES:
            kind, tool = name.removeprefix("MAKE_").lower().split("_")
            if ctx.tier(tool) < TIER_OF_TOOL[kind]:
                makes.append(name)
    return makes


def _budget(ctx: PlanContext, material: str) -> int:
    """How much of a raw material the rest of the plan consumes (with one table's slack)."""
    makes = _tools_to_make(ctx)
    total = sum(getattr(RECIPES[name], material, 0) for name in makes)
    todo = set(plan_order(ctx.required, ctx.forbidden)) - ctx.achieved
    if material == "wood":
        table_needed = bool(makes) or "PLACE_TABLE" in todo
        if table_needed and not ctx.near_cells(["crafting_table"], ctx.table_reach):
            total += TABLE_WOOD
        if any(name != "MAKE_WOOD_PICKAXE" and name != "MAKE_WOOD_SWORD" for name in makes):
            total += TABLE_WOOD  # the first table may be far from the stone by then
        if makes and ctx.tier("sword") < 1 and ctx.allowed("MAKE_WOOD_SWORD"):
            total += 1  # a wood sword while at the table
    if material == "stone":
        if "PLACE_STONE" in todo:
            total += 1
        if any(RECIPES[name].furnace for name in makes) or "PLACE_FURNACE" in todo:
            total += FURNACE_STONE
    return total


def _gather(ctx: PlanContext, block: str, achievement: str | None, amount: int) -> ExpertTask:
    """Collect `block` until the inventory holds `amount` (explore when none is known)."""
    if block in MINING:
        tier, _ = MINING[block]
        if ctx.tier("pickaxe") < tier:
            tool = {1: "MAKE_WOOD_PICKAXE", 2: "MAKE_STONE_PICKAXE", 3: "MAKE_IRON_PICKAXE"}[tier]
            return _craft(ctx, tool, achievement)
    if not ctx.world.cells([block]):
        return ExpertTask("explore", block, achievement, note=f"no {block} seen yet")
    return ExpertTask("gather", block, achievement, amount=amount)


def _material(
    ctx: PlanContext, material: str, amount: int, achievement: str | None
) -> ExpertTask | None:
    """A task that brings `material` to `amount` (the plan's budget when gathering), or None."""
    amount = min(amount, INVENTORY_CAP)
    if ctx.count(material) >= amount:
        return None
    target = min(max(amount, _budget(ctx, material)), INVENTORY_CAP)
    block = "tree" if material == "wood" else material
    return _gather(ctx, block, achievement, target)


def _table(ctx: PlanContext, achievement: str | None, extra_wood: int) -> ExpertTask | None:
    """A task that gets a crafting table within reach, or None when one is."""
    if ctx.near_cells(["crafting_table"], ctx.table_reach):
        return None
    if not ctx.allowed("PLACE_TABLE") and "PLACE_TABLE" not in ctx.achieved:
        # A table placed earlier (before the ban mattered) is still usable; explore back to it.
        if ctx.world.cells(["crafting_table"]):
            return None
        return ExpertTask("idle", note="needs a crafting table, and placing one is forbidden")
    wood = _material(ctx, "wood", TABLE_WOOD + extra_wood, achievement)
    return wood or ExpertTask("place", "PLACE_TABLE", achievement)


def _craft(
    ctx: PlanContext, action: str, achievement: str | None, sword_first: bool = True
) -> ExpertTask:
    recipe = RECIPES[action]
    if not ctx.allowed(action):
        return ExpertTask("idle", note=f"{action} is forbidden")
    for material in ("wood", "stone", "coal", "iron"):
        need = getattr(recipe, material)
        if need and (task := _material(ctx, material, need, achievement)):
            return task
    if task := _table(ctx, achievement, recipe.wood):
        return task
    if recipe.furnace and (task := _furnace(ctx, achievement)):
        return task
    chosen = _with_sword(ctx, action) if sword_first else action
    return ExpertTask("craft", chosen, achievement, needs_furnace=recipe.furnace)


def _with_sword(ctx: PlanContext, action: str) -> str:
    """A sword first when the materials allow it on top of the plan (zombie fights cost far
    less health with one); otherwise `action` itself."""
    wood, stone = ctx.count("wood"), ctx.count("stone")
    wood_budget, stone_budget = _budget(ctx, "wood"), _budget(ctx, "stone")
    tier = ctx.tier("sword")
    if tier < 2 and wood > wood_budget and stone > stone_budget and ctx.allowed("MAKE_STONE_SWORD"):
        return "MAKE_STONE_SWORD"
    # The wood budget holds one wood for this sword.
    if tier < 1 and wood >= max(wood_budget, 2) and ctx.allowed("MAKE_WOOD_SWORD"):
        return "MAKE_WOOD_SWORD"
    return action


def _furnace(ctx: PlanContext, achievement: str | None) -> ExpertTask | None:
    """A task that gets a furnace beside a reachable table, or None when there is one."""
    tables = ctx.near_cells(["crafting_table"], ctx.table_reach)
    furnaces = ctx.world.cells(["furnace"])
    for tx, ty in tables:
        if any(abs(fx - tx) <= 2 and abs(fy - ty) <= 2 for fx, fy in furnaces):
            return None
    if not ctx.allowed("PLACE_FURNACE"):
        return ExpertTask("idle", note="needs a furnace, and placing one is forbidden")
    stone = _material(ctx, "stone", FURNACE_STONE, achievement)
    return stone or _table(ctx, achievement, 0) or ExpertTask("place", "PLACE_FURNACE", achievement)


def way_out_task(ctx: PlanContext) -> ExpertTask | None:
    """For a player walled in by water, stone and trees (every reachable cell seen): the next
    task towards a wood pickaxe, which makes stone passable; None when one is in hand, or when
    it or a step on its way is forbidden."""
    if ctx.tier("pickaxe") >= 1:
        return None
    action = "MAKE_WOOD_PICKAXE"
    if (closure([action]) - ctx.achieved) & set(ctx.forbidden):
        return None
    return _craft(ctx, action, None, sword_first=False)


def task_for(ctx: PlanContext, achievement: str) -> ExpertTask:
    """The next task towards one achievement, given the inventory and the map."""
    a = achievement
    if a in ("COLLECT_WOOD", "COLLECT_DRINK"):
        block = "tree" if a == "COLLECT_WOOD" else "water"
        return _gather(ctx, block, a, ctx.count("wood") + 1 if block == "tree" else 1)
    if a in ("COLLECT_STONE", "COLLECT_COAL", "COLLECT_IRON", "COLLECT_DIAMOND"):
        block = a.removeprefix("COLLECT_").lower()
        return _gather(ctx, block, a, max(ctx.count(block) + 1, _budget(ctx, block)))
    if a == "COLLECT_SAPLING":
        return ExpertTask("forage", "grass", a)
    if a == "PLACE_PLANT":
        if ctx.count("sapling") < 1:
            return ExpertTask("forage", "grass", a)
        return ExpertTask("place", "PLACE_PLANT", a)
    if a == "EAT_PLANT":
        if ctx.world.cells(["ripe_plant"]):
            return ExpertTask("gather", "ripe_plant", a)
        if ctx.world.cells(["plant"]):
            return ExpertTask(
                "wait", "plant", a, note=f"plants ripen {PLANT_RIPENS_AFTER} steps after planting"
            )
        if ctx.count("sapling") < 1:
            return ExpertTask("forage", "grass", a)
        return ExpertTask("place", "PLACE_PLANT", a)
    if a in AIDS:
        for tool in aids(ctx):
            kind_name, tool_name = tool.removeprefix("MAKE_").lower().split("_")
            if ctx.tier(tool_name) < TIER_OF_TOOL[kind_name]:
                return _craft(ctx, tool, a)
    if a in ("EAT_COW", "DEFEAT_ZOMBIE", "DEFEAT_SKELETON"):
        kind = {"EAT_COW": "cow", "DEFEAT_ZOMBIE": "zombie", "DEFEAT_SKELETON": "skeleton"}[a]
        return ExpertTask("hunt", kind, a)
    if a == "PLACE_TABLE":
        wood = _material(ctx, "wood", TABLE_WOOD, a)
        return wood or ExpertTask("place", "PLACE_TABLE", a)
    if a == "PLACE_STONE":
        stone = _material(ctx, "stone", 1, a)
        return stone or ExpertTask("place", "PLACE_STONE", a)
    if a == "PLACE_FURNACE":
        stone = _material(ctx, "stone", FURNACE_STONE, a)
        return stone or _table(ctx, a, 0) or ExpertTask("place", "PLACE_FURNACE", a)
    if a in RECIPES:
        return _craft(ctx, a, a)
    if a == "WAKE_UP":
        if ctx.obs.vitals.energy >= ctx.obs.vitals.max_food:
            return ExpertTask(
                "wait", None, a, note="energy is full: sleep is refused until it drops"
            )
        return ExpertTask("sleep", None, a)
    return ExpertTask("idle", note=f"no plan for {a}")


def next_task(ctx: PlanContext) -> ExpertTask:
    """The task to work on now: the first required achievement (in plan order) not yet
    unlocked, resolved down to the first missing tool, material or place."""
    reason = infeasible(ctx.required, ctx.forbidden)
    if reason is not None:
        return ExpertTask("idle", note=reason)
    todo = [a for a in plan_order(ctx.required, ctx.forbidden) if a not in ctx.achieved]
    todo = [a for a in todo if a in ctx.required or a not in ctx.achieved]
    # Sleeping is only possible once energy has dropped, and quick then: do it when it is.
    if "WAKE_UP" in todo and ctx.obs.vitals.energy < ctx.obs.vitals.max_food:
        return task_for(ctx, "WAKE_UP")
    waiting: ExpertTask | None = None
    for achievement in todo:
        if achievement not in ctx.required:
            continue  # reached through the required ones' tasks
        task = task_for(ctx, achievement)
        if task.kind == "wait":
            waiting = waiting or task
            continue
        return task
    return waiting or ExpertTask("idle", note="every required achievement is unlocked")


# ---------------------------------------------------------------- Medium/Hard: placing goals

#: The action that places each block a placing goal names (Craftax block name, lower case).
PLACE_ACTION: dict[str, str] = {
    "stone": "PLACE_STONE",
    "crafting_table": "PLACE_TABLE",
    "furnace": "PLACE_FURNACE",
    "plant": "PLACE_PLANT",
}
#: Where each placed block may go (stone also fills water and lava, but a shape on land is
#: reachable from every side).
PLACE_GROUND: dict[str, frozenset[str]] = {
    "stone": FREE_GROUND,
    "crafting_table": FREE_GROUND,
    "furnace": FREE_GROUND,
    "plant": frozenset({"grass"}),
}
#: Observation axes (+x right, +y up) of the official sides (0 right/col+, 1 left, 2 up/row-,
#: 3 down).
SIDE_STEP: dict[str, Cell] = {"right": (1, 0), "left": (-1, 0), "up": (0, 1), "down": (0, -1)}


def shape_offsets(
    kind: str, size: int, diagonal: bool = False, cross: str = "straight"
) -> list[Cell]:
    """The cells of a line, filled square or star, relative to its first cell, top row first
    (placing row by row from the top keeps the cells below free to stand on)."""
    if kind == "build_line":
        cells = [(i, -i) if diagonal else (i, 0) for i in range(size)]
    elif kind == "build_square":
        cells = [(i, -j) for j in range(size) for i in range(size)]
    else:
        arms: list[Cell] = []
        if cross in ("straight", "combined"):
            arms += [(1, 0), (-1, 0), (0, 1), (0, -1)]
        if cross in ("diagonal", "combined"):
            arms += [(1, 1), (-1, 1), (1, -1), (-1, -1)]
        cells = [(0, 0)] + [(dx * k, dy * k) for dx, dy in arms for k in range(1, size + 1)]
    return sorted(cells, key=lambda c: (-c[1], c[0]))


def gather_task(ctx: PlanContext, block: str, amount: int) -> ExpertTask:
    """Collect `block` until the inventory holds `amount` (tools first, explore when unseen)."""
    return _gather(ctx, block, None, amount)


def supply_task(ctx: PlanContext, block: str, pieces: int) -> ExpertTask | None:
    """A task that brings the materials for `pieces` more `block`s into the inventory (and a
    table beside the player for furnaces), or None when they are in hand."""
    if pieces <= 0:
        return None
    if block == "plant":
        # Saplings come from one DO on grass in ten: plant each as it comes rather than hoard.
        return ExpertTask("forage", "grass") if ctx.count("sapling") < 1 else None
    if block == "crafting_table":
        return _material(ctx, "wood", TABLE_WOOD * pieces, None)
    stone = _material(ctx, "stone", pieces, None)
    if stone or block != "furnace":
        return stone
    return _table(ctx, None, 0)


#: How a conditional-placing goal's item is spent: the action, and (crafts) the recipe that
#: holds it. Nothing in Craftax-Classic spends diamonds.
SPEND_ACTION: dict[str, str] = {
    "wood": "MAKE_WOOD_PICKAXE",
    "stone": "PLACE_STONE",
    "sapling": "PLACE_PLANT",
    "coal": "MAKE_IRON_PICKAXE",
    "iron": "MAKE_IRON_PICKAXE",
}


def expert_cannot(goal: object) -> str | None:
    """Why the scripted expert cannot meet `goal` (a conditional-placing goal whose item it has
    no way to spend, `SPEND_ACTION`); None when it can try."""
    if getattr(goal, "kind", None) != "conditional_placing":
        return None
    item = str(getattr(goal, "collect", ""))
    return None if item in SPEND_ACTION else f"the scripted expert cannot spend {item}"


def spend_task(ctx: PlanContext, item: str) -> ExpertTask:
    """A task whose action takes `item` out of the inventory (a table's 2 wood, a placed stone
    or sapling, a craft's inputs), gathering the recipe's other inputs and its table and furnace
    first; idle when nothing can spend it."""
    action = SPEND_ACTION.get(item)
    if action is None:
        return ExpertTask("idle", note=f"nothing in Craftax-Classic spends {item}")
    if action in RECIPES:
        # No sword in between: it would spend the wood and stone the chosen craft needs.
        return _craft(ctx, action, None, sword_first=False)
    return ExpertTask("place", action, note=f"spending {item}")
