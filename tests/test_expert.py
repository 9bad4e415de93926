"""The scripted expert: its planner on hand-built observations, its safety rule, and real runs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from env.craftax_names import CLASSIC_BLOCKS
from env.craftext_env import VectorEnv
from env.dataset import Dataset, DatasetSource, Goal
from env.errors import UserError
from env.goals import BuildLineGoal, ConditionalPlacingGoal, LocalizationGoal
from env.scenario_tasks import encode_goals
from env.termination import Termination
from env.variant import Variant
from llm_agents.agents import NoModel
from llm_agents.agents.answers.actions import action_id
from llm_agents.agents.expert.plan import (
    PlanContext,
    WorldMap,
    infeasible,
    next_task,
    plan_order,
    spend_task,
    supply_task,
)
from llm_agents.agents.strategies.expert import ExpertAgent
from llm_agents.agents.types import EpisodeStart
from llm_agents.evaluation.config import build_config
from llm_agents.evaluation.runner import run_eval
from llm_agents.run_data.store import read_episodes
from textualizer import observe_batch
from textualizer.observation import Inventory, Mob, Observation, Position, Vitals


def observation(
    blocks: dict[str, list[tuple[int, int]]] | None = None,
    *,
    materials: dict[str, int] | None = None,
    tools: tuple[str, ...] = (),
    achievements: tuple[str, ...] = (),
    mobs: tuple[tuple[str, int, int], ...] = (),
    facing: str = "right",
    energy: int = 9,
    x: int = 20,
    y: int = 20,
) -> Observation:
    """A Classic observation: grass everywhere in the 9x7 view except the given blocks."""
    grid = {(dx, dy): "grass" for dx in range(-4, 5) for dy in range(-3, 4)}
    for name, offsets in (blocks or {}).items():
        for offset in offsets:
            grid[offset] = name
    grouped: dict[str, list[tuple[int, int]]] = {}
    for offset, name in grid.items():
        grouped.setdefault(name, []).append(offset)
    facing_offset = {"left": (-1, 0), "right": (1, 0), "up": (0, 1), "down": (0, -1)}[facing]
    return Observation(
        variant=Variant.CLASSIC,
        step=0,
        position=Position(x=x, y=y),
        floor=None,
        facing=facing,  # type: ignore[arg-type]
        facing_block=grid[facing_offset],
        vitals=Vitals(
            health=9,
            food=9,
            drink=9,
            energy=energy,
            mana=None,
            max_health=9,
            max_food=9,
            max_mana=None,
            hunger=0,
            thirst=0,
            fatigue=0,
            recover=0,
        ),
        attributes=None,
        sleeping=False,
        resting=False,
        daylight=1.0,
        night=False,
        inventory=Inventory(materials=materials or {}, tools=list(tools), enchantments={}),
        spells=[],
        achievements=list(achievements),
        view_size=(9, 7),
        blocks=grouped,
        items={},
        mobs=[Mob(kind=kind, dx=dx, dy=dy, health=3) for kind, dx, dy in mobs],
        unlit=[],
    )


def context(required: tuple[str, ...], forbidden: tuple[str, ...] = (), **seen: Any) -> PlanContext:
    obs = observation(**seen)
    world = WorldMap()
    world.update(obs)
    distances = {
        (obs.position.x + dx, obs.position.y + dy): abs(dx) + abs(dy)
        for dx in range(-4, 5)
        for dy in range(-3, 4)
    }
    return PlanContext(required, forbidden, obs, world, distances=distances)


# ------------------------------------------------------------------------------------ planner


def test_plan_orders_prerequisites_and_never_plans_a_forbidden_achievement() -> None:
    order = plan_order(["MAKE_IRON_SWORD", "PLACE_FURNACE"], ["MAKE_IRON_PICKAXE"])
    assert "MAKE_IRON_PICKAXE" not in order
    assert order.index("COLLECT_WOOD") < order.index("MAKE_WOOD_PICKAXE")
    assert order.index("MAKE_STONE_PICKAXE") < order.index("COLLECT_IRON")
    assert order.index("COLLECT_IRON") < order.index("MAKE_IRON_SWORD")
    with pytest.raises(ValueError, match="MAKE_IRON_PICKAXE"):
        plan_order(["COLLECT_DIAMOND"], ["MAKE_IRON_PICKAXE"])
    assert infeasible(["PLACE_STONE"], ["MAKE_WOOD_PICKAXE"]) is not None
    assert infeasible(["COLLECT_DRINK"], ["PLACE_TABLE"]) is None


def test_an_infeasible_goal_idles_instead_of_unlocking_the_forbidden_achievement() -> None:
    task = next_task(context(("COLLECT_STONE",), ("MAKE_WOOD_PICKAXE",), blocks={"tree": [(1, 0)]}))
    assert task.kind == "idle" and "MAKE_WOOD_PICKAXE" in task.note


def test_missing_resources_are_explored_for() -> None:
    assert (
        next_task(context(("COLLECT_WOOD",))).kind,
        next_task(context(("COLLECT_WOOD",))).target,
    ) == (
        "explore",
        "tree",
    )
    # Stone is wanted, but first wood for the pickaxe and its table: no tree in sight.
    task = next_task(context(("COLLECT_STONE",), blocks={"stone": [(3, 0)]}))
    assert (task.kind, task.target) == ("explore", "tree")
    # With a wood pickaxe and no stone seen, it explores for stone.
    task = next_task(
        context(("COLLECT_STONE",), tools=("wood_pickaxe",), achievements=("MAKE_WOOD_PICKAXE",))
    )
    assert (task.kind, task.target) == ("explore", "stone")


def test_the_planner_walks_the_recipe_chain() -> None:
    goal = ("MAKE_STONE_PICKAXE",)
    task = next_task(context(goal, blocks={"tree": [(2, 1)]}))
    assert (task.kind, task.target) == ("gather", "tree") and task.amount >= 4
    task = next_task(context(goal, materials={"wood": 6}))
    assert (task.kind, task.target) == ("place", "PLACE_TABLE")
    near_table = {"crafting_table": [(1, 1)]}
    task = next_task(context(goal, blocks=near_table, materials={"wood": 5}))
    assert (task.kind, task.target) in {
        ("craft", "MAKE_WOOD_PICKAXE"),
        ("craft", "MAKE_WOOD_SWORD"),
    }
    task = next_task(
        context(
            goal,
            blocks={**near_table, "stone": [(-3, 0)]},
            materials={"wood": 3},
            tools=("wood_pickaxe",),
        )
    )
    assert (task.kind, task.target) == ("gather", "stone")


def test_a_forbidden_sword_is_never_crafted_even_with_spare_wood() -> None:
    seen = {"blocks": {"crafting_table": [(1, 1)]}, "materials": {"wood": 9}}
    allowed = next_task(context(("MAKE_WOOD_PICKAXE",), **seen))
    assert allowed.target == "MAKE_WOOD_SWORD"  # harmless extra: fights go better with it
    banned = next_task(context(("MAKE_WOOD_PICKAXE",), ("MAKE_WOOD_SWORD",), **seen))
    assert banned.target == "MAKE_WOOD_PICKAXE"


def test_wake_up_waits_for_energy_to_drop_then_sleeps() -> None:
    assert next_task(context(("WAKE_UP", "COLLECT_WOOD"))).target == "tree"
    assert next_task(context(("WAKE_UP", "COLLECT_WOOD"), energy=8)).kind == "sleep"


# ------------------------------------------------------------------------------------ the agent


def expert_goal(required: tuple[str, ...], forbidden: tuple[str, ...] = ()) -> Goal:
    return Goal(
        id="_".join(required),
        split="easy_train",
        category="one" if len(required) == 1 and not forbidden else "combo",
        instruction="ignored by the expert",
        paraphrases=(),
        required=required,
        forbidden=forbidden,
    )


def test_the_expert_faces_and_takes_what_it_needs() -> None:
    agent = ExpertAgent(Variant.CLASSIC)
    agent.start_episode(0, EpisodeStart("text", goal=expert_goal(("COLLECT_WOOD",))))
    assert agent.choose(0, observation({"tree": [(0, 1)]}, facing="right"))[0] == "UP"
    assert agent.choose(0, observation({"tree": [(0, 1)]}, facing="up"))[0] == "DO"
    agent.start_episode(1, EpisodeStart("text", goal=expert_goal(("COLLECT_WOOD",))))
    assert agent.choose(1, observation({"tree": [(3, 0)]}))[0] == "RIGHT"


def test_the_expert_never_does_what_is_forbidden() -> None:
    agent = ExpertAgent(Variant.CLASSIC)
    # Killing the zombie next to it is forbidden: it steps away instead of attacking.
    agent.start_episode(
        0, EpisodeStart("text", goal=expert_goal(("COLLECT_WOOD",), ("DEFEAT_ZOMBIE",)))
    )
    action, task = agent.choose(0, observation(mobs=(("zombie", 1, 0),), facing="right"))
    assert action == "LEFT" and task is not None and "away" in task.note
    # Drinking is forbidden: facing water while thirsty does not make it drink.
    agent.start_episode(
        1, EpisodeStart("text", goal=expert_goal(("COLLECT_WOOD",), ("COLLECT_DRINK",)))
    )
    thirsty = observation({"water": [(1, 0)]}, facing="right").model_copy(
        update={"vitals": observation().vitals.model_copy(update={"drink": 1})}
    )
    assert agent.choose(1, thirsty)[0] != "DO"
    with pytest.raises(UserError, match="goal record"):
        agent.start_episode(2, EpisodeStart("collect wood"))


def _walled_in(blocks: dict[str, list[tuple[int, int]]]) -> dict[str, list[tuple[int, int]]]:
    """`blocks`, with water on every cell of the view two or more steps from the player: a
    pocket of ground whose every reachable cell is in sight."""
    taken = {offset for offsets in blocks.values() for offset in offsets}
    water = [
        (dx, dy)
        for dx in range(-4, 5)
        for dy in range(-3, 4)
        if max(abs(dx), abs(dy)) >= 2 and (dx, dy) not in taken
    ]
    return {**blocks, "water": water}


def test_a_walled_in_expert_makes_a_pickaxe_to_break_out() -> None:
    # No zombie can reach a pocket bounded by water and stone, and none is seen: exploring
    # has nowhere to go, so it fetches wood for a pickaxe that makes the stone passable.
    agent = ExpertAgent(Variant.CLASSIC)
    agent.start_episode(0, EpisodeStart("text", goal=expert_goal(("DEFEAT_ZOMBIE",))))
    pocket = _walled_in({"tree": [(0, 1)], "stone": [(2, 0), (2, 1)]})
    action, task = agent.choose(0, observation(pocket, facing="up"))
    assert task is not None and (task.kind, task.target) == ("gather", "tree")
    assert action == "DO"
    # With wood for a table and a pickaxe it places the table, then crafts.
    action, task = agent.choose(0, observation(pocket, materials={"wood": 3}, facing="left"))
    assert task is not None and (task.kind, task.target) == ("place", "PLACE_TABLE")
    assert action == "PLACE_TABLE"


def test_a_walled_in_expert_never_breaks_out_through_a_forbidden_achievement() -> None:
    agent = ExpertAgent(Variant.CLASSIC)
    goal = expert_goal(("DEFEAT_ZOMBIE",), ("MAKE_WOOD_PICKAXE",))
    agent.start_episode(0, EpisodeStart("text", goal=goal))
    pocket = _walled_in({"tree": [(0, 1)], "stone": [(2, 0), (2, 1)]})
    action, task = agent.choose(0, observation(pocket, facing="up"))
    assert task is not None and task.kind == "hunt" and action != "DO"


def test_a_skeleton_hunter_walks_into_the_unseen_part_of_a_tunnel() -> None:
    # A tunnel runs off the view's west edge; open grass lies ahead to the east, where an
    # explorer's heading points. Skeletons appear only on tunnel floor: it goes west.
    agent = ExpertAgent(Variant.CLASSIC)
    agent.start_episode(0, EpisodeStart("text", goal=expert_goal(("DEFEAT_SKELETON",))))
    tunnel = {"path": [(-4, 0), (-4, 1)], "stone": [(-4, 2), (-4, -1), (-3, 1), (-3, 2)]}
    seen = observation(
        tunnel,
        tools=("wood_pickaxe",),
        achievements=("COLLECT_WOOD", "PLACE_TABLE", "MAKE_WOOD_PICKAXE"),
    )
    action, task = agent.choose(0, seen)
    assert task is not None and (task.kind, task.target) == ("hunt", "skeleton")
    assert action == "LEFT"


def test_spending_picks_an_action_that_takes_the_item_out_of_the_inventory() -> None:
    stone = spend_task(context((), materials={"stone": 3}), "stone")
    assert (stone.kind, stone.target) == ("place", "PLACE_STONE")
    sapling = spend_task(context((), materials={"sapling": 1}), "sapling")
    assert (sapling.kind, sapling.target) == ("place", "PLACE_PLANT")
    # Wood beside a table: a wood pickaxe (1 wood), not a sword swapped in.
    wood = spend_task(
        context((), materials={"wood": 3}, blocks={"crafting_table": [(1, 0)]}), "wood"
    )
    assert (wood.kind, wood.target) == ("craft", "MAKE_WOOD_PICKAXE")
    # Coal is spent only by an iron tool: its missing inputs are fetched first.
    coal = spend_task(context((), materials={"coal": 4}, tools=("stone_pickaxe",)), "coal")
    assert coal.kind in ("gather", "explore") and coal.target == "tree"
    assert spend_task(context((), materials={"diamond": 3}), "diamond").kind == "idle"


def test_gathering_never_asks_for_more_than_the_inventory_holds() -> None:
    # Five tables are 10 wood; the inventory stops at 9, so 9 are gathered and placed first.
    task = supply_task(context((), blocks={"tree": [(2, 0)]}), "crafting_table", 5)
    assert task is not None and task.kind == "gather" and task.amount == 9
    assert supply_task(context((), materials={"wood": 9}), "crafting_table", 5) is None


@pytest.mark.slow
def test_an_expert_run_collects_wood_and_places_a_table(classic_env: Any, tmp_path: Path) -> None:
    goals = (expert_goal(("COLLECT_WOOD",)), expert_goal(("PLACE_TABLE",)))
    dataset = Dataset(source=DatasetSource(kind="json", path="hand-built"), goals=goals)
    path = dataset.save_json(tmp_path / "goals.json")
    config = build_config(
        {
            "agent": "expert",
            "variant": "classic",
            "categories": ["one"],
            "dataset": str(path),
            "paraphrases": False,
            "episodes_per_instruction": 2,
            "batch_size": 4,
            "output_dir": str(tmp_path / "run"),
        }
    )
    outcome = run_eval(config, NoModel(), env=classic_env.env)
    episodes = read_episodes(tmp_path / "run" / "episodes.jsonl")
    assert len(episodes) == 4 and all(e.success for e in episodes)
    assert all(e.steps < 120 for e in episodes)
    assert outcome.results.versions["model.backend"] == "none"


# --------------------------------------------------------------- Medium/Hard placing goals


def _play(env: Any, goal: Any, seed: int, max_steps: int = 250) -> Any:
    """One Classic episode of the expert on `goal`, scored by the env's own checker (the
    official one's equal); the host batch it ended with (map `game.map[0]`, `termination`)."""
    vector = VectorEnv(env, 1)
    tasks = encode_goals([goal], Variant.CLASSIC)
    keys = np.array([[seed, 7]], dtype=np.uint32)
    host = vector.reset(keys, tasks.required, tasks.forbidden, tasks.kind, tasks.params)
    agent = ExpertAgent(Variant.CLASSIC)
    agent.start_episode(0, EpisodeStart("ignored", goal=goal))
    for _ in range(max_steps):
        if host.done[0]:
            break
        obs = observe_batch(host.game, Variant.CLASSIC)[0]
        name, _ = agent.choose(0, obs)
        host = vector.step(np.array([action_id(name, Variant.CLASSIC)]))
    return host


def _runs(hits: np.ndarray, length: int) -> bool:
    """Whether `hits` holds `length` consecutive True cells along a row or a column."""
    for grid in (hits, hits.T):
        for row in grid:
            run = 0
            for hit in row:
                run = run + 1 if hit else 0
                if run >= length:
                    return True
    return False


@pytest.mark.slow
def test_the_expert_builds_a_line_of_tables_on_the_map(classic_env: Any) -> None:
    goal = BuildLineGoal(
        id="line",
        split="medium_train",
        scenario="medium",
        instruction="ignored",
        paraphrases=(),
        block="CRAFTING_TABLE",
        size=3,
        diagonal=False,
    )
    game_map = np.asarray(_play(classic_env.env, goal, seed=3).game.map[0])
    tables = game_map == CLASSIC_BLOCKS.index("CRAFTING_TABLE")
    assert _runs(tables, 3)


@pytest.mark.slow
def test_the_expert_places_a_table_at_the_side_and_distance_of_a_tree(classic_env: Any) -> None:
    goal = LocalizationGoal(
        id="beside",
        split="medium_train",
        scenario="medium",
        instruction="ignored",
        paraphrases=(),
        place="CRAFTING_TABLE",
        target="TREE",
        side="up",
        distance=2,
    )
    game_map = np.asarray(_play(classic_env.env, goal, seed=4).game.map[0])
    table, tree = CLASSIC_BLOCKS.index("CRAFTING_TABLE"), CLASSIC_BLOCKS.index("TREE")
    # The official side 2 ("up") is a smaller first (row) index.
    rows, cols = np.nonzero(game_map == table)
    assert any(game_map[r + 2, c] == tree for r, c in zip(rows, cols, strict=True))


def _conditional(collect: str, count: int, place: str, place_count: int) -> ConditionalPlacingGoal:
    return ConditionalPlacingGoal(
        id=f"{collect}_{place}",
        split="medium_train",
        scenario="medium",
        instruction="ignored",
        paraphrases=(),
        collect=collect,
        collect_count=count,
        place=place,
        place_count=place_count,
    )


@pytest.mark.slow
def test_the_expert_spends_wood_through_the_threshold_once_a_table_stands(classic_env: Any) -> None:
    goal = _conditional("wood", 3, "CRAFTING_TABLE", 1)
    assert _play(classic_env.env, goal, seed=3).termination[0] == Termination.SUCCESS


@pytest.mark.slow
def test_the_expert_plants_saplings_through_the_threshold_once_a_plant_stands(
    classic_env: Any,
) -> None:
    goal = _conditional("sapling", 3, "PLANT", 1)
    assert _play(classic_env.env, goal, seed=4).termination[0] == Termination.SUCCESS


@pytest.mark.slow
def test_the_expert_places_the_missing_reference_block_too(classic_env: Any) -> None:
    # No plant stands in a new world: the expert plants one, then puts a stone 2 right of it.
    goal = LocalizationGoal(
        id="beside_plant",
        split="medium_train",
        scenario="medium",
        instruction="ignored",
        paraphrases=(),
        place="STONE",
        target="PLANT",
        side="right",
        distance=2,
    )
    assert _play(classic_env.env, goal, seed=5).termination[0] == Termination.SUCCESS
