"""The `objects` style: a compact list of what is in view, per kind, nearest first.

Every visible non-background block, item and mob is given with its exact offset; the nearest of
each kind also gets its step distance and compass word. Background floor (see
`vocabulary.BACKGROUND_BLOCKS`) is left out, and tiles past the map edge are summarised as one
"map edge" line.
"""

from collections import Counter
from functools import lru_cache

from textualizer import vocabulary as voc
from textualizer.geometry import compass, format_offset, number, signed, steps
from textualizer.observation import Mob, Observation, Offset

MAX_LISTED = 6
"""Kinds with more tiles than this are given as runs per row instead of one offset each."""

_EDGE_DIRECTIONS: tuple[tuple[str, Offset], ...] = (
    ("left", (-1, 0)),
    ("right", (1, 0)),
    ("up", (0, 1)),
    ("down", (0, -1)),
)


# An offset's words depend on it alone, and a view has at most 99 offsets: each is worded once,
# not at every step (about 2 us of the 23 an observation took to render).
@lru_cache(maxsize=256)
def _annotated(offset: Offset) -> str:
    return f"{format_offset(offset)} {steps(offset)} {compass(offset)}"


_offset_text = lru_cache(maxsize=256)(format_offset)


def _runs(values: list[int]) -> str:
    """`-5..-1, 3, 5..6` for sorted integers."""
    if not values:
        return ""
    parts: list[str] = []
    low = high = values[0]
    for value in values[1:]:
        if value == high + 1:
            high = value
            continue
        parts.append(f"{low}..{high}" if high > low else f"{low}")
        low = high = value
    parts.append(f"{low}..{high}" if high > low else f"{low}")
    return ", ".join(parts)


def _offsets_line(name: str, offsets: list[Offset]) -> str:
    first, *rest = offsets
    if len(offsets) <= MAX_LISTED:
        return f"{name}: " + "; ".join([_annotated(first), *map(_offset_text, rest)])
    # Many tiles of one kind (a cave wall, a lake) read shorter as runs along each row, top row
    # first. Grouped by row before sorting: sorting every tile by a key function cost more
    # than the rest of the line.
    rows: dict[int, list[int]] = {}
    for dx, dy in offsets:
        row = rows.get(dy)
        if row is None:
            rows[dy] = [dx]
        else:
            row.append(dx)
    runs = "; ".join(f"dy {dy}: dx {_runs(sorted(rows[dy]))}" for dy in sorted(rows, reverse=True))
    return f"{name} ({len(offsets)} tiles): nearest {_annotated(first)}; rows {runs}"


def _mob_text(mob: Mob) -> str:
    health = "" if mob.health is None else f" hp {number(mob.health)}"
    return _annotated((mob.dx, mob.dy)) + health


def _mob_lines(mobs: list[Mob]) -> list[str]:
    by_kind: dict[str, list[Mob]] = {}
    for mob in mobs:
        by_kind.setdefault(mob.kind, []).append(mob)
    return [f"{kind}: " + "; ".join(map(_mob_text, group)) for kind, group in by_kind.items()]


def _map_edge(edge_tiles: list[Offset]) -> str | None:
    tiles = set(edge_tiles)
    parts = []
    for word, (step_x, step_y) in _EDGE_DIRECTIONS:
        # The player's own row and column are inside the map, so the first out-of-bounds tile
        # along them marks where the world ends in that direction.
        for distance in range(1, 6):
            if (step_x * distance, step_y * distance) in tiles:
                axis = "dx" if step_x else "dy"
                parts.append(f"{word} from {axis}={signed(step_x * distance + step_y * distance)}")
                break
    return "map edge: " + ", ".join(parts) if parts else None


def _unlit_summary(obs: Observation) -> str:
    sectors = Counter(compass(offset) for offset in obs.unlit)
    total = obs.view_size[0] * obs.view_size[1]
    spread = ", ".join(f"{sector} {count}" for sector, count in sectors.most_common())
    return f"unlit (unknown) tiles: {len(obs.unlit)} of {total} ({spread})"


def _status_lines(obs: Observation) -> list[str]:
    where = f"You: at x={obs.position.x} y={obs.position.y}"
    if obs.floor is not None:
        ladder = "open" if obs.floor.ladder_open else "closed"
        where += f", floor {obs.floor.level} ({obs.floor.name}, ladder down {ladder})"
    faced = voc.FACING_OFFSETS[obs.facing]
    facing_mob = next((m.kind for m in obs.mobs if (m.dx, m.dy) == faced), None)
    target = obs.facing_block or "unlit tile"
    if facing_mob is not None:
        target = f"{facing_mob} on {target}"
    lines = [f"{where}; facing {obs.facing}: {target}."]
    vitals = obs.vitals
    needs = (
        f"Health {number(vitals.health)}/{vitals.max_health}, food {vitals.food}/{vitals.max_food}, "
        f"drink {vitals.drink}/{vitals.max_food}, energy {vitals.energy}/{vitals.max_food}"
    )
    if vitals.mana is not None:
        needs += f", mana {vitals.mana}/{vitals.max_mana}"
    if obs.sleeping:
        needs += "; sleeping"
    if obs.resting:
        needs += "; resting"
    if obs.floor is None or obs.floor.level == 0:
        needs += f"; {'night' if obs.night else 'day'} (light {obs.daylight:.2f})"
    lines.append(needs + ".")
    if obs.attributes is not None:
        attrs = obs.attributes
        lines.append(
            f"XP {attrs.xp}; dexterity {attrs.dexterity}, strength {attrs.strength}, "
            f"intelligence {attrs.intelligence}"
            + (f"; spells: {', '.join(obs.spells)}" if obs.spells else "")
            + "."
        )
    inventory = obs.inventory
    carried = (
        ", ".join(f"{name} {count}" for name, count in inventory.materials.items()) or "nothing"
    )
    tools = [
        f"{tool} ({inventory.enchantments[tool.rsplit('_', 1)[-1]]})"
        if tool.rsplit("_", 1)[-1] in inventory.enchantments
        else tool
        for tool in inventory.tools
    ]
    lines.append(f"Inventory: {carried}; tools: {', '.join(tools) or 'none'}.")
    return lines


def render_objects(obs: Observation) -> str:
    """Status, inventory, then every visible non-background thing with its offset."""
    background = voc.BACKGROUND_BLOCKS[obs.variant]
    lines = _status_lines(obs)
    columns, rows = obs.view_size
    hidden = [name for name in obs.blocks if name in background]
    lines.append(
        f"In view ({columns}x{rows}, offsets (dx,dy): dx right, dy up"
        + (f"; {', '.join(hidden)} not listed" if hidden else "")
        + "):"
    )
    things = [
        _offsets_line(name, offsets)
        for name, offsets in obs.blocks.items()
        if name not in background and name != "out_of_bounds"
    ]
    things += [_offsets_line(name, offsets) for name, offsets in obs.items.items()]
    things += _mob_lines(obs.mobs)
    edge = _map_edge(obs.blocks.get("out_of_bounds", []))
    if edge is not None:
        things.append(edge)
    if obs.unlit:
        things.append(_unlit_summary(obs))
    lines += things or ["only background"]
    if obs.achievements:
        lines.append(f"Achieved so far: {', '.join(obs.achievements)}.")
    return "\n".join(lines)
