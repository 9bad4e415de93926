"""What a variant rules out (issue 31): the items its actions spend, checked against the
installed craftax's game logic, and the reasons a goal can never be met."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from env.goal_status import INVENTORY_CAP, SPENT, impossible_reason
from env.goals import BuildLineGoal, ConditionalPlacingGoal
from env.scenario_tasks import CLASSIC_INVENTORY_SLOTS, INVENTORY_SLOTS
from env.variant import Variant
from llm_agents.agents.expert.plan import expert_cannot

GAME_LOGIC = {Variant.CLASSIC: "craftax.craftax_classic", Variant.FULL: "craftax.craftax"}


def decremented(variant: Variant) -> set[str]:
    """The inventory slots craftax's game logic of `variant` ever lowers (`wood=... .wood - `
    or `new_ruby = ... .ruby - `)."""
    spec = importlib.util.find_spec(GAME_LOGIC[variant])
    assert spec is not None and spec.submodule_search_locations
    source = (Path(next(iter(spec.submodule_search_locations))) / "game_logic.py").read_text()
    slots = CLASSIC_INVENTORY_SLOTS if variant is Variant.CLASSIC else INVENTORY_SLOTS
    return {
        slot for slot in slots if re.search(rf"(?:\b|new_){slot}\s*=\s*[\w.]*\.{slot}\s*-", source)
    }


@pytest.mark.parametrize("variant", list(Variant))
def test_the_spent_items_are_those_craftax_takes_out_of_the_inventory(variant: Variant) -> None:
    assert decremented(variant) == SPENT[variant]


def conditional(collect: str, count: int, place: str = "STONE") -> ConditionalPlacingGoal:
    return ConditionalPlacingGoal(
        id="G",
        split="medium_train",
        scenario="medium",
        instruction="collect then place",
        paraphrases=(),
        collect=collect,
        collect_count=count,
        place=place,
        place_count=1,
    )


def test_a_goal_on_an_item_the_variant_never_spends_is_impossible_there_only() -> None:
    diamonds = conditional("diamond", 2)
    assert "nothing in classic Craftax spends diamond" in (
        impossible_reason(diamonds, Variant.CLASSIC) or ""
    )
    assert impossible_reason(diamonds, Variant.FULL) is None
    assert impossible_reason(conditional("wood", 2), Variant.CLASSIC) is None


@pytest.mark.parametrize(
    ("goal", "reason"),
    [
        (conditional("wood", 0), "collect count 0"),
        (conditional("wood", INVENTORY_CAP + 1), "at most 9"),
        (conditional("ruby", 1), "counts ruby, which classic Craftax has no inventory slot for"),
        (conditional("wood", 1, place="ENCHANTMENT_TABLE_ICE"), "classic Craftax lacks"),
    ],
)
def test_counts_and_names_no_world_can_meet_are_impossible(
    goal: ConditionalPlacingGoal, reason: str
) -> None:
    assert reason in (impossible_reason(goal, Variant.CLASSIC) or "")


def test_other_kinds_are_ruled_out_only_by_what_the_variant_lacks() -> None:
    line = BuildLineGoal(
        id="L", split="medium_train", scenario="medium", instruction="a line",
        paraphrases=(), block="STONE", size=3, diagonal=False,
    )  # fmt: skip
    assert impossible_reason(line, Variant.CLASSIC) is None


def test_the_expert_cannot_spend_what_it_has_no_spending_action_for() -> None:
    assert expert_cannot(conditional("ruby", 1)) == "the scripted expert cannot spend ruby"
    assert expert_cannot(conditional("stone", 1)) is None
    assert expert_cannot(conditional("diamond", 1)) is not None
