"""The action catalogue matches craftax's Action enums exactly and resolves names and ids."""

import pytest

from env.errors import UserError
from env.variant import Variant
from llm_agents.agents.answers.actions import action_catalogue, action_id, action_names


def craftax_actions(variant: Variant) -> dict[str, int]:
    if variant is Variant.FULL:
        from craftax.craftax.constants import Action
    else:
        from craftax.craftax_classic.constants import Action
    return {member.name: member.value for member in Action}


@pytest.mark.parametrize("variant", list(Variant))
def test_names_and_ids_match_craftax_enum(variant: Variant) -> None:
    ours = {spec.name: spec.id for spec in action_catalogue(variant)}
    assert ours == craftax_actions(variant)
    assert len(ours) == variant.num_actions


@pytest.mark.parametrize("variant", list(Variant))
def test_catalogue_is_in_id_order_with_distinct_descriptions(variant: Variant) -> None:
    catalogue = action_catalogue(variant)
    assert [spec.id for spec in catalogue] == list(range(len(catalogue)))
    assert list(action_names(variant)) == [spec.name for spec in catalogue]
    descriptions = [spec.description for spec in catalogue]
    assert all(len(d) > 10 for d in descriptions)
    assert len(set(descriptions)) == len(descriptions)


def test_classic_is_a_prefix_of_full() -> None:
    classic = action_names(Variant.CLASSIC)
    assert action_names(Variant.FULL)[: len(classic)] == classic


@pytest.mark.parametrize(
    ("name", "recipe_words"),
    [
        ("MAKE_WOOD_PICKAXE", ["1 wood", "crafting table"]),
        ("MAKE_IRON_PICKAXE", ["1 iron", "1 coal", "furnace"]),
        ("PLACE_TABLE", ["2 wood"]),
        ("PLACE_FURNACE", ["1 stone"]),
    ],
)
def test_descriptions_state_craftax_recipes(name: str, recipe_words: list[str]) -> None:
    for variant in Variant:
        description = action_catalogue(variant)[action_id(name, variant)].description
        for words in recipe_words:
            assert words in description, (variant, name, words)


def test_full_only_actions_are_unknown_in_classic() -> None:
    assert action_id("make_diamond_sword", "full") == 21
    with pytest.raises(UserError, match="MAKE_DIAMOND_SWORD"):
        action_id("MAKE_DIAMOND_SWORD", Variant.CLASSIC)


def test_lookups_round_trip_and_reject_bad_values() -> None:
    for variant in Variant:
        for spec in action_catalogue(variant):
            assert action_names(variant)[action_id(spec.name.lower(), variant)] == spec.name
    with pytest.raises(UserError, match="bogus"):
        action_names("bogus")
