"""The JSON schemas an agent holds a model's answers to under `--structured-output`.

`reading_schema`: a goal reading, built from the pydantic models of the readings
(`run_data.readings`: each kind's typed parameters, declared once in `env.goals`) with every name
narrowed to the names the grounding parser reads in the variant (achievements, blocks, items), and
laid out as the grounding prompt asks for it (`agents.grounding.reading_json`: EASY's achievements
goal without its `kind`, every goal of Medium and Hard with it), each list of achievements at
most `READING_MAX` long. An answer that follows it always parses as a reading: the one rule JSON
Schema cannot state, that no achievement is both required and forbidden, the parser settles by
reading such a name as required.

`action_schema`: an action name, as `{"action": NAME}` over the variant's 43 or 17 names, with a
`reasoning` string first for agents that reason before answering (`cot`); `answered_action`
reads the name back.
"""

from __future__ import annotations

import json
from typing import Any

from env.errors import UserError
from env.goals import DIFFICULTY_KINDS, Difficulty
from env.variant import Variant
from llm_agents.agents.answers.actions import action_names
from llm_agents.agents.grounding import goal_vocabulary, inventory_items
from llm_agents.backends.base import OutputSchema
from llm_agents.run_data.readings import READING_CLASSES

__all__ = [
    "READING_MAX",
    "STRUCTURED_AGENTS",
    "action_schema",
    "agent_schema",
    "answered_action",
    "reading_schema",
]

#: The built-in agents that ask under a schema, and what their answers are.
STRUCTURED_AGENTS = {
    "zero-shot": "an action",
    "cot": "reasoning, then an action",
    "guided": "a goal",
}

#: The most names a reading's list may hold. CrafText's goals name at most 3 required and 1
#: forbidden achievement (tests check the data against these); one more of each leaves a reader
#: room to over-read, while an answer looping through the whole vocabulary, as small models do,
#: is closed by the grammar instead of being cut mid-name by `max_tokens`: the longest reading
#: allowed is 55 Qwen2.5 tokens, within the 64 the guided runs give.
READING_MAX = {"required": 4, "forbidden": 2}
#: Schema keywords that describe rather than constrain: left out of what a backend compiles.
_DESCRIPTIVE = ("title", "description", "default")
#: The placing goals' fields that name a block or an inventory item (as the parser reads them).
_BLOCK_FIELDS = frozenset({"place", "target", "block"})
_ITEM_FIELDS = frozenset({"collect"})


def _kind_schema(kind: str, variant: Variant, difficulty: Difficulty) -> dict[str, Any]:
    generated = READING_CLASSES[kind].model_json_schema()  # type: ignore[index]
    properties: dict[str, Any] = {}
    for field, spec in generated["properties"].items():
        spec = {key: value for key, value in spec.items() if key not in _DESCRIPTIVE}
        if field == "kind" and kind == "achievements" and difficulty == "easy":
            continue  # EASY's prompt offers no other kind and asks for none
        if field in ("required", "forbidden"):
            names = list(goal_vocabulary(variant))
            spec = {"type": "array", "items": {"enum": names}, "maxItems": READING_MAX[field]}
            if field == "required":
                spec["minItems"] = 1
        elif field in _BLOCK_FIELDS:
            spec = {"enum": list(variant.block_names)}
        elif field in _ITEM_FIELDS:
            spec = {"enum": list(inventory_items(variant))}
        properties[field] = spec
    return {
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }


def reading_schema(variant: Variant, difficulty: Difficulty) -> OutputSchema:
    """The schema of a goal reading of `difficulty` over `variant`'s names."""
    kinds = [_kind_schema(kind, variant, difficulty) for kind in DIFFICULTY_KINDS[difficulty]]
    schema = kinds[0] if len(kinds) == 1 else {"anyOf": kinds}
    return OutputSchema.of(f"goal_reading_{difficulty}_{variant.value}", schema)


def action_schema(variant: Variant, reasoning: bool = False) -> OutputSchema:
    """The schema of an answer naming one of `variant`'s actions, after a `reasoning` string
    where the agent reasons first."""
    properties: dict[str, Any] = {"reasoning": {"type": "string"}} if reasoning else {}
    properties["action"] = {"enum": list(action_names(variant))}
    schema = {
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }
    name = f"action_{'reasoned_' if reasoning else ''}{variant.value}"
    return OutputSchema.of(name, schema)


def answered_action(answer: str) -> str:
    """The action an answer under `action_schema` names; the answer itself where it is not
    such JSON (cut short by `max_tokens`, or from a backend that did not hold it), so the
    action parser reads it as any other answer."""
    try:
        parsed = json.loads(answer)
    except json.JSONDecodeError:
        return answer
    action = parsed.get("action") if isinstance(parsed, dict) else None
    return action if isinstance(action, str) else answer


def agent_schema(agent: str, variant: Variant, difficulty: Difficulty) -> OutputSchema:
    """The schema `agent`'s requests are held to under `--structured-output`; a `UserError`
    for an agent that asks no such question (few-shot's demonstrations answer in plain names,
    the skills agent picks among its own options, expert and noop ask nothing)."""
    if agent == "guided":
        return reading_schema(variant, difficulty)
    if agent in ("zero-shot", "cot"):
        return action_schema(variant, reasoning=agent == "cot")
    listed = ", ".join(f"{name} ({what})" for name, what in STRUCTURED_AGENTS.items())
    raise UserError(f"--structured-output holds the answers of {listed}; not of the {agent} agent")
