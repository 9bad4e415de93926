"""The skills' preconditions against craftax's own rules: for every craft and place skill of
both variants, states are set up in the real env (inventory, stations around the player, the
cell it faces, tools held) and the executor's decision to act now is compared with whether the
env's step accepts the action.

The executor acts now when its skill can start (`SkillRun.why_not` is None) and its first
action is the craft or placement itself. For materials, tools and stations the two must agree
exactly; for the faced cell, a placement the executor makes must be one the env accepts (it may
walk on to a cell it prefers)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from env import Variant, make_task
from env.achievements import ACHIEVEMENT_IDS, NUM_ACHIEVEMENTS
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.expert.navigation import ExpertEpisode
from llm_agents.agents.expert.plan import RECIPES
from llm_agents.agents.skills.catalogue import AnySkill, Craft, Place, skill_offer
from llm_agents.agents.skills.runner import SkillRun
from textualizer import observe

pytestmark = pytest.mark.slow

MATERIALS = ("wood", "stone", "coal", "iron", "diamond", "sapling")
#: What each placement spends (craftax's place_block).
PLACE_COST = {"crafting_table": ("wood", 2), "furnace": ("stone", 1), "stone": ("stone", 1),
              "plant": ("sapling", 1)}  # fmt: skip
PLACE_ACTIONS = {"crafting_table": "PLACE_TABLE", "furnace": "PLACE_FURNACE",
                 "stone": "PLACE_STONE", "plant": "PLACE_PLANT"}  # fmt: skip
#: Cells faced besides grass (the cases of materials and stations face grass).
FACED = ("sand", "path", "water", "stone", "tree", "lava")
TIERS = {"wood": 1, "stone": 2, "iron": 3}


@dataclass(frozen=True)
class Case:
    skill: AnySkill
    action: str
    inventory: dict[str, int]
    stations: frozenset[str]
    faced: str = "grass"
    held_tier: int = 0
    """Full Craftax: the tier of the skill's tool kind already held."""

    @property
    def label(self) -> str:
        return (
            f"{self.skill.text} with {self.inventory}, stations {sorted(self.stations)}, "
            f"facing {self.faced}, holding tier {self.held_tier}"
        )


def craft_cases(variant: Variant) -> Iterator[Case]:
    for item in skill_offer(variant, "easy").items:
        action = f"MAKE_{item.upper()}"
        recipe = RECIPES[action]
        need = {m: getattr(recipe, m) for m in ("wood", "stone", "coal", "iron")}
        need = {m: n for m, n in need.items() if n}
        full = frozenset({"crafting_table", "furnace"})
        skill = Craft(item=item)
        yield Case(skill, action, need, full)
        for material in need:
            yield Case(skill, action, need | {material: need[material] - 1}, full)
        yield Case(skill, action, need, frozenset({"crafting_table"}))
        yield Case(skill, action, need, frozenset({"furnace"}))
        yield Case(skill, action, need, frozenset())
        if variant is Variant.FULL:
            tier = TIERS[item.split("_")[0]]
            for held in range(1, 4):
                yield Case(skill, action, need, full, held_tier=held)
            assert tier


def place_cases(variant: Variant) -> Iterator[Case]:
    for block in skill_offer(variant, "easy").placeable:
        material, cost = PLACE_COST[block]
        skill, action = Place(block=block), PLACE_ACTIONS[block]
        for stations in (frozenset(), frozenset({"crafting_table"})):
            yield Case(skill, action, {material: cost}, stations)
            yield Case(skill, action, {material: cost - 1}, stations)
        for faced in FACED:
            yield Case(skill, action, {material: cost}, frozenset(), faced)


@dataclass
class Rig:
    """One variant's env with one reset state to edit."""

    variant: Variant
    step: Any
    state: Any
    blocks: dict[str, int]


@pytest.fixture(scope="module", params=["classic", "full"])
def rig(request: pytest.FixtureRequest, classic_env: Any, full_env: Any) -> Rig:
    compiled = classic_env if request.param == "classic" else full_env
    variant = Variant(request.param)
    required = np.zeros(NUM_ACHIEVEMENTS, bool)
    required[ACHIEVEMENT_IDS["COLLECT_DIAMOND"]] = True  # never met here: the episode goes on
    task = make_task(required, np.zeros(NUM_ACHIEVEMENTS, bool))
    state = compiled.reset(jnp.asarray(np.array([0, 3], np.uint32)), task)
    if variant is Variant.CLASSIC:
        from craftax.craftax_classic.constants import BlockType
    else:
        from craftax.craftax.constants import BlockType  # type: ignore[no-redef]
    blocks = {b.name.lower(): b.value for b in BlockType}
    return Rig(variant, compiled.step, state, blocks)


def _directions(variant: Variant) -> np.ndarray:
    if variant is Variant.CLASSIC:
        from craftax.craftax_classic.constants import DIRECTIONS
    else:
        from craftax.craftax.constants import DIRECTIONS  # type: ignore[no-redef]
    return np.asarray(DIRECTIONS)


def _set_up(rig: Rig, case: Case) -> Any:
    game = rig.state.game
    pos = np.asarray(game.player_position)
    facing = _directions(rig.variant)[int(game.player_direction)]
    side = np.array([facing[1], facing[0]])
    full = rig.variant is Variant.FULL
    level = int(game.player_level) if full else 0
    world = np.asarray(game.map[level] if full else game.map).copy()
    world[pos[0] - 2 : pos[0] + 3, pos[1] - 2 : pos[1] + 3] = rig.blocks["grass"]
    world[tuple(pos + facing)] = rig.blocks[case.faced]
    if "crafting_table" in case.stations:
        world[tuple(pos - facing)] = rig.blocks["crafting_table"]
    if "furnace" in case.stations:
        world[tuple(pos + side)] = rig.blocks["furnace"]
    inventory = {m: case.inventory.get(m, 0) for m in MATERIALS}
    if full:
        kind = (
            "sword" if isinstance(case.skill, Craft) and "sword" in case.skill.item else "pickaxe"
        )
        tools = {"pickaxe": 0, "sword": 0} | {kind: case.held_tier}
        game = game.replace(
            map=game.map.at[level].set(jnp.asarray(world)),
            mob_map=jnp.zeros_like(game.mob_map),
            melee_mobs=game.melee_mobs.replace(mask=jnp.zeros_like(game.melee_mobs.mask)),
            passive_mobs=game.passive_mobs.replace(mask=jnp.zeros_like(game.passive_mobs.mask)),
            ranged_mobs=game.ranged_mobs.replace(mask=jnp.zeros_like(game.ranged_mobs.mask)),
            inventory=game.inventory.replace(**inventory, **tools),
        )
    else:
        game = game.replace(
            map=jnp.asarray(world),
            zombies=game.zombies.replace(mask=jnp.zeros_like(game.zombies.mask)),
            cows=game.cows.replace(mask=jnp.zeros_like(game.cows.mask)),
            skeletons=game.skeletons.replace(mask=jnp.zeros_like(game.skeletons.mask)),
            inventory=game.inventory.replace(**inventory),
        )
    return rig.state.replace(game=game)


def _host(game: Any) -> Any:
    return jax.tree_util.tree_map(np.asarray, game)


def env_accepts(rig: Rig, state: Any, case: Case) -> bool:
    after, _ = rig.step(state, jnp.int32(action_id(case.action, rig.variant)))
    before_inv = jax.tree_util.tree_leaves(_host(state.game.inventory))
    after_inv = jax.tree_util.tree_leaves(_host(after.game.inventory))
    return any(not np.array_equal(a, b) for a, b in zip(before_inv, after_inv, strict=True))


def executor_acts(rig: Rig, state: Any, case: Case) -> bool:
    obs = observe(_host(state.game), rig.variant)
    episode = ExpertEpisode((), ())
    episode.world.update(obs)
    run = SkillRun(case.skill, episode, obs, 60)
    return run.why_not() is None and run.advance(obs) == case.action


def _compare(rig: Rig, cases: list[Case]) -> list[tuple[Case, bool, bool]]:
    found = []
    for case in cases:
        state = _set_up(rig, case)
        found.append((case, executor_acts(rig, state, case), env_accepts(rig, state, case)))
    return found


def test_every_craft_is_refused_exactly_where_the_env_refuses_it(rig: Rig) -> None:
    results = _compare(rig, list(craft_cases(rig.variant)))
    assert any(env for _, _, env in results) and not all(env for _, _, env in results)
    disagree = [f"{c.label}: executor {ex}, env {env}" for c, ex, env in results if ex != env]
    assert not disagree, "\n".join(disagree)


def test_every_placement_is_refused_exactly_where_the_env_refuses_it(rig: Rig) -> None:
    cases = [c for c in place_cases(rig.variant) if c.faced == "grass"]
    results = _compare(rig, cases)
    assert any(env for _, _, env in results) and not all(env for _, _, env in results)
    disagree = [f"{c.label}: executor {ex}, env {env}" for c, ex, env in results if ex != env]
    assert not disagree, "\n".join(disagree)


def test_a_placement_the_executor_makes_on_the_faced_cell_is_one_the_env_accepts(
    rig: Rig,
) -> None:
    cases = [c for c in place_cases(rig.variant) if c.faced in FACED]
    results = _compare(rig, cases)
    refused = [f"{c.label}: the env refuses it" for c, ex, env in results if ex and not env]
    assert not refused, "\n".join(refused)
    # Grass, sand and path take every block the env lets the executor place there.
    open_ground = [(c, ex) for c, ex, env in results if env and c.faced in ("sand", "path")]
    assert all(ex for c, ex in open_ground if c.skill.text != "place plant")
