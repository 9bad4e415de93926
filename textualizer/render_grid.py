"""The `grid` style: an ASCII picture of the view, with a legend of the symbols present."""

from textualizer.geometry import signed
from textualizer.observation import Observation

SYMBOLS: dict[str, str] = {
    # blocks
    "invalid": "?",
    "out_of_bounds": "x",
    "grass": ".",
    "water": "~",
    "stone": "s",
    "tree": "t",
    "wood": "w",
    "path": "_",
    "coal": "c",
    "iron": "i",
    "diamond": "d",
    "crafting_table": "+",
    "furnace": "f",
    "sand": ":",
    "lava": "%",
    "plant": "p",
    "ripe_plant": "&",
    "wall": "#",
    "darkness": "0",
    "wall_moss": "m",
    "stalagmite": "a",
    "sapphire": "e",
    "ruby": "r",
    "chest": "h",
    "fountain": "u",
    "fire_grass": ",",
    "ice_grass": ";",
    "gravel": "=",
    "fire_tree": "y",
    "ice_shrub": "j",
    "enchantment_table_fire": "1",
    "enchantment_table_ice": "2",
    "necromancer": "W",
    "grave": "g",
    "grave2": "l",
    "grave3": "o",
    "necromancer_vulnerable": "V",
    # items
    "torch": "!",
    "ladder_down": ">",
    "ladder_up": "<",
    # creatures
    "zombie": "Z",
    "gnome_warrior": "G",
    "orc_soldier": "O",
    "lizard": "L",
    "knight": "K",
    "troll": "T",
    "pigman": "P",
    "frost_troll": "F",
    "cow": "C",
    "bat": "B",
    "snail": "N",
    "skeleton": "S",
    "gnome_archer": "A",
    "orc_mage": "M",
    "kobold": "D",
    "knight_archer": "H",
    "deep_thing": "Q",
    "fire_elemental": "E",
    "ice_elemental": "I",
    # projectiles
    "arrow": "*",
    "dagger": "/",
    "fireball": "{",
    "iceball": "}",
    "slimeball": ")",
    "player_arrow": "'",
    "player_dagger": "\\",
    "player_fireball": "[",
    "player_iceball": "]",
    "player_slimeball": "(",
}
"""One distinct character per name; the player is `@`, an unlit tile `-`."""

PLAYER = "@"
UNLIT = "-"


def render_grid(obs: Observation) -> str:
    """Rows from the top of the view (+dy) down; a creature hides the item, an item the block."""
    columns, rows = obs.view_size
    half_x, half_y = columns // 2, rows // 2
    cells: dict[tuple[int, int], str] = dict.fromkeys(obs.unlit, UNLIT)
    for layer in (obs.blocks, obs.items):
        for name, offsets in layer.items():
            for offset in offsets:
                cells[offset] = name
    for mob in obs.mobs:
        cells[(mob.dx, mob.dy)] = mob.kind
    cells[(0, 0)] = "you"
    present: dict[str, str] = {}
    lines = [
        f"View {columns}x{rows}: dx {signed(-half_x)}..{signed(half_x)} left to right, dy {signed(half_y)}..{signed(-half_y)} top to bottom."
    ]
    for dy in range(half_y, -half_y - 1, -1):
        symbols = []
        for dx in range(-half_x, half_x + 1):
            name = cells[(dx, dy)]
            symbol = PLAYER if name == "you" else UNLIT if name == UNLIT else SYMBOLS[name]
            if name not in ("you", UNLIT):
                present.setdefault(symbol, name)
            symbols.append(symbol)
        lines.append(f"{signed(dy):>2} " + " ".join(symbols))
    legend = [f"{PLAYER} you (facing {obs.facing})"]
    if obs.unlit:
        legend.append(f"{UNLIT} unlit")
    legend += [f"{symbol} {name}" for symbol, name in present.items()]
    lines.append("Legend: " + ", ".join(legend))
    return "\n".join(lines)
