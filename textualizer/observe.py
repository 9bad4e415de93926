"""craftax state (numpy leaves) -> `Observation`, exactly what the player can see.

Visibility follows craftax's own symbolic observation: the view is `OBS_DIM` tiles centred on
the player, tiles past the map edge read as `out_of_bounds`, and in full Craftax a tile (with
its items and mobs) is hidden when its light-map value is not above 0.05 (which is also the case
for every tile past the map edge). Mobs come from the state's mob arrays, never the observation
vector, which can lose a visible mob when an off-screen one is written over it.

A batch is read a field at a time: each leaf is indexed for every chosen episode at once and
turned into Python values in one `tolist`, views are gathered for the whole batch with one fancy
index per map, and only the grouping of the view's cells by name runs per episode. The typed
records are built unvalidated (`env.trusted`): every value is a plain Python value of the
field's type made here, so validating it again would only cost time (the tests compare them
with validated ones).
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from env.errors import UserError
from env.trusted import trusted
from env.variant import Variant, as_variant
from textualizer import vocabulary as voc
from textualizer.observation import (
    Attributes,
    Floor,
    Inventory,
    Mob,
    Observation,
    Offset,
    Position,
    Vitals,
)

_ROW_COL_STEPS: dict[int, tuple[int, int]] = {1: (0, -1), 2: (0, 1), 3: (-1, 0), 4: (1, 0)}
"""`player_direction` -> (row, col) step, as craftax `DIRECTIONS`."""

_FULL_MATERIALS: tuple[tuple[str, str], ...] = (
    ("wood", "wood"),
    ("stone", "stone"),
    ("coal", "coal"),
    ("iron", "iron"),
    ("diamond", "diamond"),
    ("sapphire", "sapphire"),
    ("ruby", "ruby"),
    ("sapling", "sapling"),
    ("torch", "torches"),
    ("arrow", "arrows"),
    ("book", "books"),
)
"""Full Craftax inventory: (name shown, craftax field), in the order they are listed."""
_CLASSIC_MATERIALS = ("wood", "stone", "coal", "iron", "diamond", "sapling")
_CLASSIC_TOOLS = tuple(
    f"{tier}_{tool}" for tool in ("pickaxe", "sword") for tier in ("iron", "stone", "wood")
)


class _View:
    """Per-variant constants of the local view, computed once."""

    def __init__(self, variant: Variant) -> None:
        rows, cols = voc.VIEW_SHAPE[variant]
        self.half_rows, self.half_cols = rows // 2, cols // 2
        self.row_offsets = np.arange(-self.half_rows, self.half_rows + 1)
        self.col_offsets = np.arange(-self.half_cols, self.half_cols + 1)
        cells = [(r, c) for r in self.row_offsets.tolist() for c in self.col_offsets.tolist()]
        # Nearest first; ties go to upper rows, then left to right, so text is stable.
        order = sorted(
            range(len(cells)), key=lambda i: (abs(cells[i][0]) + abs(cells[i][1]), *cells[i])
        )
        self.order = np.array(order)
        self.offsets: list[Offset] = [(cells[i][1], -cells[i][0]) for i in order]
        # The same offsets as an array of tuples, so that picking some is one numpy index.
        self.offset_array = np.empty(len(self.offsets), object)
        self.offset_array[:] = self.offsets
        self.size = (cols, rows)


@cache
def _view(variant: Variant) -> _View:
    return _View(variant)


def _check_state(state: Any, variant: Variant) -> None:
    is_full = hasattr(state, "player_level")
    is_classic = hasattr(state, "zombies")
    if not (is_full or is_classic):
        raise UserError(f"expected a craftax EnvState, got {type(state).__name__}")
    if is_full != (variant is Variant.FULL):
        kind = "full Craftax" if is_full else "Craftax-Classic"
        raise UserError(f"state is a {kind} state but variant is {variant.value!r}")


class _Leaves:
    """A state's fields as numpy arrays with a leading episode axis, each looked up once (a
    nested group of fields is another `_Leaves`); `single` gives one episode's state that axis."""

    def __init__(self, state: Any, single: bool = False) -> None:
        self._state = state
        self._single = single
        self._fields: dict[str, Any] = {}

    def has(self, name: str) -> bool:
        return hasattr(self._state, name)

    def __getitem__(self, name: str) -> Any:
        found = self._fields.get(name)
        if found is None:
            value = getattr(self._state, name)
            if isinstance(value, int | float | np.generic) or hasattr(value, "__array__"):
                found = np.asarray(value)
                if self._single:
                    found = found[None]
            else:
                found = _Leaves(value, self._single)
            self._fields[name] = found
        return found


def observe(state: Any, variant: Variant | str) -> Observation:
    """The observation of one episode's craftax `EnvState` whose leaves are numpy arrays."""
    variant = as_variant(variant)
    _check_state(state, variant)
    if np.ndim(state.player_position) != 1:
        raise UserError(
            "observe() takes one episode's state; use observe_batch() for a batched state "
            f"(player_position has shape {np.shape(state.player_position)})"
        )
    return _Batch(_Leaves(state, single=True), variant, np.zeros(1, np.intp)).observations()[0]


def observe_batch(
    states: Any, variant: Variant | str, indices: Sequence[int] | None = None
) -> list[Observation]:
    """One observation per episode of a craftax `EnvState` with a leading episode axis
    (only the episodes at `indices`, in that order, when given)."""
    variant = as_variant(variant)
    shape = np.shape(getattr(states, "player_position", ()))
    if len(shape) != 2:
        raise UserError(
            f"observe_batch() takes a batched state (player_position of shape (N, 2)), got shape {shape}"
        )
    _check_state(states, variant)
    rows = np.arange(shape[0]) if indices is None else np.asarray(indices, np.intp)
    if not len(rows):
        return []
    return _Batch(_Leaves(states), variant, rows).observations()


_Sight = tuple[dict[str, list[Offset]], dict[str, list[Offset]], list[Offset]]
"""What the view shows: blocks and items by name, and the unlit tiles."""


@dataclass
class _Player:
    """The player's own state, as the variant has it."""

    vitals: Vitals
    inventory: Inventory
    attributes: Attributes | None = None
    floor: Floor | None = None
    spells: list[str] = field(default_factory=list)


class _Batch:
    """The chosen episodes of a batch, read a field at a time (see the module)."""

    def __init__(self, leaves: _Leaves, variant: Variant, rows: np.ndarray) -> None:
        self.leaves = leaves
        self.variant = variant
        self.full = variant is Variant.FULL
        self.view = _view(variant)
        self.rows = rows
        self.count = len(rows)
        position = leaves["player_position"][rows]
        self.row, self.col = position[:, 0], position[:, 1]
        self.level = (
            leaves["player_level"][rows].astype(np.intp)
            if self.full
            else np.zeros(self.count, np.intp)
        )
        view = self.view
        world = leaves["map"]
        self.height, width = world.shape[-2:]
        rows_seen = self.row[:, None] + view.row_offsets
        cols_seen = self.col[:, None] + view.col_offsets
        self._inside = ((rows_seen >= 0) & (rows_seen < self.height))[:, :, None] & (
            (cols_seen >= 0) & (cols_seen < width)
        )[:, None, :]
        self._cell_rows = np.clip(rows_seen, 0, self.height - 1)[:, :, None]
        self._cell_cols = np.clip(cols_seen, 0, width - 1)[:, None, :]

    def values(self, name: str, group: _Leaves | None = None) -> list[Any]:
        """A field of every chosen episode, as Python values."""
        return (group or self.leaves)[name][self.rows].tolist()

    def window(self, grid: np.ndarray, fill: float) -> np.ndarray:
        """Each episode's view-sized window of `grid` (one map per level in full Craftax)
        centred on its player, `fill` past the map's edges: (episodes, rows, columns)."""
        episodes = self.rows[:, None, None]
        if self.full:
            cells = grid[episodes, self.level[:, None, None], self._cell_rows, self._cell_cols]
        else:
            cells = grid[episodes, self._cell_rows, self._cell_cols]
        return np.where(self._inside, cells, np.asarray(fill, grid.dtype))

    def observations(self) -> list[Observation]:
        variant, view, full = self.variant, self.view, self.full
        blocks_window = self.window(self.leaves["map"], voc.OUT_OF_BOUNDS)
        if full:
            lit = self.window(self.leaves["light_map"], 0.0) > voc.LIGHT_THRESHOLD
            sights = self._sights(blocks_window, lit)
        else:
            lit = None
            sights = self._classic_sights(blocks_window)
        directions = self.values("player_direction")
        facing = self._facing_blocks(directions, blocks_window, lit)
        players = self._full_players() if full else self._classic_players()
        mobs = self._mobs(lit)
        steps = self.values("timestep")
        daylight = [round(float(value), 3) for value in self.values("light_level")]
        sleeping = self.values("is_sleeping")
        resting = self.values("is_resting") if full else [False] * self.count
        achievements = self._achievements()
        levels = self.level.tolist()
        rows, cols = self.row.tolist(), self.col.tolist()
        top = self.height - 1
        return [
            trusted(
                Observation,
                variant=variant,
                step=int(steps[i]),
                position=trusted(Position, x=cols[i], y=top - rows[i]),
                floor=players[i].floor,
                facing=voc.DIRECTION_NAMES[directions[i]],
                facing_block=facing[i],
                vitals=players[i].vitals,
                attributes=players[i].attributes,
                sleeping=bool(sleeping[i]),
                resting=bool(resting[i]),
                daylight=daylight[i],
                night=levels[i] == 0 and daylight[i] < 0.5,
                inventory=players[i].inventory,
                spells=players[i].spells,
                achievements=achievements[i],
                view_size=view.size,
                blocks=sights[i][0],
                items=sights[i][1],
                mobs=mobs[i],
                unlit=sights[i][2],
            )
            for i in range(self.count)
        ]

    def _sights(self, blocks_window: np.ndarray, lit: np.ndarray) -> list[_Sight]:
        """Per episode: visible blocks and items by name, and the unlit tiles."""
        view, count = self.view, self.count
        hidden = -1
        in_order = lit.reshape(count, -1)[:, view.order]
        blocks = np.where(lit, blocks_window, hidden).reshape(count, -1)[:, view.order]
        items_window = self.window(self.leaves["item_map"], 0)
        items = np.where(lit, items_window, 0).reshape(count, -1)[:, view.order]
        unlit = [view.offset_array[~seen].tolist() for seen in in_order]
        return list(
            zip(
                _grouped(blocks, voc.BLOCK_NAMES, view, hidden),
                _grouped(items, voc.ITEM_NAMES, view, 0),
                unlit,
                strict=True,
            )
        )

    def _classic_sights(self, blocks_window: np.ndarray) -> list[_Sight]:
        view = self.view
        blocks = blocks_window.reshape(self.count, -1)[:, view.order]
        return [(grouped, {}, []) for grouped in _grouped(blocks, voc.BLOCK_NAMES, view, None)]

    def _facing_blocks(
        self, directions: list[int], blocks_window: np.ndarray, lit: np.ndarray | None
    ) -> list[str | None]:
        """The block each player faces; None when that tile is dark."""
        view = self.view
        steps = [_ROW_COL_STEPS[direction] for direction in directions]
        cells = (
            np.arange(self.count),
            np.array([view.half_rows + step_row for step_row, _ in steps], np.intp),
            np.array([view.half_cols + step_col for _, step_col in steps], np.intp),
        )
        faced = blocks_window[cells].tolist()
        seen = [True] * self.count if lit is None else lit[cells].tolist()
        return [
            voc.BLOCK_NAMES[block] if visible else None
            for block, visible in zip(faced, seen, strict=True)
        ]

    def _achievements(self) -> list[list[str]]:
        names = self.variant.achievement_names
        found: list[list[str]] = [[] for _ in range(self.count)]
        episodes, ids = np.nonzero(self.leaves["achievements"][self.rows])
        for episode, achievement in zip(episodes.tolist(), ids.tolist(), strict=True):
            found[episode].append(names[achievement])
        return found

    def _mobs(self, lit: np.ndarray | None) -> list[list[Mob]]:
        """Each episode's visible mobs, nearest first."""
        if self.full:
            player_shots = tuple(f"player_{name}" for name in voc.PROJECTILE_NAMES)
            groups: tuple[tuple[str, tuple[str, ...], bool], ...] = (
                ("melee_mobs", voc.MELEE_MOB_NAMES, True),
                ("passive_mobs", voc.PASSIVE_MOB_NAMES, True),
                ("ranged_mobs", voc.RANGED_MOB_NAMES, True),
                ("mob_projectiles", voc.PROJECTILE_NAMES, False),
                ("player_projectiles", player_shots, False),
            )
        else:
            groups = (
                ("zombies", ("zombie",), True),
                ("cows", ("cow",), True),
                ("skeletons", ("skeleton",), True),
                ("arrows", ("arrow",), False),
            )
        found: list[list[Mob]] = [[] for _ in range(self.count)]
        for name, names, with_health in groups:
            self._add_mobs(found, self.leaves[name], names, with_health, lit)
        for mobs in found:
            mobs.sort(key=_nearest_first)
        return found

    def _on_level(self, leaf: np.ndarray) -> np.ndarray:
        """Each chosen episode's row of a per-level leaf (full Craftax), or its row (Classic)."""
        return leaf[self.rows, self.level] if self.full else leaf[self.rows]

    def _add_mobs(
        self,
        found: list[list[Mob]],
        group: _Leaves,
        names: tuple[str, ...],
        with_health: bool,
        lit: np.ndarray | None,
    ) -> None:
        """Append the visible mobs of one craftax `Mobs` group, in index order, to each
        episode's list; `names` by type id (Classic groups have one)."""
        view = self.view
        mask = self._on_level(group["mask"])
        if not mask.any():
            return
        position = self._on_level(group["position"])
        rows_apart = position[..., 0] - self.row[:, None]
        cols_apart = position[..., 1] - self.col[:, None]
        seen = (
            mask & (np.abs(rows_apart) <= view.half_rows) & (np.abs(cols_apart) <= view.half_cols)
        )
        if lit is not None:
            seen &= lit[
                np.arange(self.count)[:, None],
                np.clip(rows_apart + view.half_rows, 0, 2 * view.half_rows),
                np.clip(cols_apart + view.half_cols, 0, 2 * view.half_cols),
            ]
        episodes, indices = np.nonzero(seen)
        if not len(episodes):
            return
        kinds = (
            self._on_level(group["type_id"])[episodes, indices].tolist()
            if group.has("type_id")
            else [0] * len(episodes)
        )
        health = self._on_level(group["health"])[episodes, indices].tolist()
        dy = (-rows_apart[episodes, indices]).tolist()
        dx = cols_apart[episodes, indices].tolist()
        for k, episode in enumerate(episodes.tolist()):
            found[episode].append(
                trusted(
                    Mob,
                    kind=names[int(kinds[k])],
                    dx=int(dx[k]),
                    dy=int(dy[k]),
                    health=round(float(health[k]), 2) if with_health else None,
                )
            )

    def _vitals(
        self,
        mana: list[int] | None,
        max_health: list[int],
        max_food: list[int],
        max_mana: list[int] | None,
    ) -> list[Vitals]:
        values = self.values
        health, food, drink = values("player_health"), values("player_food"), values("player_drink")
        energy, hunger = values("player_energy"), values("player_hunger")
        thirst, fatigue = values("player_thirst"), values("player_fatigue")
        recover = values("player_recover")
        return [
            trusted(
                Vitals,
                health=round(float(health[i]), 2),
                food=int(food[i]),
                drink=int(drink[i]),
                energy=int(energy[i]),
                mana=None if mana is None else mana[i],
                max_health=max_health[i],
                max_food=max_food[i],
                max_mana=None if max_mana is None else max_mana[i],
                hunger=round(float(hunger[i]), 2),
                thirst=round(float(thirst[i]), 2),
                fatigue=round(float(fatigue[i]), 2),
                recover=round(float(recover[i]), 2),
            )
            for i in range(self.count)
        ]

    def _classic_players(self) -> list[_Player]:
        inventory = self.leaves["inventory"]
        materials = [(name, self.values(name, inventory)) for name in _CLASSIC_MATERIALS]
        tools = [(name, self.values(name, inventory)) for name in _CLASSIC_TOOLS]
        vitals = self._vitals(None, [9] * self.count, [9] * self.count, None)
        return [
            _Player(
                vitals=vitals[i],
                inventory=trusted(
                    Inventory,
                    materials={
                        name: int(counts[i]) for name, counts in materials if int(counts[i]) > 0
                    },
                    tools=[name for name, held in tools if int(held[i]) > 0],
                    enchantments={},
                ),
            )
            for i in range(self.count)
        ]

    def _full_players(self) -> list[_Player]:
        values = self.values
        strength = [int(v) for v in values("player_strength")]
        dexterity = [int(v) for v in values("player_dexterity")]
        intelligence = [int(v) for v in values("player_intelligence")]
        mana, xp = values("player_mana"), values("player_xp")
        learned = values("learned_spells")
        killed = self._on_level(self.leaves["monsters_killed"]).tolist()
        vitals = self._vitals(
            [int(v) for v in mana],
            [8 + v for v in strength],
            [7 + 2 * v for v in dexterity],
            [6 + 3 * v for v in intelligence],
        )
        inventories = self._full_inventories()
        levels = self.level.tolist()
        return [
            _Player(
                vitals=vitals[i],
                inventory=inventories[i],
                attributes=trusted(
                    Attributes,
                    xp=int(xp[i]),
                    dexterity=dexterity[i],
                    strength=strength[i],
                    intelligence=intelligence[i],
                ),
                floor=trusted(
                    Floor,
                    level=levels[i],
                    name=voc.FLOOR_NAMES[levels[i]],
                    ladder_open=int(killed[i]) >= voc.MONSTERS_TO_OPEN_LADDER,
                ),
                spells=[name for name, known in zip(voc.SPELLS, learned[i], strict=True) if known],
            )
            for i in range(self.count)
        ]

    def _full_inventories(self) -> list[Inventory]:
        inventory, values = self.leaves["inventory"], self.values
        materials = [(name, values(field, inventory)) for name, field in _FULL_MATERIALS]
        potions = values("potions", inventory)
        pickaxe, sword, bow = (values(name, inventory) for name in ("pickaxe", "sword", "bow"))
        sword_enchantment, bow_enchantment = (
            values("sword_enchantment"),
            values("bow_enchantment"),
        )
        armour, armour_enchantments = values("armour", inventory), values("armour_enchantments")
        found = []
        for i in range(self.count):
            counts = {name: int(column[i]) for name, column in materials}
            for colour, count in zip(voc.POTION_COLOURS, potions[i], strict=True):
                counts[f"{colour}_potion"] = int(count)
            tools: list[str] = []
            enchantments: dict[str, str] = {}
            if pickaxe[i] > 0:
                tools.append(f"{voc.TIERS[int(pickaxe[i])]}_pickaxe")
            if sword[i] > 0:
                tools.append(f"{voc.TIERS[int(sword[i])]}_sword")
                if sword_enchantment[i] > 0:
                    enchantments["sword"] = voc.ENCHANTMENTS[int(sword_enchantment[i])]
            if bow[i] > 0:
                tools.append("bow")
                if bow_enchantment[i] > 0:
                    enchantments["bow"] = voc.ENCHANTMENTS[int(bow_enchantment[i])]
            for slot, tier, enchantment in zip(
                voc.ARMOUR_SLOTS, armour[i], armour_enchantments[i], strict=True
            ):
                if tier > 0:
                    tools.append(f"{voc.ARMOUR_TIERS[tier]}_{slot}")
                    if enchantment > 0:
                        enchantments[slot] = voc.ENCHANTMENTS[enchantment]
            found.append(
                trusted(
                    Inventory,
                    materials={name: count for name, count in counts.items() if count > 0},
                    tools=tools,
                    enchantments=enchantments,
                )
            )
        return found


def _grouped(
    values: np.ndarray, names: tuple[str, ...], view: _View, skip: int | None
) -> list[dict[str, list[Offset]]]:
    """Per episode (a row of `values`, the view's cells in view order): the cells' offsets by
    the name of their value, names in the order they first appear, offsets in view order
    (`skip`: a value left out).

    The whole batch is sorted by value at once (stably, so each group keeps view order); then
    each group is one slice of the episode's offsets in that order.
    """
    count, cells = values.shape
    order = np.argsort(values, axis=1, kind="stable")
    ordered = np.take_along_axis(values, order, axis=1)
    starts_group = np.ones((count, cells), bool)
    starts_group[:, 1:] = ordered[:, 1:] != ordered[:, :-1]
    episodes, starts = np.nonzero(starts_group)
    # A group ends where the next starts, or at its episode's last cell.
    ends = np.append(starts[1:], cells)
    ends[np.append(episodes[1:], -1) != episodes] = cells
    # Groups by episode, then by the first cell they hold: the order the names first appear.
    by_appearance = np.lexsort((order[episodes, starts], episodes))
    offsets = view.offset_array[order].tolist()
    group_values = ordered[episodes, starts]
    found: list[dict[str, list[Offset]]] = [{} for _ in range(count)]
    for episode, start, end, value in zip(
        episodes[by_appearance].tolist(),
        starts[by_appearance].tolist(),
        ends[by_appearance].tolist(),
        group_values[by_appearance].tolist(),
        strict=True,
    ):
        if value != skip:
            found[episode][names[value]] = offsets[episode][start:end]
    return found


def _nearest_first(mob: Mob) -> tuple[int, int, int]:
    return (abs(mob.dx) + abs(mob.dy), -mob.dy, mob.dx)
