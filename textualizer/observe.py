"""craftax state (numpy leaves) -> `Observation`, exactly what the player can see.

Visibility follows craftax's own symbolic observation: the view is `OBS_DIM` tiles centred on
the player, tiles past the map edge read as `out_of_bounds`, and in full Craftax a tile (with
its items and mobs) is hidden when its light-map value is not above 0.05 (which is also the case
for every tile past the map edge). Mobs come from the state's mob arrays, never the observation
vector, which can lose a visible mob when an off-screen one is written over it.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from env.errors import UserError
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
    if np.ndim(state.player_position) != 1:
        raise UserError(
            "observe() takes one episode's state; use observe_batch() for a batched state "
            f"(player_position has shape {np.shape(state.player_position)})"
        )


def _window(grid: np.ndarray, row: int, col: int, view: _View, fill: float) -> np.ndarray:
    """The view-sized window of `grid` centred on (row, col), `fill` past the edges."""
    top, left = row - view.half_rows, col - view.half_cols
    bottom, right = row + view.half_rows + 1, col + view.half_cols + 1
    if top >= 0 and left >= 0 and bottom <= grid.shape[0] and right <= grid.shape[1]:
        # Away from the edges (nearly always) a plain slice does: fancy indexing costs 3x more.
        return grid[top:bottom, left:right]
    rows = row + view.row_offsets
    cols = col + view.col_offsets
    row_in = (rows >= 0) & (rows < grid.shape[0])
    col_in = (cols >= 0) & (cols < grid.shape[1])
    window = np.full((rows.size, cols.size), fill, dtype=grid.dtype)
    window[np.ix_(row_in, col_in)] = grid[np.ix_(rows[row_in], cols[col_in])]
    return window


def _group(
    values: list[int], names: tuple[str, ...], view: _View, skip: int | None
) -> dict[str, list[Offset]]:
    grouped: dict[str, list[Offset]] = {}
    for value, offset in zip(values, view.offsets, strict=True):
        if value != skip:
            grouped.setdefault(names[value], []).append(offset)
    return grouped


def _mobs_of(
    mobs: Any,
    names: tuple[str, ...],
    level: int | None,
    row: int,
    col: int,
    view: _View,
    lit: np.ndarray | None,
    with_health: bool,
) -> list[Mob]:
    """Visible mobs of one craftax `Mobs` group; `names` by type id (Classic groups have one)."""
    position = np.asarray(mobs.position)
    mask = np.asarray(mobs.mask)
    health = np.asarray(mobs.health)
    type_id = np.asarray(mobs.type_id) if hasattr(mobs, "type_id") else np.zeros_like(mask, int)
    if level is not None:
        position, mask, health, type_id = (
            position[level],
            mask[level],
            health[level],
            type_id[level],
        )
    found = []
    for index in np.flatnonzero(mask).tolist():
        dr = int(position[index, 0]) - row
        dc = int(position[index, 1]) - col
        if abs(dr) > view.half_rows or abs(dc) > view.half_cols:
            continue
        if lit is not None and not lit[dr + view.half_rows, dc + view.half_cols]:
            continue
        found.append(
            Mob(
                kind=names[int(type_id[index])],
                dx=dc,
                dy=-dr,
                health=round(float(health[index]), 2) if with_health else None,
            )
        )
    return found


def _nearest_first(mob: Mob) -> tuple[int, int, int]:
    return (abs(mob.dx) + abs(mob.dy), -mob.dy, mob.dx)


def _classic_inventory(inventory: Any) -> Inventory:
    materials = {
        name: int(getattr(inventory, name))
        for name in ("wood", "stone", "coal", "iron", "diamond", "sapling")
        if int(getattr(inventory, name)) > 0
    }
    tools = [
        f"{tier}_{tool}"
        for tool in ("pickaxe", "sword")
        for tier in ("iron", "stone", "wood")
        if int(getattr(inventory, f"{tier}_{tool}")) > 0
    ]
    return Inventory(materials=materials, tools=tools, enchantments={})


def _full_inventory(state: Any) -> Inventory:
    inventory = state.inventory
    counts = {
        "wood": inventory.wood,
        "stone": inventory.stone,
        "coal": inventory.coal,
        "iron": inventory.iron,
        "diamond": inventory.diamond,
        "sapphire": inventory.sapphire,
        "ruby": inventory.ruby,
        "sapling": inventory.sapling,
        "torch": inventory.torches,
        "arrow": inventory.arrows,
        "book": inventory.books,
    }
    potions = np.asarray(inventory.potions)
    for colour, count in zip(voc.POTION_COLOURS, potions.tolist(), strict=True):
        counts[f"{colour}_potion"] = count
    materials = {name: int(count) for name, count in counts.items() if int(count) > 0}
    tools: list[str] = []
    enchantments: dict[str, str] = {}
    pickaxe, sword, bow = int(inventory.pickaxe), int(inventory.sword), int(inventory.bow)
    if pickaxe > 0:
        tools.append(f"{voc.TIERS[pickaxe]}_pickaxe")
    if sword > 0:
        tools.append(f"{voc.TIERS[sword]}_sword")
        if int(state.sword_enchantment) > 0:
            enchantments["sword"] = voc.ENCHANTMENTS[int(state.sword_enchantment)]
    if bow > 0:
        tools.append("bow")
        if int(state.bow_enchantment) > 0:
            enchantments["bow"] = voc.ENCHANTMENTS[int(state.bow_enchantment)]
    armour = np.asarray(inventory.armour).tolist()
    armour_enchantments = np.asarray(state.armour_enchantments).tolist()
    for slot, tier, enchantment in zip(voc.ARMOUR_SLOTS, armour, armour_enchantments, strict=True):
        if tier > 0:
            tools.append(f"{voc.ARMOUR_TIERS[tier]}_{slot}")
            if enchantment > 0:
                enchantments[slot] = voc.ENCHANTMENTS[enchantment]
    return Inventory(materials=materials, tools=tools, enchantments=enchantments)


def observe(state: Any, variant: Variant | str) -> Observation:
    """The observation of one episode's craftax `EnvState` whose leaves are numpy arrays."""
    variant = as_variant(variant)
    _check_state(state, variant)
    view = _view(variant)
    full = variant is Variant.FULL
    level = int(state.player_level) if full else 0
    world = np.asarray(state.map)[level] if full else np.asarray(state.map)
    row, col = (int(v) for v in np.asarray(state.player_position))
    blocks_window = _window(world, row, col, view, voc.OUT_OF_BOUNDS)
    sight = (
        _sight(state, view, level, row, col, blocks_window)
        if full
        else _classic_sight(view, blocks_window)
    )
    direction = int(state.player_direction)
    player = _full_player(state, level) if full else _classic_player(state)
    daylight = round(float(state.light_level), 3)
    achieved = np.flatnonzero(np.asarray(state.achievements)).tolist()
    return Observation(
        variant=variant,
        step=int(state.timestep),
        position=Position(x=col, y=world.shape[0] - 1 - row),
        floor=player.floor,
        facing=voc.DIRECTION_NAMES[direction],
        facing_block=_facing_block(direction, blocks_window, view, sight.lit),
        vitals=player.vitals,
        attributes=player.attributes,
        sleeping=bool(state.is_sleeping),
        resting=bool(state.is_resting) if full else False,
        daylight=daylight,
        night=level == 0 and daylight < 0.5,
        inventory=player.inventory,
        spells=player.spells,
        achievements=[variant.achievement_names[i] for i in achieved],
        view_size=view.size,
        blocks=sight.blocks,
        items=sight.items,
        mobs=_mobs(state, full, level, row, col, view, sight.lit),
        unlit=sight.unlit,
    )


@dataclass
class _Sight:
    """What the view shows of the world."""

    lit: np.ndarray | None
    """Which tiles of the view are lit (full Craftax); None in Classic, where all are seen."""
    blocks: dict[str, list[Offset]]
    items: dict[str, list[Offset]]
    unlit: list[Offset]


def _classic_sight(view: _View, blocks_window: np.ndarray) -> _Sight:
    blocks = _group(blocks_window.ravel()[view.order].tolist(), voc.BLOCK_NAMES, view, skip=None)
    return _Sight(lit=None, blocks=blocks, items={}, unlit=[])


def _sight(
    state: Any, view: _View, level: int, row: int, col: int, blocks_window: np.ndarray
) -> _Sight:
    light = _window(np.asarray(state.light_map)[level], row, col, view, 0.0)
    lit = light > voc.LIGHT_THRESHOLD
    lit_in_order = lit.ravel()[view.order].tolist()
    unlit = [offset for offset, seen in zip(view.offsets, lit_in_order, strict=True) if not seen]
    hidden = -1
    block_values = np.where(lit, blocks_window, hidden).ravel()[view.order].tolist()
    item_window = _window(np.asarray(state.item_map)[level], row, col, view, 0)
    item_values = np.where(lit, item_window, 0).ravel()[view.order].tolist()
    return _Sight(
        lit=lit,
        blocks=_group(block_values, voc.BLOCK_NAMES, view, skip=hidden),
        items=_group(item_values, voc.ITEM_NAMES, view, skip=0),
        unlit=unlit,
    )


def _mobs(
    state: Any, full: bool, level: int, row: int, col: int, view: _View, lit: np.ndarray | None
) -> list[Mob]:
    if full:
        player_shots = tuple(f"player_{name}" for name in voc.PROJECTILE_NAMES)
        groups: tuple[tuple[Any, tuple[str, ...], bool], ...] = (
            (state.melee_mobs, voc.MELEE_MOB_NAMES, True),
            (state.passive_mobs, voc.PASSIVE_MOB_NAMES, True),
            (state.ranged_mobs, voc.RANGED_MOB_NAMES, True),
            (state.mob_projectiles, voc.PROJECTILE_NAMES, False),
            (state.player_projectiles, player_shots, False),
        )
    else:
        groups = (
            (state.zombies, ("zombie",), True),
            (state.cows, ("cow",), True),
            (state.skeletons, ("skeleton",), True),
            (state.arrows, ("arrow",), False),
        )
    mob_level = level if full else None
    mobs = [
        mob
        for group, names, with_health in groups
        for mob in _mobs_of(group, names, mob_level, row, col, view, lit, with_health)
    ]
    mobs.sort(key=_nearest_first)
    return mobs


def _facing_block(
    direction: int, blocks_window: np.ndarray, view: _View, lit: np.ndarray | None
) -> str | None:
    """The block the player faces; None when that tile is dark."""
    step_row, step_col = _ROW_COL_STEPS[direction]
    facing_row, facing_col = view.half_rows + step_row, view.half_cols + step_col
    if lit is not None and not lit[facing_row, facing_col]:
        return None
    return voc.BLOCK_NAMES[int(blocks_window[facing_row, facing_col])]


@dataclass
class _Player:
    """The player's own state, as the variant has it."""

    vitals: Vitals
    inventory: Inventory
    attributes: Attributes | None = None
    floor: Floor | None = None
    spells: list[str] = field(default_factory=list)


def _classic_player(state: Any) -> _Player:
    return _Player(
        vitals=_vitals(state, mana=None, max_health=9, max_food=9, max_mana=None),
        inventory=_classic_inventory(state.inventory),
    )


def _full_player(state: Any, level: int) -> _Player:
    strength, dexterity = int(state.player_strength), int(state.player_dexterity)
    intelligence = int(state.player_intelligence)
    learned = np.asarray(state.learned_spells).tolist()
    return _Player(
        vitals=_vitals(
            state,
            mana=int(state.player_mana),
            max_health=8 + strength,
            max_food=7 + 2 * dexterity,
            max_mana=6 + 3 * intelligence,
        ),
        inventory=_full_inventory(state),
        attributes=Attributes(
            xp=int(state.player_xp),
            dexterity=dexterity,
            strength=strength,
            intelligence=intelligence,
        ),
        floor=Floor(
            level=level,
            name=voc.FLOOR_NAMES[level],
            ladder_open=int(np.asarray(state.monsters_killed)[level])
            >= voc.MONSTERS_TO_OPEN_LADDER,
        ),
        spells=[name for name, known in zip(voc.SPELLS, learned, strict=True) if known],
    )


def _vitals(
    state: Any, mana: int | None, max_health: int, max_food: int, max_mana: int | None
) -> Vitals:
    return Vitals(
        health=round(float(state.player_health), 2),
        food=int(state.player_food),
        drink=int(state.player_drink),
        energy=int(state.player_energy),
        mana=mana,
        max_health=max_health,
        max_food=max_food,
        max_mana=max_mana,
        hunger=round(float(state.player_hunger), 2),
        thirst=round(float(state.player_thirst), 2),
        fatigue=round(float(state.player_fatigue), 2),
        recover=round(float(state.player_recover), 2),
    )


class _Leaves:
    """A batched state's fields, each looked up and made a numpy array once per batch (a
    nested group of fields becomes another `_Leaves`), shared by the batch's episode rows."""

    def __init__(self, batch: Any) -> None:
        self._batch = batch
        self._fields: dict[str, Any] = {}

    def field(self, name: str) -> Any:
        found = self._fields.get(name)
        if found is None:
            value = getattr(self._batch, name)
            if isinstance(value, np.ndarray) or hasattr(value, "__array__"):
                found = np.asarray(value)
            else:
                found = _Leaves(value)
            self._fields[name] = found
        return found


class _EpisodeRow:
    """One episode of a batched state: attribute access indexes the leading axis lazily."""

    def __init__(self, leaves: _Leaves, index: int) -> None:
        self._leaves = leaves
        self._index = index

    def __getattr__(self, name: str) -> Any:
        value = self._leaves.field(name)
        found: Any = (
            _EpisodeRow(value, self._index) if isinstance(value, _Leaves) else value[self._index]
        )
        # Kept, so that reading a field again (observe reads several twice) skips this lookup.
        setattr(self, name, found)
        return found


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
    chosen = range(shape[0]) if indices is None else indices
    leaves = _Leaves(states)
    return [observe(_EpisodeRow(leaves, i), variant) for i in chosen]
