"""The typed observation the agent sees: everything a player can see, nothing it cannot.

Coordinate convention (used by every field and every renderer):

- An offset `(dx, dy)` is relative to the player: `+dx` = right (east, the `RIGHT` action),
  `+dy` = up (north, the `UP` action). `(+1, 0)` is the tile one step right of the player,
  `(0, -2)` the tile two steps down. Moving `UP` once adds 1 to the player's `y` and so
  subtracts 1 from the `dy` of every fixed block.
- A world position `(x, y)` uses the same axes: `x` = column counted from the west (left) map
  edge, `y` = row counted from the south (bottom) map edge, both from 0. The offset of a thing
  is its position minus the player's.
- craftax stores positions as `(row, col)` with rows growing downwards; the textualizer
  converts once, here, so nothing else needs to know.
"""

from typing import Literal

from pydantic import BaseModel, ConfigDict

from env.variant import Variant

Offset = tuple[int, int]
Direction = Literal["left", "right", "up", "down"]


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, use_attribute_docstrings=True, extra="forbid")


class Position(_Model):
    """A world position; see the module docstring for the axes."""

    x: int
    """Column, 0 at the left (west) edge of the map."""
    y: int
    """Row, 0 at the bottom (south) edge of the map."""


class Vitals(_Model):
    """The player's needs; the agent diffs these between steps ("health -2")."""

    health: float
    """Health points (full Craftax keeps fractions; Classic is whole)."""
    food: int
    """Food points; 0 drains health."""
    drink: int
    """Drink points; 0 drains health."""
    energy: int
    """Energy points; 0 drains health; sleeping restores it."""
    mana: int | None
    """Mana points (full Craftax only, else None)."""
    max_health: int
    """Cap of `health` (9 in Classic; 8 + strength in full Craftax)."""
    max_food: int
    """Cap of `food`, `drink` and `energy` (9 in Classic; 7 + 2 * dexterity in full Craftax)."""
    max_mana: int | None
    """Cap of `mana` (full Craftax: 6 + 3 * intelligence), else None."""
    hunger: float
    """Counter that costs 1 food when it passes a threshold (craftax `player_hunger`)."""
    thirst: float
    """Counter that costs 1 drink when it passes a threshold (craftax `player_thirst`)."""
    fatigue: float
    """Counter that costs 1 energy when it passes a threshold (craftax `player_fatigue`)."""
    recover: float
    """Counter that heals 1 health when it passes a threshold (craftax `player_recover`)."""


class Attributes(_Model):
    """Full Craftax character attributes (raised with the LEVEL_UP_* actions)."""

    xp: int
    """Unspent experience points."""
    dexterity: int
    """Raises the food/drink/energy caps and slows their decay."""
    strength: int
    """Raises the health cap and melee damage."""
    intelligence: int
    """Raises the mana cap and spell damage."""


class Inventory(_Model):
    """What the player carries; zero counts are left out."""

    materials: dict[str, int]
    """Countable items with a non-zero count, e.g. {"wood": 3, "sapling": 1, "red_potion": 2}."""
    tools: list[str]
    """Tools and armour held, best tier first, e.g. ["stone_pickaxe", "wood_pickaxe", "bow"]."""
    enchantments: dict[str, str]
    """Full Craftax enchanted gear -> element, e.g. {"sword": "fire"}."""


class Mob(_Model):
    """A creature or projectile in view."""

    kind: str
    """craftax name: "zombie", "cow", "skeleton", "arrow"; projectiles the player fired are
    "player_arrow", "player_fireball", "player_iceball"."""
    dx: int
    """Columns right of the player (negative: left)."""
    dy: int
    """Rows above the player (negative: below)."""
    health: float | None
    """Remaining health points; None for projectiles."""


class Floor(_Model):
    """Full Craftax dungeon floor the player is on."""

    level: int
    """0 = overworld ... 8 = graveyard."""
    name: str
    """Human name of the level, e.g. "gnomish mines"."""
    ladder_open: bool
    """Whether the down ladder works (enough monsters killed on this floor)."""


class Observation(_Model):
    """One episode's view at one step, built from the craftax state (never the obs vector).

    Offsets are `(dx, dy)`: `+dx` = right, `+dy` = up, relative to the player; world positions
    share the axes (`x` from the left edge, `y` from the bottom edge). See docs/observation.md.
    """

    variant: Variant
    """Which Craftax the state came from."""
    step: int
    """craftax `timestep` of the state."""
    position: Position
    """Player's world position."""
    floor: Floor | None
    """Full Craftax floor; None in Classic (a single overworld)."""
    facing: Direction
    """Direction the player faces, named after the move action pointing that way."""
    facing_block: str | None
    """Block on the tile the player faces ("out_of_bounds" past the map edge); None when
    darkness hides it."""
    vitals: Vitals
    """Health, food, drink, energy (and mana) with their caps."""
    attributes: Attributes | None
    """Full Craftax attributes; None in Classic."""
    sleeping: bool
    """Whether the player is asleep (it wakes when energy is full or it is attacked)."""
    resting: bool
    """Full Craftax REST action in progress; always False in Classic."""
    daylight: float
    """craftax `light_level`, 1 = full day, 0 = darkest night (only matters on the surface)."""
    night: bool
    """True when on the surface and `daylight` is below 0.5 (zombies spawn more)."""
    inventory: Inventory
    """Non-zero items, tools by tier."""
    spells: list[str]
    """Full Craftax spells learned ("fireball", "iceball")."""
    achievements: list[str]
    """Achievements unlocked so far in this episode, by craftax name, in id order."""
    view_size: tuple[int, int]
    """Visible area (columns, rows) centred on the player: 9x7 Classic, 11x9 full Craftax."""
    blocks: dict[str, list[Offset]]
    """Every visible tile, including the player's own and background, grouped by block name;
    offsets nearest first (Manhattan steps, ties: higher rows, then left to right)."""
    items: dict[str, list[Offset]]
    """Full Craftax items lying on visible tiles ("torch", "ladder_down", "ladder_up")."""
    mobs: list[Mob]
    """Every visible creature and projectile, nearest first."""
    unlit: list[Offset]
    """Full Craftax tiles in view that darkness hides (their content is unknown)."""

    def block_at(self, dx: int, dy: int) -> str | None:
        """The block name at an offset, or None if hidden or outside the view."""
        for name, offsets in self.blocks.items():
            if (dx, dy) in offsets:
                return name
        return None
