"""The `table` style: the information of the official CrafText LLM baseline's observation.

For reproduction studies only. It keeps that baseline's choices: one line per cell of the view,
"<block> <dx>, <dy>" (its axes happen to be ours: +dx right, +dy up), the player's cell as
"agent 0, 0", a creature as an extra "mob <kind> on <dx>, <dy>" line before its cell, the whole
inventory including zeros, the hidden need counters, and the facing direction as craftax's
integer (1 left, 2 right, 3 up, 4 down). Full Craftax adds item lines and "unlit" cells.
"""

from textualizer import vocabulary as voc
from textualizer.geometry import number
from textualizer.observation import Observation

_DIRECTION_IDS = {name: value for value, name in voc.DIRECTION_NAMES.items()}
_CLASSIC_TOOLS = tuple(
    f"{tier}_{tool}" for tool in ("pickaxe", "sword") for tier in ("wood", "stone", "iron")
)


def _title(name: str) -> str:
    return name.replace("_", " ").title()


def _inventory_counts(obs: Observation) -> dict[str, int]:
    materials, tools = obs.inventory.materials, set(obs.inventory.tools)
    if obs.floor is None:
        counts = {
            n: materials.get(n, 0) for n in ("wood", "stone", "coal", "iron", "diamond", "sapling")
        }
        counts.update({tool: int(tool in tools) for tool in _CLASSIC_TOOLS})
        return counts
    counts = {
        n: materials.get(n, 0)
        for n in (
            "wood",
            "stone",
            "coal",
            "iron",
            "diamond",
            "sapphire",
            "ruby",
            "sapling",
            "torch",
            "arrow",
            "book",
        )
    }
    for tool in ("pickaxe", "sword"):
        counts[tool] = next(
            (voc.TIERS.index(t) for t in voc.TIERS[1:] if f"{t}_{tool}" in tools), 0
        )
    counts["bow"] = int("bow" in tools)
    for slot in voc.ARMOUR_SLOTS:
        counts[slot] = next(
            (voc.ARMOUR_TIERS.index(t) for t in voc.ARMOUR_TIERS[1:] if f"{t}_{slot}" in tools), 0
        )
    counts.update(
        {f"{colour}_potion": materials.get(f"{colour}_potion", 0) for colour in voc.POTION_COLOURS}
    )
    return counts


def render_table(obs: Observation) -> str:
    """Cell lines row by row from the top-left, then inventory, status and light."""
    columns, rows = obs.view_size
    half_x, half_y = columns // 2, rows // 2
    cells: dict[tuple[int, int], str] = dict.fromkeys(obs.unlit, "unlit")
    for name, offsets in obs.blocks.items():
        for offset in offsets:
            cells[offset] = name
    extras: dict[tuple[int, int], list[str]] = {}
    for name, offsets in obs.items.items():
        for offset in offsets:
            extras.setdefault(offset, []).append(f"item {name} on")
    for mob in obs.mobs:
        extras.setdefault((mob.dx, mob.dy), []).append(f"mob {mob.kind} on")
    lines = ["Map:"]
    for dy in range(half_y, -half_y - 1, -1):
        for dx in range(-half_x, half_x + 1):
            lines += [f"{extra} {dx}, {dy}" for extra in extras.get((dx, dy), [])]
            lines.append(f"{'agent' if (dx, dy) == (0, 0) else cells[(dx, dy)]} {dx}, {dy}")
    counts = _inventory_counts(obs)
    lines.append("Inventory: " + " ".join(f"{_title(n)}: {c};" for n, c in counts.items()))
    vitals = obs.vitals
    status = [
        f"Health: {number(vitals.health)}",
        f"Food: {vitals.food}",
        f"Drink: {vitals.drink}",
        f"Energy: {vitals.energy}",
    ]
    if vitals.mana is not None:
        status.append(f"Mana: {vitals.mana}")
    status += [
        f"Sleeping: {obs.sleeping}",
        f"Recover: {vitals.recover:.2f}",
        f"Hunger: {vitals.hunger:.2f}",
        f"Thirst: {vitals.thirst:.2f}",
        f"Fatigue: {vitals.fatigue:.2f}",
        f"Direction: {_DIRECTION_IDS[obs.facing]}",
    ]
    if obs.floor is not None:
        status.append(f"Floor: {obs.floor.level}")
    lines.append("Player Status: " + " ".join(f"{s};" for s in status))
    lines.append(f"Light Level: {obs.daylight:.2f};")
    return "\n".join(lines)
