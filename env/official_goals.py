"""Typed goals (`env.goals`) from the official dataset modules' values as `env.official_ast`
evaluates them: a split's dict of goal entries, each entry's instruction, paraphrases, checker and
target (an achievement mask or one of the placing and building records), checked as the official
loader would build them."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from env.achievements import ACHIEVEMENT_IDS
from env.craftax_names import FULL_BLOCKS
from env.errors import UserError
from env.goals import (
    CROSS_TYPES,
    SIDES,
    AnyGoal,
    BuildLineGoal,
    BuildSquareGoal,
    BuildStarGoal,
    ConditionalPlacingGoal,
    Goal,
    LocalizationGoal,
    Split,
    category_of,
    difficulty_of,
)
from env.official_ast import (
    AchievementRef,
    EnumRef,
    Opaque,
    SourceTree,
    StateRecord,
    Table,
    TargetState,
)
from env.official_tables import (
    COUNTED_ITEM,
    ENUMS,
    OFFICIAL_MISSING_INSTRUCTION,
    REQUIRED_SPLITS,
    SCENARIO_KINDS,
    SCENARIOS_PACKAGE,
    STATE_KINDS,
    TARGET_STATE_FUNCTION,
)


def split_goals(
    tree: SourceTree, split: Split, module_name: str, variables: tuple[str, ...]
) -> list[AnyGoal]:
    """The goals of `split`, bound to the first of `variables` that `module_name` defines; none
    for a missing split the official loader reads as empty."""
    module = tree.module(f"{SCENARIOS_PACKAGE}.{module_name}", str(tree.label))
    variable = next((name for name in variables if name in module.bindings), None)
    if variable is None:
        if split not in REQUIRED_SPLITS:
            return []
        raise UserError(
            f"{module.display} defines none of {', '.join(variables)} (the {split} split)"
        )
    table = module.lookup(variable, module.display)
    if not isinstance(table, Table):
        raise UserError(f"{module.display}: {variable} is not a dict of goals")
    goals = []
    for key, entry in table.items():
        if isinstance(entry, dict) and isinstance(entry.get("arguments"), str):
            # Code quoted as a string: the official loader cannot build its target at all.
            tree.notes.append(f"goal {key!r} at {table.locations[key]} has quoted arguments")
            continue
        goals.append(build_goal(split, key, entry, table.locations[key]))
    return goals


def build_goal(split: Split, key: Any, entry: Any, where: str) -> AnyGoal:
    if not isinstance(key, str) or not isinstance(entry, dict):
        raise UserError(f"{where}: goal {key!r} is not a string key with a dict of fields")
    instruction = entry.get("instruction")
    paraphrases = entry.get("instruction_paraphrases", [])
    if instruction is None and "Instruction" in entry:
        # The official loader reads only the lower-case keys and falls back to this text (the
        # craftext 0.2.2 wheel's localization test goals are spelt "Instruction").
        instruction, paraphrases = OFFICIAL_MISSING_INSTRUCTION, []
    target = entry.get("arguments")
    if not isinstance(instruction, str):
        raise UserError(f"{where}: goal {key!r} has no literal 'instruction' string")
    if not isinstance(paraphrases, list) or not all(isinstance(text, str) for text in paraphrases):
        raise UserError(
            f"{where}: goal {key!r} has 'instruction_paraphrases' that are not literal strings"
        )
    checker = entry.get("scenario_checker")
    if isinstance(checker, EnumRef) and checker.enum == "Scenarios":
        kind = SCENARIO_KINDS.get(checker.member)
        if kind is None:
            raise UserError(
                f"{where}: goal {key!r} uses the {checker.member} checker, which is not supported"
            )
        stated = "achievements" if isinstance(target, TargetState) else None
        if isinstance(target, StateRecord):
            stated = STATE_KINDS[target.name]
        if stated is not None and stated != kind:
            raise UserError(
                f"{where}: goal {key!r} names the {checker.member} checker but builds a {stated} target"
            )
    if isinstance(target, StateRecord):
        return _record_goal(split, key, instruction, paraphrases, target)
    if not isinstance(target, TargetState):
        raise UserError(
            f"{where}: goal {key!r} has no {TARGET_STATE_FUNCTION}(required=..., forbidden=...)"
        )
    required = _achievement_names(target.required, key, "required", target.where)
    forbidden = _achievement_names(target.forbidden, key, "forbidden", target.where)
    try:
        return Goal(
            id=key,
            scenario=difficulty_of(split),
            split=split,
            category=category_of(split, required, forbidden),
            instruction=instruction,
            paraphrases=tuple(paraphrases),
            required=required,
            forbidden=forbidden,
        )
    except ValidationError as error:
        raise UserError(f"{where}: goal {key!r} is invalid: {error.errors()[0]['msg']}") from None


def _record_goal(
    split: Split, key: str, instruction: str, paraphrases: list[str], record: StateRecord
) -> AnyGoal:
    values = {
        name: _integer(value, key, name, record.where) for name, value in record.fields.items()
    }
    common: dict[str, Any] = {
        "id": key,
        "scenario": difficulty_of(split),
        "split": split,
        "instruction": instruction,
        "paraphrases": tuple(paraphrases),
    }
    try:
        if record.name == "ConditionalPlacingState":
            code = values["object_inventory_enum"]
            return ConditionalPlacingGoal(
                **common,
                collect=COUNTED_ITEM[min(max(code, 0), len(COUNTED_ITEM) - 1)],
                collect_count=values["count_to_collect"],
                place=_block(values["object_to_place"], key, record.where),
                place_count=values["count_to_stand"],
            )
        if record.name == "LocalizaPlacingState":
            side = values["side"]
            if not 0 <= side < len(SIDES):
                raise UserError(f"{record.where}: goal {key!r} has side {side}, not 0-3")
            return LocalizationGoal(
                **common,
                place=_block(values["object_name"], key, record.where),
                target=_block(values["target_object_name"], key, record.where),
                side=SIDES[side],
                distance=values["distance"],
            )
        if record.name == "BuildLineState":
            return BuildLineGoal(
                **common,
                block=_block(values["block_type"], key, record.where),
                size=values["size"],
                diagonal=bool(values["is_diagonal"]),
            )
        if record.name == "BuildSquareState":
            return BuildSquareGoal(
                **common, block=_block(values["block_type"], key, record.where), size=values["size"]
            )
        cross = values["cross_type"]
        if not 0 <= cross < len(CROSS_TYPES):
            raise UserError(f"{record.where}: goal {key!r} has cross type {cross}, not 0-2")
        return BuildStarGoal(
            **common,
            block=_block(values["block_type"], key, record.where),
            size=values["size"],
            cross=CROSS_TYPES[cross],
        )
    except ValidationError as error:
        raise UserError(
            f"{record.where}: goal {key!r} is invalid: {error.errors()[0]['msg']}"
        ) from None


def _integer(value: Any, goal: str, field: str, where: str) -> int:
    if isinstance(value, EnumRef):
        members = ENUMS[value.enum]
        if value.member not in members:
            raise UserError(f"{value.where}: goal {goal!r}: unknown {value.enum}.{value.member}")
        return members[value.member]
    if isinstance(value, bool | int):
        return int(value)
    text = value.text if isinstance(value, Opaque) else repr(value)
    raise UserError(f"{where}: goal {goal!r}: {field} is {text!r}, not a number or a known enum")


def _block(code: int, goal: str, where: str) -> str:
    if not 0 <= code < len(FULL_BLOCKS):
        raise UserError(f"{where}: goal {goal!r}: block code {code} is not a Craftax block")
    return FULL_BLOCKS[code]


def _achievement_names(values: Any, goal: str, role: str, where: str) -> tuple[str, ...]:
    if not isinstance(values, list) or not all(
        isinstance(value, AchievementRef) for value in values
    ):
        raise UserError(f"{where}: goal {goal!r}: {role} must be a list of Achievement.NAME")
    unknown = [value.name for value in values if value.name not in ACHIEVEMENT_IDS]
    if unknown:
        raise UserError(f"{where}: goal {goal!r}: unknown achievements {unknown} in {role}")
    return tuple(value.name for value in values)
