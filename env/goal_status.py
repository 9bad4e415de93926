"""Which goals a run's numbers should be read without: those a do-nothing agent meets, and those
no agent can meet on the variant.

- **Do nothing**: the fraction of seeded worlds in which an agent that only ever takes `NOOP`
  meets the goal within the step cap, played in the real env with the real checkers
  (`do_nothing_successes`). The official line and star checks make some goals true in a fresh
  world (a straight line of 2 of a block absent from the window, straight stars). Played, not
  listed by hand, and cached on disk (`cache_root()/do-nothing/`), keyed by everything that
  decides it: the goals' checker encodings, variant, step cap, success rule, step keys, worlds and seed.
- **Not achievable on the variant** (`impossible_reason`), derived from the goal's parameters and
  the variant's tables: a conditional-placing goal succeeds when the collected count *falls*
  below `collect_count` (the official check), so an item nothing in the variant takes out of the
  inventory (`SPENT`: diamonds in Craftax-Classic), a count of 0, or one above the inventory's
  cap can never be met; a goal naming a block or item the variant lacks neither.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from env.errors import UserError
from env.goals import AnyGoal, ConditionalPlacingGoal
from env.scenario_tasks import CLASSIC_INVENTORY_SLOTS, INVENTORY_SLOTS, encode_goals
from env.variant import Variant

if TYPE_CHECKING:
    from env.craftext_env import EnvConfig

__all__ = [
    "INVENTORY_CAP",
    "SPENT",
    "do_nothing_successes",
    "goal_key",
    "impossible_reason",
]

#: The inventory items some action of each variant takes out of the inventory (crafting, placing,
#: enchanting), as Craftax's game logic does; `tests/test_goal_status.py` checks it against the
#: installed craftax's source.
SPENT: dict[Variant, frozenset[str]] = {
    Variant.CLASSIC: frozenset({"wood", "stone", "coal", "iron", "sapling"}),
    Variant.FULL: frozenset(INVENTORY_SLOTS),
}
#: Craftax caps every inventory count at 9.
INVENTORY_CAP = 9
_CACHE_FORMAT = 1
#: Episodes stepped together while playing do-nothing worlds.
_BATCH = 128


def goal_key(goal: AnyGoal) -> str:
    """`split/id`: a goal's name, unique in a dataset."""
    return f"{goal.split}/{goal.id}"


def impossible_reason(goal: AnyGoal, variant: Variant) -> str | None:
    """Why no agent can meet `goal` on `variant`; None when nothing in the goal's parameters
    and the variant's tables rules it out."""
    try:
        encode_goals([goal], variant)
    except UserError as error:  # it names the block or item the variant lacks
        return str(error).removeprefix(f"goal {goal.id!r} ({goal.split}) ")
    if not isinstance(goal, ConditionalPlacingGoal):
        return None
    item, count = goal.collect, goal.collect_count
    slots = CLASSIC_INVENTORY_SLOTS if variant is Variant.CLASSIC else INVENTORY_SLOTS
    if item not in slots:
        return f"{variant.value} Craftax has no inventory slot for {item}"
    if count == 0:
        return "collect count 0: a count never falls below 0, so the official check never holds"
    if count > INVENTORY_CAP:
        return f"collect count {count}: the inventory holds at most {INVENTORY_CAP}"
    if item not in SPENT[variant]:
        return f"nothing in {variant.value} Craftax spends {item}, so its count never falls"
    return None


def do_nothing_successes(
    goals: Sequence[AnyGoal],
    config: EnvConfig,
    *,
    worlds: int,
    seed: int,
    cache_dir: Path | None = None,
) -> dict[str, int]:
    """`goal_key` -> in how many of `worlds` seeded worlds an agent taking only `NOOP` meets
    the goal within `config.max_steps` under `config.success_rule`; read from `cache_dir`
    (default: the project's cache) when played before with the same everything."""
    from env.downloads import cache_root

    if worlds < 1:
        raise ValueError(f"worlds must be at least 1, got {worlds}")
    goals = list({goal_key(goal): goal for goal in goals}.values())
    encoded = encode_goals(goals, config.variant)
    identity = {
        "format": _CACHE_FORMAT,
        "goals": [goal_key(goal) for goal in goals],
        "kind": encoded.kind.tolist(),
        "required": encoded.required.astype(int).tolist(),
        "forbidden": encoded.forbidden.astype(int).tolist(),
        "params": encoded.params.tolist(),
        "variant": config.variant.value,
        "max_steps": config.max_steps,
        "success_rule": config.success_rule,
        "world_key": config.world_key,
        "step_keys": config.step_keys,
        "worlds": worlds,
        "seed": seed,
        "craftax": _craftax_version(),
    }
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:24]
    path = (cache_dir or cache_root() / "do-nothing") / f"v{_CACHE_FORMAT}-{digest}.json"
    try:
        return {str(k): int(v) for k, v in json.loads(path.read_text())["successes"].items()}
    except (OSError, ValueError, KeyError, AttributeError):
        pass
    successes = _play_do_nothing(goals, encoded, config, worlds, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(f".{np.random.default_rng().integers(1 << 62)}.tmp")
    temporary.write_text(json.dumps({"identity": identity, "successes": successes}, indent=1))
    temporary.replace(path)
    return successes


def _craftax_version() -> str:
    import importlib.metadata

    try:
        return importlib.metadata.version("craftax")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _play_do_nothing(
    goals: Sequence[AnyGoal], encoded: object, config: EnvConfig, worlds: int, seed: int
) -> dict[str, int]:
    from env.craftext_env import VectorEnv, episode_key, shared_env
    from env.termination import Termination

    rows = [(index, world) for index in range(len(goals)) for world in range(worlds)]
    batch = min(_BATCH, len(rows))
    vector = VectorEnv(shared_env(config), batch)
    noop = config.variant.action_names.index("NOOP")
    kind, required, forbidden, params = (
        getattr(encoded, name) for name in ("kind", "required", "forbidden", "params")
    )
    successes = dict.fromkeys((goal_key(goal) for goal in goals), 0)
    for start in range(0, len(rows), batch):
        chunk = rows[start : start + batch]
        # The last chunk is padded with its first row (played, not counted): shapes stay fixed.
        padded = chunk + [chunk[0]] * (batch - len(chunk))
        index = np.array([i for i, _ in padded])
        keys = np.stack([episode_key(seed, goals[i].id, 0, world) for i, world in padded]).astype(
            np.uint32
        )
        ends = vector.reset(
            keys, required[index], forbidden[index], kind[index], params[index]
        ).termination
        actions = np.full(batch, noop, dtype=np.int32)
        while np.any(ends == Termination.RUNNING):
            ends = vector.step_terminations(actions, ends == Termination.RUNNING)
        for row, (i, _) in enumerate(chunk):
            successes[goal_key(goals[i])] += int(ends[row] == Termination.SUCCESS)
    return successes
