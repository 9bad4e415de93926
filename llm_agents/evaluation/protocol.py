"""Evaluation protocols: named presets of run settings, each choice with its source.

`default` is this project's protocol; `paper` is what the official CrafText evaluation does
(AIRI-Institute/CrafText at commit 1c518ae and its LLM baseline loop), so a run under it can be
set beside the published zero-shot numbers; `balrog` is BALROG's open-ended Crafter task (EASY
only: it plays no CrafText difficulty), to set a run beside BALROG's leaderboard. A preset only
fills in the settings a user did not set: `apply_protocol` puts it under the file and flag
settings and lists the explicit settings that depart from it, which the run records as
`protocol_overrides`.

Each protocol has a version per CrafText difficulty (`protocol_for`): `PROTOCOLS` holds EASY's.
Medium's `paper` protocol follows the official configs (Craftax-Classic, the official success
rule, the LLM loop's 250 steps and 0.7 temperature) and the paper's evaluation of 50 worlds per
instruction: the published Medium numbers are means over 50 worlds, so a run plays 50 episodes
per instruction, each in its own world (`per_episode`), where the EASY protocol follows the LLM
loop's one world. Hard's plays full Craftax (its configs) and only its train split (the
official data has no Hard test splits); the paper publishes no Hard numbers beside it.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from enum import Enum
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict

from env.dataset import PAPER_CATEGORIES, parse_categories
from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY, DIFFICULTY_CATEGORIES, Difficulty, check_difficulty
from env.rules import DEFAULT_SUCCESS_RULE, STEP_CAP
from env.variant import DEFAULT_VARIANT

ProtocolName = Literal["default", "paper", "balrog"]
PROTOCOL_NAMES: tuple[ProtocolName, ...] = get_args(ProtocolName)


class ProtocolChoice(BaseModel):
    """One setting a protocol fixes."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    setting: str
    """The `EvalConfig` key; generation settings as `generation.NAME`."""
    value: Any
    """The value the protocol gives it."""
    source: str
    """Where the choice comes from (shown in docs/protocols/index.md's tables)."""


class Protocol(BaseModel):
    """A named set of choices."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: ProtocolName
    """The name `--protocol` takes."""
    difficulty: Difficulty = DEFAULT_DIFFICULTY
    """The CrafText difficulty this version of the protocol is for."""
    summary: str
    """One line on what the protocol is for."""
    choices: tuple[ProtocolChoice, ...]
    """The settings it fixes."""

    def value(self, setting: str) -> Any:
        """The protocol's value of `setting`; KeyError when it fixes none."""
        for choice in self.choices:
            if choice.setting == setting:
                return choice.value
        raise KeyError(setting)


_OFFICIAL = "official CrafText code (AIRI-Institute/CrafText at 1c518ae)"
_LOOP = "the official LLM baseline loop"
# Both protocols take these two from the paper.
_PAPER_SPLITS = ProtocolChoice(
    setting="categories",
    value=PAPER_CATEGORIES,
    source="the paper's zero-shot table (Achievements one / combo, New objects)",
)
_STEP_CAP = ProtocolChoice(
    setting="max_steps", value=STEP_CAP, source=f"{_LOOP} (the paper states no step cap)"
)

PROTOCOLS: dict[ProtocolName, Protocol] = {
    "default": Protocol(
        name="default",
        summary="this project's protocol: the harder game, independent worlds, reproducible answers",
        choices=(
            ProtocolChoice(
                setting="variant",
                value=DEFAULT_VARIANT.value,
                source="ours: full Craftax is the current game; the checker's 22 achievement ids "
                "exist in both variants",
            ),
            _PAPER_SPLITS,
            _STEP_CAP,
            ProtocolChoice(
                setting="episodes_per_instruction",
                value=1,
                source=f"{_LOOP}; raise it for tighter intervals",
            ),
            ProtocolChoice(
                setting="success_rule",
                value=DEFAULT_SUCCESS_RULE,
                source="ours: a goal completed on the step the player dies was completed",
            ),
            ProtocolChoice(
                setting="world_seeding",
                value="per_episode",
                source="ours: a world per episode, so episodes are independent samples "
                "(the Wilson intervals assume it)",
            ),
            ProtocolChoice(
                setting="generation.temperature",
                value=0.0,
                source="ours: greedy answers make runs reproducible and resumable",
            ),
            ProtocolChoice(
                setting="generation.max_tokens",
                value=256,
                source="ours: room for a short thought before the action",
            ),
            ProtocolChoice(
                setting="history_length",
                value=5,
                source="ours: the last 5 actions, with their outcomes",
            ),
            ProtocolChoice(
                setting="structured_output",
                value=False,
                source="ours: free text, so a model's answers are its own; "
                "--structured-output holds them to a JSON schema",
            ),
        ),
    ),
    "paper": Protocol(
        name="paper",
        summary="the official CrafText evaluation, to compare with the published numbers",
        choices=(
            ProtocolChoice(
                setting="variant",
                value="classic",
                source=f"{_OFFICIAL}: its EASY checker masks 22 Craftax-Classic achievements "
                "and fails on full Craftax",
            ),
            _PAPER_SPLITS,
            _STEP_CAP,
            ProtocolChoice(
                setting="episodes_per_instruction",
                value=1,
                source=f"{_LOOP}: one episode per instruction, averaged per episode",
            ),
            ProtocolChoice(
                setting="success_rule",
                value="official",
                source=f"{_OFFICIAL}: on the step the game ends the wrapper checks the goal "
                "on the auto-reset world, so a goal completed on that step fails (and a Medium "
                "or Hard goal met in the new world succeeds)",
            ),
            ProtocolChoice(
                setting="world_seeding",
                value="official",
                source=f"{_LOOP}: every instruction in the one world of reset key PRNGKey(1)",
            ),
            ProtocolChoice(
                setting="generation.temperature", value=0.7, source=f"{_LOOP}: samples at 0.7"
            ),
            ProtocolChoice(
                setting="generation.max_tokens", value=10, source=f"{_LOOP}: a 10-token answer"
            ),
            ProtocolChoice(
                setting="history_length", value=4, source=f"{_LOOP}: the last 4 actions shown"
            ),
            ProtocolChoice(
                setting="structured_output",
                value=False,
                source=f"{_LOOP}: the answer is read from free text",
            ),
        ),
    ),
}

_BALROG = "BALROG's Crafter evaluation (balrog-ai/BALROG)"
PROTOCOLS["balrog"] = Protocol(
    name="balrog",
    summary="BALROG's open-ended Crafter task, to compare with its leaderboard (progression)",
    choices=(
        ProtocolChoice(
            setting="task",
            value="open_ended",
            source=f"{_BALROG}: no instruction, as many achievements as possible; judged by "
            "progression, not a checker",
        ),
        ProtocolChoice(
            setting="variant",
            value="classic",
            source=f"{_BALROG} plays Crafter, whose game Craftax-Classic re-implements",
        ),
        ProtocolChoice(
            setting="categories",
            value=("combo",),
            source="ours: the open-ended goal's set (it requires all 22 achievements)",
        ),
        ProtocolChoice(
            setting="max_steps", value=2000, source=f"{_BALROG}: episodes of up to 2,000 steps"
        ),
        ProtocolChoice(
            setting="episodes_per_instruction",
            value=10,
            source=f"{_BALROG}: 10 episodes per submission",
        ),
        ProtocolChoice(
            setting="world_seeding",
            value="per_episode",
            source=f"{_BALROG}: a fresh world (seed) per episode",
        ),
        ProtocolChoice(
            setting="generation.temperature",
            value=1.0,
            source=f"{_BALROG}: its default client samples at temperature 1.0",
        ),
        ProtocolChoice(
            setting="history_length",
            value=16,
            source=f"{_BALROG}: its default agent keeps 16 steps of history",
        ),
        ProtocolChoice(
            setting="fallback_action",
            value="NOOP",
            source=f"{_BALROG}: an invalid action is played as the environment's default (noop)",
        ),
        ProtocolChoice(
            setting="report_invalid_answers",
            value=True,
            source=f"{_BALROG}: the next observation tells the model its action was invalid",
        ),
    ),
)

_PAPER_WORLDS = "the paper's Table 2: success averaged over 50 worlds per instruction"


def _later_difficulty(difficulty: Difficulty) -> dict[str, Protocol]:
    """Medium's or Hard's version of each protocol: EASY's with the difficulty's own splits,
    and the paper's with what its configs and the paper's evaluation state."""
    medium = difficulty == "medium"
    paper_variant = "classic" if medium else "full"
    replaced = {
        "categories": ProtocolChoice(
            setting="categories",
            value=DIFFICULTY_CATEGORIES[difficulty] if medium else ("train",),
            source="the paper's Table 2 columns (Train / Paraphrased / New objects)"
            if medium
            else f"{_OFFICIAL}: SMALL/test.py defines no Hard test splits",
        ),
        "variant": ProtocolChoice(
            setting="variant",
            value=paper_variant,
            source=f"{_OFFICIAL}: its {difficulty}_* configs play "
            + ("Craftax-Classic" if medium else "full Craftax"),
        ),
        "episodes_per_instruction": ProtocolChoice(
            setting="episodes_per_instruction", value=50, source=_PAPER_WORLDS
        ),
        "world_seeding": ProtocolChoice(
            setting="world_seeding",
            value="per_episode",
            source=f"{_PAPER_WORLDS}, so each episode plays its own world",
        ),
    }
    every_split = (
        ProtocolChoice(
            setting="categories",
            value=DIFFICULTY_CATEGORIES[difficulty],
            source="ours: every split of the difficulty",
        )
        if medium
        else replaced["categories"]
    )
    default, paper = PROTOCOLS["default"], PROTOCOLS["paper"]
    return {
        "default": default.model_copy(
            update={
                "difficulty": difficulty,
                "choices": tuple(
                    every_split if c.setting == "categories" else c for c in default.choices
                ),
            }
        ),
        "paper": paper.model_copy(
            update={
                "difficulty": difficulty,
                "summary": f"the official CrafText evaluation of {difficulty} goals"
                + (", to compare with the published Medium numbers" if medium else ""),
                "choices": tuple(replaced.get(c.setting, c) for c in paper.choices),
            }
        ),
    }


_LATER_PROTOCOLS: dict[Difficulty, dict[str, Protocol]] = {
    "medium": _later_difficulty("medium"),
    "hard": _later_difficulty("hard"),
}


def get_protocol(name: str) -> Protocol:
    """The protocol called `name` (EASY's version), or a `UserError` listing the known ones."""
    if name not in PROTOCOLS:
        raise UserError(f"unknown protocol {name!r}; known: {', '.join(PROTOCOL_NAMES)}")
    return PROTOCOLS[name]


def protocol_for(name: str, difficulty: str = DEFAULT_DIFFICULTY) -> Protocol:
    """The version of protocol `name` for `difficulty`; a `UserError` for an unknown either."""
    protocol = get_protocol(name)
    level = check_difficulty(difficulty)
    if level == "easy":
        return protocol
    if protocol.name not in _LATER_PROTOCOLS[level]:
        raise UserError(
            f"--protocol {protocol.name} plays the open-ended Crafter task, no CrafText "
            f"difficulty: leave out --difficulty {level}"
        )
    return _LATER_PROTOCOLS[level][protocol.name]


def apply_protocol(
    settings: Mapping[str, Any], explicit: Iterable[str]
) -> tuple[dict[str, Any], list[str]]:
    """`settings` with its protocol's choices filled in under the `explicit` ones.

    `settings` are the merged file and flag settings, generation settings nested under
    `generation`; its `protocol` key names the protocol (`default` when absent). `explicit`
    holds the keys the user set (`generation.NAME` for generation settings). Returns the
    completed settings and the explicit settings whose values depart from the protocol's.
    """
    protocol = protocol_for(
        str(settings.get("protocol") or "default"),
        str(settings.get("difficulty") or DEFAULT_DIFFICULTY),
    )
    chosen = set(explicit)
    result = copy.deepcopy(dict(settings))
    overrides = []
    for choice in protocol.choices:
        head, _, leaf = choice.setting.rpartition(".")
        table = result.setdefault(head, {}) if head else result
        if choice.setting in chosen and leaf in table:
            if normalised_setting(choice.setting, table[leaf]) != normalised_setting(
                choice.setting, choice.value
            ):
                overrides.append(choice.setting)
        else:
            table[leaf] = copy.deepcopy(choice.value)
    return result, overrides


def normalised_setting(setting: str, value: Any) -> Any:
    """`value` of `setting` in the form two values are compared in."""
    if setting == "categories":
        return parse_categories(value)
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, list | tuple):
        return tuple(value)
    return value
