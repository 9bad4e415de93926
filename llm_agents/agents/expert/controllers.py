"""The expert's controllers: one task (gather, hunt, craft, place, build a placing goal's
site, forage, sleep, wait) turned into this step's action.

`Controller.perform` carries out the `ExpertTask` the expert's rules (or a skill of the
`skills` agent) chose, on top of the `Navigator`'s paths: None means nothing to do here but
explore. For placing goals it chooses the cells to fill (the shape on free ground, or beside
the reference block, placing that too when none stands) and fills them, each from the cell
before it, keeping clear of other blocks of the kind where the official checks count them.
"""

from __future__ import annotations

from env.checker_geometry import LOCAL_RADIUS as _LOCAL_REACH
from env.checker_geometry import WINDOW_RADIUS as _LINE_APART
from llm_agents.agents.expert.navigation import (
    MOVES,
    Navigator,
    add,
    direction,
    neighbours,
)
from llm_agents.agents.expert.plan import (
    FREE_GROUND,
    PLACE_ACTION,
    PLACE_GROUND,
    SIDE_STEP,
    STONE_GROUND,
    WALKABLE,
    Cell,
    ExpertTask,
    shape_offsets,
)

_PREY_MEMORY = 12
_PLACED_ON_CLEARED = frozenset({"PLACE_TABLE", "PLACE_FURNACE", "PLACE_STONE"})


class Controller(Navigator):
    """The navigator, plus the way to carry out each kind of task."""

    def perform(self, task: ExpertTask) -> str | None:
        kind, target = task.kind, task.target
        if kind == "gather" and target is not None:
            return self.interact(set(self.world.cells([target])))
        if kind == "hunt" and target is not None:
            prey = {cell for cell, mob in self.mobs.items() if mob == target}
            if prey:
                self.episode.last_prey = (min(prey, key=self._steps_to), self.obs.step)
                return self.interact(prey) or self._closest_to(prey)
            last = self.episode.last_prey
            # A creature that just left the view is still about where it was seen.
            recent = last is not None and self.obs.step - last[1] <= _PREY_MEMORY
            if recent and last is not None and self._steps_to(last[0]) > 1:
                action = self._closest_to({last[0]})
                if action is not None:
                    return action
            return self._patrol() if target == "skeleton" else None
        if kind == "craft" and target is not None:
            return self._craft(target, task.needs_furnace)
        if kind == "place" and target is not None:
            return self._place(target)
        if kind == "build" and target is not None:
            return self._build(target)
        if kind == "forage":
            return self._face_ground({"grass"}, "DO")
        if kind == "sleep":
            return "SLEEP"
        if kind == "wait" and target is not None:
            spots = {n for t in self.world.cells([target]) for n in neighbours(t)}
            return self.step_towards(spots) or "NOOP"
        if kind in ("wait", "idle"):
            return "NOOP"
        return None  # explore

    def _patrol(self) -> str | None:
        """Walk the known tunnels: skeletons appear only on tunnel floor 10-13 steps away and
        mostly wander, so covering the tunnels finds them. None: no tunnel known (explore)."""
        tunnels = [
            c for c in self.world.cells(["path"]) if c in self.dist and c not in self.episode.mined
        ]
        if not tunnels:
            return None
        frontier = [c for c in self._frontier() if c in tunnels]
        if frontier:
            # Into the tunnels' unseen part: a general exploring step keeps to its heading,
            # which may lead away from them.
            return self.step_towards(set(frontier))
        goal = self.episode.patrol_target
        if goal is None or goal == self.pos or goal not in self.dist:
            far = [c for c in tunnels if 6 <= self._steps_to(c) <= 16] or tunnels
            # Deterministic but varied: the episode step picks among the far tunnel cells.
            goal = sorted(far)[self.obs.step * 7 % len(far)]
            self.episode.patrol_target = goal
        return self.step_towards({goal})

    def _station(self, needs_furnace: bool) -> set[Cell]:
        """Walkable cells with a table (and a furnace, when asked) among their 8 neighbours."""
        wanted = [{"crafting_table"}, {"furnace"}] if needs_furnace else [{"crafting_table"}]
        tables = self.world.cells(["crafting_table"])
        cells = {(tx + dx, ty + dy) for tx, ty in tables for dx in (-1, 0, 1) for dy in (-1, 0, 1)}
        return {
            c
            for c in cells
            if (c == self.pos or self.world.get(c) in WALKABLE)
            and all(self._near(c, blocks) for blocks in wanted)
        }

    def _craft(self, action: str, needs_furnace: bool) -> str | None:
        station = self._station(needs_furnace)
        if self.pos in station:
            return action
        return self.step_towards(station)

    def _place(self, action: str) -> str | None:
        ground = STONE_GROUND if action == "PLACE_STONE" else FREE_GROUND
        if action == "PLACE_PLANT":
            ground = frozenset({"grass"})
        if action == "PLACE_FURNACE":
            station = self._station(False)
            if station and self.pos not in station:
                return self.step_towards(station)
            return self._face_ground(ground, action, keep_near_table=bool(station))
        return self._face_ground(ground, action)

    def _build(self, block: str) -> str | None:
        """Fill the goal's site, choosing the site first (None: explore)."""
        episode = self.episode
        if not self._plan(block):
            return self._clear_of(block)
        if episode.site is None:
            episode.site = self._choose_site(block)
            if episode.site is None:
                return None
        remaining = self._remaining()
        if not remaining:
            return self._stay_near()
        target, kind = remaining[0]
        if target in self.mobs:
            return "NOOP"  # creatures move on
        here = self.world.get(target)
        if here not in PLACE_GROUND[kind]:
            if self._ground_for(kind, target):
                return self.interact({target})  # mine the stone away first
            episode.site = None  # something else took the cell: choose again
            return None
        return self._place_at(target, PLACE_ACTION[kind])

    def _clear_of(self, block: str) -> str | None:
        """A step to the nearest cell with no known `block` within the official line check's
        window; standing on one, explore (the window's unseen cells may hold some)."""
        known = self.world.cells([block])

        def clear(cell: Cell) -> bool:
            return all(max(abs(cell[0] - b[0]), abs(cell[1] - b[1])) > _LINE_APART for b in known)

        if clear(self.pos):
            return None
        spots = {cell for cell in sorted(self.dist, key=self.dist.__getitem__)[:400] if clear(cell)}
        return self.step_towards(spots)

    def _stay_near(self) -> str:
        """Once a localization site is filled: a step to where both blocks are within the
        official check's 5 tiles (it reads them around the player)."""
        near = self.episode.near
        if not near:
            return "NOOP"

        def spread(cell: Cell) -> int:
            return max(max(abs(cell[0] - n[0]), abs(cell[1] - n[1])) for n in near)

        if spread(self.pos) <= _LOCAL_REACH:
            return "NOOP"
        spots = {cell for cell in self.dist if spread(cell) <= _LOCAL_REACH - 1}
        return self.step_towards(spots) or "NOOP"

    def _place_at(self, target: Cell, action: str) -> str | None:
        """`action` when facing `target`, else the way to stand beside it facing it: a move
        onto a free cell steps onto it, so the stand is entered from the cell behind it."""
        if self.facing_cell == target and self._steps_to(target) == 1:
            return action
        backs: set[Cell] = set()
        for name, step in MOVES.items():
            stand = (target[0] - step[0], target[1] - step[1])
            back = (stand[0] - step[0], stand[1] - step[1])
            free = self.world.get(stand) in WALKABLE and stand not in self.mobs
            if not free and stand != self.pos:
                continue
            if self.pos == back and free:
                return name
            if self.pos == stand:
                if self.world.get(back) in WALKABLE and back not in self.mobs:
                    return direction(self.pos, back)
                continue
            backs.add(back)
        return self.step_towards(backs)

    def _choose_site(self, block: str) -> dict[Cell, str] | None:
        """The nearest reachable cells for the goal's shape (or beside its reference block) on
        ground their blocks may go on, kept apart from other blocks of their kind (the official
        shape checks count every one of them nearby)."""
        goal = self.episode.goal
        kind = getattr(goal, "kind", "")
        plan = self._plan(block)
        if kind == "localization_placing" and len(plan) == 1:
            step = SIDE_STEP[str(getattr(goal, "side", "right"))]
            distance = int(getattr(goal, "distance", 1))
            offset = (step[0] * distance, step[1] * distance)
            pairs = [(add(t, offset), t) for t in self.world.cells([self._reference()])]
            free = [
                (spot, ref)
                for spot, ref in pairs
                if self._ground_for(block, spot) and any(n in self.dist for n in neighbours(spot))
            ]
            if not free:
                return None
            spot, ref = min(free, key=lambda pair: (self._steps_to(pair[0]), pair[0]))
            self.episode.near = [spot, ref]
            return {spot: block}
        # A line counts only when it is all of its kind within 10 cells of the player; a square
        # or star needs its border clear.
        apart = _LINE_APART if kind == "build_line" else 1
        existing = {
            name: [c for c in self.world.cells([name]) if self._steps_to(c) <= 2 * _LINE_APART]
            for name in {name for _, name in plan}
        }
        anchors = sorted(self.dist, key=lambda c: (self.dist[c], c))[:400]
        for anchor in anchors:
            cells = [(add(anchor, offset), name) for offset, name in plan]
            if any(self.world.get(c) not in PLACE_GROUND[n] or c in self.mobs for c, n in cells):
                continue
            crowded = any(
                max(abs(e[0] - c[0]), abs(e[1] - c[1])) <= apart
                for c, name in cells
                for e in existing[name]
            )
            if not crowded:
                if kind == "localization_placing":
                    self.episode.near = [c for c, _ in cells]
                return dict(cells)
        return None

    def _reference(self) -> str:
        return str(getattr(self.episode.goal, "target", "")).lower()

    def _plan(self, block: str) -> list[tuple[Cell, str]]:
        """The blocks the goal asks to place, relative to the first one."""
        goal = self.episode.goal
        kind = getattr(goal, "kind", "")
        if kind in ("build_line", "build_square", "build_star"):
            size = int(getattr(goal, "size", 1))
            diagonal = bool(getattr(goal, "diagonal", False))
            if kind == "build_line" and not diagonal and size == 2:
                # The official straight line of 2 looks for two empty cells and no such block
                # at all around the player: nothing to place, only somewhere clear of them.
                return []
            if kind == "build_line" and diagonal and size == 2:
                # The official diagonal line of 2 looks for exactly 3 such blocks around the
                # player (and two empty cells): a diagonal of 3 is that.
                size = 3
            offsets = shape_offsets(
                kind, size, diagonal=diagonal, cross=str(getattr(goal, "cross", "straight"))
            )
            return [(offset, block) for offset in offsets]
        if kind == "conditional_placing":
            # Spaced out, so every block is placed from open ground.
            count = int(getattr(goal, "place_count", 1))
            return [((2 * i, 0), block) for i in range(count - len(self.world.cells([block])))]
        reference = self._reference()
        step = SIDE_STEP[str(getattr(goal, "side", "right"))]
        distance = int(getattr(goal, "distance", 1))
        offset = (step[0] * distance, step[1] * distance)
        if reference == block or (reference in PLACE_ACTION and not self.world.cells([reference])):
            # No reference block to use (or one of its own kind): place the reference too.
            return [((0, 0), reference), (offset, block)]
        return [((0, 0), block)]

    def _remaining(self) -> list[tuple[Cell, str]]:
        """The site's cells not yet holding their block, in placing order."""
        site = self.episode.site or {}
        return [(cell, kind) for cell, kind in site.items() if self.world.get(cell) != kind]

    def _ground_for(self, kind: str, cell: Cell) -> bool:
        """Whether `kind` can go on `cell` now, or once its stone is mined away (not plants:
        mined stone leaves path, and plants need grass)."""
        if cell in self.mobs:
            return False
        here = self.world.get(cell)
        return here in PLACE_GROUND[kind] or (kind != "plant" and self.minable(here))

    def _face_ground(
        self, ground: frozenset[str] | set[str], action: str, keep_near_table: bool = False
    ) -> str | None:
        """`action` when facing a free cell of `ground`, else a move that ends facing one."""
        if self.obs.facing_block in ground and self.facing_cell not in self.mobs:
            return action
        options = []
        for name, step in MOVES.items():
            one, two = add(self.pos, step), add(self.pos, (2 * step[0], 2 * step[1]))
            if self.world.get(one) not in WALKABLE or one in self.mobs:
                continue
            if keep_near_table and not self._near(one, {"crafting_table"}):
                continue
            score = 0 if self.world.get(two) in ground else 1
            options.append((score, name))
        if options:
            return min(options)[1]
        # Walled in (a tunnel): clear a neighbouring block to make room.
        for name, step in MOVES.items():
            cell = add(self.pos, step)
            if self.minable(self.world.get(cell)) and action in _PLACED_ON_CLEARED:
                if self.facing_cell == cell:
                    return "DO"
                return name
        return None
