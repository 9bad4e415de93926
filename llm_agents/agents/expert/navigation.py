"""The expert's navigation: walking the known map (shortest paths, facing and using a cell,
exploring unseen ground), and the memory of one episode it walks with.

A `Navigator` is built afresh for every step from the episode's memory (`ExpertEpisode`) and
the step's `Observation`: it searches the map from the player once (Dijkstra; stone costs an
extra step to mine through once there is a pickaxe) and answers, for a set of target cells,
the first action towards them. It never walks into lava and never mines what would unlock a
forbidden achievement.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from llm_agents.agents.expert.plan import (
    MINING,
    WALKABLE,
    Cell,
    ExpertTask,
    PlanContext,
    WorldMap,
)
from textualizer.observation import Observation

if TYPE_CHECKING:
    from env.goals import AnyGoal
    from llm_agents.run_data.readings import GoalReading

#: Move action -> (dx, dy) in the observation's axes (+x east, +y north).
MOVES: dict[str, Cell] = {"LEFT": (-1, 0), "RIGHT": (1, 0), "UP": (0, 1), "DOWN": (0, -1)}
_FACING: dict[str, Cell] = {"left": (-1, 0), "right": (1, 0), "up": (0, 1), "down": (0, -1)}
_HEADING_WEIGHT = 3.0
_STONE_WEIGHT = 4.0
_DEEP = frozenset({"iron", "diamond"})
_MOUNTAIN = frozenset({"stone", "coal", "iron", "diamond", "path", "lava"})
_UNREACHABLE = 10**9


def add(a: Cell, b: Cell) -> Cell:
    return (a[0] + b[0], a[1] + b[1])


def neighbours(cell: Cell) -> list[Cell]:
    return [add(cell, step) for step in MOVES.values()]


def direction(src: Cell, dst: Cell) -> str:
    step = (dst[0] - src[0], dst[1] - src[1])
    for name, move in MOVES.items():
        if move == step:
            return name
    raise ValueError(f"{dst} is not next to {src}")


class ExpertEpisode:
    """What the expert remembers of one episode: its goal, the map seen so far, where it was
    heading and what it worked on."""

    def __init__(
        self,
        required: Sequence[str],
        forbidden: Sequence[str],
        goal: AnyGoal | GoalReading | None = None,
    ):
        self.goal = goal
        self.required = tuple(required)
        self.forbidden = tuple(forbidden)
        self.site: dict[Cell, str] | None = None
        """The world cells a placing goal fills and the block each gets, in placing order,
        chosen once the materials are in hand."""
        self.near: list[Cell] = []
        """Localization: the placed and reference cells, which the official check wants within
        5 tiles of the player."""
        self.world = WorldMap()
        self.explore_target: Cell | None = None
        self.heading: Cell = (1, 0)
        self.last_task: ExpertTask | None = None
        self.patrol_target: Cell | None = None
        self.last_prey: tuple[Cell, int] | None = None
        self.mined: set[Cell] = set()


class Navigator:
    """One step's view of the map: the search from the player and the ways to targets."""

    def __init__(self, episode: ExpertEpisode, obs: Observation):
        self.episode = episode
        self.obs = obs
        self.world = episode.world
        self.pos: Cell = (obs.position.x, obs.position.y)
        self.mobs: dict[Cell, str] = {
            add(self.pos, (m.dx, m.dy)): m.kind for m in obs.mobs if m.health is not None
        }
        self.facing_cell = add(self.pos, _FACING[obs.facing])
        self.pickaxe = self._tier("pickaxe")
        self.dist, self.parent = self._search()

    def _tier(self, tool: str) -> int:
        ctx = PlanContext(self.episode.required, self.episode.forbidden, self.obs, self.world)
        return ctx.tier(tool)

    def forbidden(self, achievement: str | None) -> bool:
        return (
            achievement is not None
            and achievement in self.episode.forbidden
            and achievement not in self.obs.achievements
        )

    def minable(self, block: str | None) -> bool:
        if block not in MINING:
            return False
        tier, achievement = MINING[block]
        return self.pickaxe >= tier and not self.forbidden(achievement)

    def _block_cost(self, block: str) -> int | None:
        if block in WALKABLE:
            return 1
        if self.minable(block):
            return 3
        return None

    def _search(self) -> tuple[dict[Cell, int], dict[Cell, Cell]]:
        # The map holds thousands of cells late in an episode and this runs every step: each
        # block name's cost is worked out once per search, not once per cell visited.
        blocks = self.world.blocks
        mobs = self.mobs
        cost_of: dict[str, int | None] = {}
        moves = tuple(MOVES.values())
        dist = {self.pos: 0}
        parent: dict[Cell, Cell] = {}
        heap = [(0, self.pos)]
        while heap:
            d, cell = heapq.heappop(heap)
            if d > dist.get(cell, _UNREACHABLE):
                continue
            x, y = cell
            for dx, dy in moves:
                nxt = (x + dx, y + dy)
                block = blocks.get(nxt)
                if block is None or nxt in mobs:
                    continue
                if block in cost_of:
                    cost = cost_of[block]
                else:
                    cost = cost_of[block] = self._block_cost(block)
                if cost is None:
                    continue
                if d + cost < dist.get(nxt, _UNREACHABLE):
                    dist[nxt] = d + cost
                    parent[nxt] = cell
                    heapq.heappush(heap, (d + cost, nxt))
        return dist, parent

    def context(self) -> PlanContext:
        return PlanContext(
            self.episode.required,
            self.episode.forbidden,
            self.obs,
            self.world,
            distances=self.dist,
        )

    def step_towards(self, goals: set[Cell]) -> str | None:
        """The first action on the shortest path to the nearest goal cell (None: none reachable,
        or already standing on one)."""
        reachable = [cell for cell in goals if cell in self.dist]
        if not reachable:
            return None
        best = min(reachable, key=lambda cell: (self.dist[cell], cell))
        if best == self.pos:
            return None
        cell = best
        while self.parent[cell] != self.pos:
            cell = self.parent[cell]
        move = direction(self.pos, cell)
        block = self.world.get(cell)
        if block in WALKABLE:
            return move
        if self.facing_cell == cell and self.obs.facing_block == block:
            return "DO"  # mine through
        return move

    def interact(self, targets: set[Cell]) -> str | None:
        """Face and DO a target cell next to the player, else walk towards one."""
        for target in targets:
            if abs(target[0] - self.pos[0]) + abs(target[1] - self.pos[1]) == 1:
                if self.facing_cell == target:
                    return "DO"
                return direction(self.pos, target)
        stands = {n for t in targets for n in neighbours(t)}
        return self.step_towards(stands)

    def _steps_to(self, cell: Cell) -> int:
        return abs(cell[0] - self.pos[0]) + abs(cell[1] - self.pos[1])

    def _near(self, cell: Cell, blocks: set[str]) -> bool:
        return any(
            self.world.get((cell[0] + dx, cell[1] + dy)) in blocks
            for dx in (-1, 0, 1)
            for dy in (-1, 0, 1)
            if dx or dy
        )

    def _closest_to(self, cells: set[Cell]) -> str | None:
        """A step towards the reachable cell nearest (as the crow flies) to any of `cells`."""
        if not self.dist:
            return None
        best = min(
            self.dist,
            key=lambda c: (min(abs(c[0] - t[0]) + abs(c[1] - t[1]) for t in cells), self.dist[c]),
        )
        return self.step_towards({best})

    def explore(self, target: str | None) -> str | None:
        """A step towards unseen cells, keeping to a heading; biased towards where `target`
        is found (ores in stone, cows and zombies on grass, skeletons in tunnels)."""
        episode = self.episode
        frontier = self._frontier()
        goal = episode.explore_target
        if goal is None or goal not in frontier or goal == self.pos or goal not in self.dist:
            goal = self._pick_frontier(frontier, target)
            episode.explore_target = goal
            if goal is not None:
                dx, dy = goal[0] - self.pos[0], goal[1] - self.pos[1]
                norm = math.hypot(dx, dy) or 1.0
                episode.heading = (round(dx / norm), round(dy / norm))
        if goal is None:
            return self._wander()
        return self.step_towards({goal}) or self._wander()

    def _frontier(self) -> set[Cell]:
        known = self.world.blocks
        return {
            cell
            for cell in self.dist
            if cell != self.pos and any(n not in known for n in neighbours(cell))
        }

    def _pick_frontier(self, frontier: set[Cell], target: str | None) -> Cell | None:
        if not frontier:
            return None
        prefer = {
            "stone": {"stone", "path"},
            "coal": {"stone", "path"},
            "iron": {"stone", "path", "coal"},
            "diamond": {"stone", "path", "iron"},
            "skeleton": {"path"},
            "water": {"sand", "water"},
            "cow": {"grass"},
            "zombie": {"grass"},
            "tree": {"grass", "tree"},
        }.get(target or "", set())
        hx, hy = self.episode.heading

        def score(cell: Cell) -> float:
            dx, dy = cell[0] - self.pos[0], cell[1] - self.pos[1]
            norm = math.hypot(dx, dy) or 1.0
            align = (dx * hx + dy * hy) / norm
            bonus = 4.0 if prefer and self._near(cell, prefer) else 0.0
            if target in _DEEP:
                bonus += _STONE_WEIGHT * self._stoniness(cell)
            return self.dist[cell] - _HEADING_WEIGHT * align - bonus

        return min(frontier, key=lambda cell: (score(cell), cell))

    def _stoniness(self, cell: Cell) -> float:
        """The share of known cells around `cell` that are mountain (diamonds lie deep in it)."""
        around = [
            self.world.get((cell[0] + dx, cell[1] + dy))
            for dx in range(-3, 4)
            for dy in range(-3, 4)
        ]
        known = [block for block in around if block is not None]
        return sum(block in _MOUNTAIN for block in known) / len(known) if known else 0.0

    def _wander(self) -> str | None:
        """A free step along the heading, else any free step (which becomes the heading)."""
        for name, step in sorted(MOVES.items(), key=lambda item: item[1] != self.episode.heading):
            cell = add(self.pos, step)
            if self.world.get(cell) in WALKABLE and cell not in self.mobs:
                self.episode.heading = step
                return name
        return None
