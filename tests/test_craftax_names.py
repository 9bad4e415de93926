"""`env.craftax_names`, copied by value to stay free of JAX, equals the installed craftax."""

import ast
from enum import Enum
from pathlib import Path

import pytest
from craftax.craftax import constants as full
from craftax.craftax.craftax_state import EnvState as FullState
from craftax.craftax_classic import constants as classic
from craftax.craftax_classic.envs.craftax_state import EnvState as ClassicState
from craftax.craftax_env import make_craftax_env_from_name

from env import craftax_names as names
from env.variant import Variant

#: Our mob name -> the spelling of craftax's achievement for it (its typo and its short form).
ACHIEVEMENT_SPELLING = {"ORC_SOLDIER": "ORC_SOLIDER", "KNIGHT_ARCHER": "ARCHER"}


def by_value(enum: type[Enum]) -> list[str]:
    """Member names in value order, checking the values are exactly 0..n-1."""
    members = sorted(enum, key=lambda member: member.value)
    assert [member.value for member in members] == list(range(len(members)))
    return [member.name for member in members]


def test_the_module_is_plain_data_importing_nothing() -> None:
    tree = ast.parse(Path(names.__file__).read_text(encoding="utf-8"))
    assert not [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
    assert not [node for node in tree.body if isinstance(node, ast.FunctionDef | ast.ClassDef)]


def test_actions_follow_craftax_ids() -> None:
    assert list(names.CLASSIC_ACTIONS) == by_value(classic.Action)
    assert list(names.FULL_ACTIONS) == by_value(full.Action)


def test_achievements_follow_craftax_ids() -> None:
    assert list(names.CLASSIC_ACHIEVEMENTS) == by_value(classic.Achievement)
    assert list(names.FULL_ACHIEVEMENTS) == by_value(full.Achievement)


def test_blocks_items_and_projectiles_follow_craftax_values() -> None:
    assert list(names.CLASSIC_BLOCKS) == by_value(classic.BlockType)
    assert list(names.FULL_BLOCKS) == by_value(full.BlockType)
    assert list(names.FULL_ITEMS) == by_value(full.ItemType)
    assert list(names.FULL_PROJECTILES) == by_value(full.ProjectileType)


def test_mobs_are_the_creatures_of_craftax_achievements() -> None:
    # craftax names a mob (class, type id) only through the achievement for beating it.
    achievement = {member.value: member.name for member in full.Achievement}
    table = full.MOB_ACHIEVEMENT_MAP.tolist()
    for row, mobs, prefix in (
        (0, names.PASSIVE_MOBS, "EAT_"),
        (1, names.MELEE_MOBS, "DEFEAT_"),
        (2, names.RANGED_MOBS, "DEFEAT_"),
    ):
        assert len(mobs) == len(set(mobs))
        expected = [prefix + ACHIEVEMENT_SPELLING.get(name, name) for name in mobs]
        assert [achievement[value] for value in table[row][: len(mobs)]] == expected
        # Beyond our names the row is padding (achievement 0), never an unnamed mob.
        assert set(table[row][len(mobs) :]) <= {0}
    classic_fields = set(ClassicState.__dataclass_fields__)
    for name in names.CLASSIC_MOBS:
        assert f"{name.lower()}s" in classic_fields
        assert {f"EAT_{name}", f"DEFEAT_{name}"} & set(names.CLASSIC_ACHIEVEMENTS)
    assert {"melee_mobs", "passive_mobs", "ranged_mobs"} <= set(FullState.__dataclass_fields__)


@pytest.mark.parametrize("variant", list(Variant))
def test_variant_tables_match_the_craftax_env_it_wraps(variant: Variant) -> None:
    env = make_craftax_env_from_name(variant.craftax_name, auto_reset=False)
    assert env.action_space(env.default_params).n == variant.num_actions
    assert len(variant.action_names) == variant.num_actions
    constants = full if variant is Variant.FULL else classic
    assert list(variant.achievement_names) == by_value(constants.Achievement)
