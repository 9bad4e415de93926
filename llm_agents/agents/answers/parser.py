"""Turns a model's free-text answer into one action id of a variant.

Stages, first match wins:
1. reasoning blocks (`<think>...</think>` and the like) are dropped by the backends' own
   `split_reasoning`: an opening tag with no close makes the rest reasoning, a close with no
   opening makes what precedes it reasoning;
2. `field`: the last explicit answer field or tag (`ACTION: X`, `<action>X</action>`,
   `<|ACTION|>X<|END|>`, `{"action": "X"}`) decides; placeholders such as `<NAME>` (the
   answer-format instruction echoed back) are not answers;
3. `exact`: the answer, or one of its lines, is an action name, insensitive to case, spaces,
   hyphens and underscores (`make wood pickaxe` = MAKE_WOOD_PICKAXE);
4. `alias`: ... or a known alias (`move west`, `west`, `left` -> LEFT; `collect wood`,
   `attack` -> DO; a numeric id);
5. `mention`: the last line naming exactly one action in running text decides; lines naming
   several (an echoed action list) and `NAME: description` lines (an echoed catalogue or
   history) are skipped;
6. `fuzzy`: a short final line close to a name or alias (rapidfuzz ratio >= 85).
Otherwise the result is `invalid` (action None); the caller applies its fallback.
Diagonal moves (`north-west`) match nothing: no single action does them.
The parser never raises on any text and runs in time linear in its length.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache, lru_cache
from typing import Literal

from pydantic import BaseModel, ConfigDict
from rapidfuzz import fuzz, process

from env.variant import Variant, as_variant
from llm_agents.agents.answers.actions import action_names
from llm_agents.backends.reasoning import split_reasoning

ParseStage = Literal["field", "exact", "alias", "mention", "fuzzy", "invalid", "skill"]
"""The parser's stages; `skill` is none of its own: the `skills` agent marks with it the steps
whose action a running skill chose, where no answer was read."""

#: Lowest rapidfuzz ratio (0-100) at which a short answer counts as a misspelt name.
FUZZY_THRESHOLD = 85.0
#: Longest answer (normalised characters) the fuzzy stage considers; longer is prose.
FUZZY_MAX_CHARS = 40
_FUZZY_MIN_CHARS = 3
_DO_PHRASE_MAX_WORDS = 6
_LIST_MIN_NAMES = 3


class ParseResult(BaseModel):
    """What the parser read from one model answer."""

    model_config = ConfigDict(frozen=True)

    action: int | None
    """The action id, or None when no stage matched."""
    name: str | None
    """The action's name (e.g. `MAKE_WOOD_PICKAXE`), or None."""
    stage: ParseStage
    """The stage that matched, `invalid` when none did."""
    matched: str | None = None
    """The piece of the answer the action was read from."""
    raw: str
    """The text given to the parser, unchanged."""

    @property
    def valid(self) -> bool:
        return self.action is not None


# ---------------------------------------------------------------- normalisation

_WORD_SUBSTITUTIONS = {
    "wooden": "wood",
    "armor": "armour",
    "workbench": "table",
    "crafting table": "table",
}
_NON_WORD = re.compile(r"[^a-z0-9]+")
_DIAGONAL = re.compile(r"\b(north|south|up|down) ?(east|west|left|right)\b")
_DIAGONAL_WORD = re.compile(r"(?:north|south)(?:east|west)")
_SUBSTITUTION = re.compile(r"\b(" + "|".join(_WORD_SUBSTITUTIONS) + r")\b")


def _normalise(text: str) -> str:
    """Lower case, words separated by single spaces, diagonals as one word."""
    words = _NON_WORD.sub(" ", text.lower()).strip()
    words = _DIAGONAL.sub(r"\1\2", words)
    return _SUBSTITUTION.sub(lambda m: _WORD_SUBSTITUTIONS[m.group(1)], words)


# ---------------------------------------------------------------- vocabulary

_DIRECTION_WORDS = {
    "LEFT": ("left", "west"),
    "RIGHT": ("right", "east"),
    "UP": ("up", "north"),
    "DOWN": ("down", "south"),
}
_MOVE_VERBS = (
    "move",
    "go",
    "walk",
    "step",
    "head",
    "turn",
    "face",
    "run",
    "move to the",
    "go to the",
)
_DO_VERBS = (
    "do",
    "interact",
    "use",
    "attack",
    "hit",
    "collect",
    "gather",
    "mine",
    "chop",
    "harvest",
    "pick up",
    "pickup",
    "take",
    "grab",
    "eat",
    "drink",
    "fight",
    "punch",
    "strike",
    "kill",
    "defeat",
    "break",
    "dig",
)
#: Single words that name one action even inside running text.
_MENTION_WORDS = (
    "noop",
    "sleep",
    "descend",
    "ascend",
    "attack",
    "interact",
    "collect",
    "chop",
    "gather",
    "harvest",
    "pickup",
    "fireball",
    "iceball",
)
_MAKE_VERBS = ("make", "craft", "build", "create")
_PLACE_VERBS = ("place", "put", "build", "set", "set up")
_PLACEHOLDERS = frozenset({"", "name", "action", "action name", "x", "your action", "answer"})


def _aliases(names: tuple[str, ...]) -> tuple[dict[str, str], dict[str, str]]:
    """Normalised phrase -> action name (names themselves are matched separately).

    The second mapping holds phrases that name an action only as a whole answer: a bare item
    ("wood pickaxe") in running text is more often a thing to use than a thing to make.
    """
    known = set(names)
    aliases: dict[str, str] = {}
    bare_items: dict[str, str] = {}
    for name, words in _DIRECTION_WORDS.items():
        for word in words:
            aliases[word] = name
            for verb in _MOVE_VERBS:
                aliases[f"{verb} {word}"] = name
    for verb in _DO_VERBS:
        aliases[verb] = "DO"
    aliases.update(
        {
            phrase: "NOOP"
            for phrase in (
                "no op",
                "nothing",
                "do nothing",
                "wait",
                "idle",
                "stay",
                "stand still",
                "none",
                "pass",
                "no action",
                # Asleep, every action is ignored and waking is automatic: nothing to do.
                "wake up",
            )
        }
    )
    aliases.update({"go to sleep": "SLEEP", "nap": "SLEEP"})
    if "REST" not in known:
        aliases["rest"] = "SLEEP"
    placeables = {
        "PLACE_TABLE": ("table",),
        "PLACE_FURNACE": ("furnace",),
        "PLACE_STONE": ("stone", "rock", "block"),
        "PLACE_PLANT": ("plant", "sapling", "seed"),
        "PLACE_TORCH": ("torch",),
    }
    for name, objects in placeables.items():
        if name in known:
            for thing in objects:
                for verb in _PLACE_VERBS:
                    aliases[f"{verb} {thing}"] = name
                    aliases[f"{verb} a {thing}"] = name
    aliases["plant"] = aliases["plant sapling"] = "PLACE_PLANT"
    for name in names:
        if name.startswith("MAKE_"):
            item = name.removeprefix("MAKE_").lower().replace("_", " ")
            plural = item + ("es" if item.endswith("h") else "s")
            for verb in _MAKE_VERBS:
                for thing in (item, plural, f"a {item}"):
                    aliases[f"{verb} {thing}"] = name
            bare_items[item] = name
        elif name.startswith("DRINK_POTION_"):
            colour = name.removeprefix("DRINK_POTION_").lower()
            for phrase in (f"drink {colour} potion", f"drink {colour}", f"{colour} potion"):
                aliases[phrase] = name
        elif name.startswith("LEVEL_UP_"):
            aliases[name.removeprefix("LEVEL_UP_").lower()] = name
    optional = {
        "DESCEND": ("go downstairs", "go down stairs", "go down the ladder", "take ladder down"),
        "ASCEND": ("go upstairs", "go up stairs", "go up the ladder", "take ladder up"),
        "SHOOT_ARROW": ("shoot", "fire arrow", "shoot an arrow", "shoot bow"),
        "CAST_FIREBALL": ("fireball",),
        "CAST_ICEBALL": ("iceball",),
        "READ_BOOK": ("read", "read a book", "read the book"),
    }
    for name, phrases in optional.items():
        if name in known:
            aliases.update(dict.fromkeys(phrases, name))
    return aliases, bare_items


@dataclass(frozen=True)
class _Vocabulary:
    names: tuple[str, ...]
    ids: dict[str, int]
    compact: dict[str, str]
    """Name without separators ("makewoodpickaxe") -> name."""
    aliases: dict[str, str]
    mention_pattern: re.Pattern[str]
    """Phrases that name an action even in running text (on normalised text)."""
    mention_names: dict[str, str]
    upper_pattern: re.Pattern[str]
    """Action names written as enum names (`MAKE_WOOD_PICKAXE`, `LEFT`) in raw text."""
    catalogue_line: re.Pattern[str]
    """`NAME: text` lines, as in an echoed action list or history."""
    fuzzy_keys: tuple[str, ...]
    fuzzy_names: tuple[str, ...]


def _alternation(phrases: list[str]) -> str:
    """A regex matching any of the phrases, longest first, shaped as a trie.

    A flat `a|b|c` alternation retries every phrase at every position; the trie shares
    prefixes, so matching costs the length of the text, not that times the phrase count.
    """
    trie: dict[str, dict] = {}
    for phrase in phrases:
        node = trie
        for char in phrase:
            node = node.setdefault(char, {})
        node[""] = {}
    return _trie_regex(trie)


def _trie_regex(node: dict[str, dict]) -> str:
    branches = [
        re.escape(char) + _trie_regex(child) for char, child in sorted(node.items()) if char
    ]
    if not branches:
        return ""
    body = branches[0] if len(branches) == 1 else "(?:" + "|".join(branches) + ")"
    # A phrase ending here is optional continuation: greedy `?` prefers the longer phrase.
    return f"(?:{body})?" if "" in node else body


@cache
def _vocabulary(variant: Variant) -> _Vocabulary:
    names = action_names(variant)
    aliases, bare_items = _aliases(names)
    spaced = {name.lower().replace("_", " "): name for name in names}
    mentions = {phrase: name for phrase, name in {**aliases, **spaced}.items() if " " in phrase}
    for word in _MENTION_WORDS:
        name = spaced.get(word) or aliases.get(word)
        if name is not None:
            mentions[word] = name
    # In prose "go up"/"go down" means a ladder or a list as often as a move.
    for phrase in ("go up", "go down"):
        mentions.pop(phrase, None)
    upper = _alternation(list(names))
    fuzzy_table = {**{name.lower().replace("_", ""): name for name in names}}
    fuzzy_table.update(
        {phrase.replace(" ", ""): name for phrase, name in {**bare_items, **aliases}.items()}
    )
    return _Vocabulary(
        names=names,
        ids={name: i for i, name in enumerate(names)},
        compact={name.lower().replace("_", ""): name for name in names},
        aliases={**bare_items, **aliases},
        mention_pattern=re.compile(rf"\b(?:{_alternation(list(mentions))})\b"),
        mention_names=mentions,
        upper_pattern=re.compile(rf"(?<![A-Za-z_])(?:{upper})(?![A-Za-z_])"),
        catalogue_line=re.compile(rf"^[\s\-*•>#\d.)]*(?:step \d+:\s*)?\**(?:{upper})\**\s*:\s*\S"),
        fuzzy_keys=tuple(fuzzy_table),
        fuzzy_names=tuple(fuzzy_table.values()),
    )


# ---------------------------------------------------------------- resolution


def _whole(candidate: str, vocabulary: _Vocabulary) -> tuple[str, ParseStage] | None:
    """The action a whole candidate names: exactly, by alias, or by numeric id."""
    words = _normalise(candidate)
    if not words:
        return None
    compact = words.replace(" ", "")
    if compact in vocabulary.compact:
        return vocabulary.compact[compact], "exact"
    if words in vocabulary.aliases:
        return vocabulary.aliases[words], "alias"
    if words.isdigit() and len(words) <= 3 and int(words) < len(vocabulary.names):
        return vocabulary.names[int(words)], "alias"
    split = words.split(" ")
    if (
        split[0] in _DO_VERBS
        and split[0] != "do"
        and len(split) <= _DO_PHRASE_MAX_WORDS
        and not _mentioned(words, vocabulary) - {"DO"}
    ):
        # "attack zombie with wood sword", "pickup coal": an interaction with the faced cell.
        return "DO", "alias"
    return None


def _mentioned(words: str, vocabulary: _Vocabulary) -> set[str]:
    return {
        vocabulary.mention_names[m.group(0)] for m in vocabulary.mention_pattern.finditer(words)
    }


def _mentions_in_line(line: str, vocabulary: _Vocabulary) -> set[str]:
    found = _mentioned(_normalise(line), vocabulary)
    found.update(m.group(0) for m in vocabulary.upper_pattern.finditer(line))
    return found


def _fuzzy(candidate: str, vocabulary: _Vocabulary) -> str | None:
    words = _normalise(candidate)
    compact = words.replace(" ", "")
    if (
        not _FUZZY_MIN_CHARS <= len(words) <= FUZZY_MAX_CHARS
        or words in _PLACEHOLDERS
        or _DIAGONAL_WORD.search(words)
    ):
        return None
    best = process.extractOne(
        compact, vocabulary.fuzzy_keys, scorer=fuzz.ratio, score_cutoff=FUZZY_THRESHOLD
    )
    return None if best is None else vocabulary.fuzzy_names[best[2]]


# ---------------------------------------------------------------- stages

_TAG_FIELDS = (
    re.compile(r"<\s*action\s*>([^<]*)<\s*/\s*action\s*>", re.IGNORECASE),
    re.compile(r"<\|\s*action\s*\|>(.*?)(?:<\||$)", re.IGNORECASE | re.MULTILINE),
    re.compile(r"""["']action["']\s*:\s*["']?([^"'\n,}]*)""", re.IGNORECASE),
)
_LINE_FIELD = re.compile(
    r"(?:^|[^a-z0-9])(?:final |next |chosen |selected )?(?:action|answer)\W{0,3}?\s*(?:is\s*)?[:=]\s*(.*)$",
    re.IGNORECASE | re.MULTILINE,
)
_VALUE_HEAD = re.compile(r"^(.*?)(?:[(\[,;.!?]| - | because | to | so | then |$)")
_PLACEHOLDER = re.compile(r"<[^<>]{0,20}>|\bone of\b|\baction names?\b", re.IGNORECASE)


def _fields(answer: str) -> list[tuple[int, str]]:
    found = [(m.start(), m.group(1)) for pattern in _TAG_FIELDS for m in pattern.finditer(answer)]
    found += [(m.start(), m.group(1)) for m in _LINE_FIELD.finditer(answer)]
    return sorted(
        (start, value)
        for start, value in found
        if not _PLACEHOLDER.search(value) and _normalise(value) not in _PLACEHOLDERS
    )


def _resolve_value(value: str, vocabulary: _Vocabulary) -> str | None:
    """The action an answer field holds, tolerating trailing explanations."""
    whole = _whole(value, vocabulary)
    if whole is not None:
        return whole[0]
    head_match = _VALUE_HEAD.match(_normalise_keep_punctuation(value))
    head = head_match.group(1) if head_match else ""
    head_resolved = _whole(head, vocabulary)
    if head_resolved is not None:
        return head_resolved[0]
    mentioned = _mentions_in_line(value, vocabulary)
    if len(mentioned) == 1:
        return mentioned.pop()
    return _fuzzy(head, vocabulary)


def _normalise_keep_punctuation(value: str) -> str:
    return value.strip().strip("*`'\" ").lower()


def _result(
    text: str, vocabulary: _Vocabulary, name: str | None, stage: ParseStage, matched: str | None
) -> ParseResult:
    if name is None:
        return ParseResult(action=None, name=None, stage="invalid", matched=None, raw=text)
    return ParseResult(
        action=vocabulary.ids[name], name=name, stage=stage, matched=matched, raw=text
    )


@lru_cache(maxsize=64)
def _prompt_lines(prompt: str) -> frozenset[str]:
    return frozenset(filter(None, (_normalise(line) for line in prompt.splitlines())))


def parse_action(
    text: str, variant: Variant | str, prompt: str | Sequence[str] | None = None
) -> ParseResult:
    """Read one action of `variant` from a model's answer; never raises on any text.

    `prompt`, the text the model was given (one string, or one per message), lets the line
    stages skip lines the model merely copied from it (an echoed plan or observation naming an
    action). Messages are normalised one by one and cached, so a system prompt shared by every
    step is read once.
    """
    variant = as_variant(variant)
    well_formed = _well_formed(text, variant)
    if well_formed is not None:
        return well_formed
    return _parse_layered(text, _vocabulary(variant), prompt)


#: The answer the step prompt asks for, written exactly: `ACTION: NAME`.
_WELL_FORMED_PREFIX = "ACTION: "


def _well_formed(text: str, variant: Variant) -> ParseResult | None:
    """The result of an answer that is exactly `ACTION: NAME` with NAME an action name, which
    every stage would read as the `field` stage does (the tests check each name), or None.

    Most answers of a model that follows the prompt are this one line: the layered stages
    (reasoning split, field patterns, normalisation) cost ten times more for it."""
    if not text.startswith(_WELL_FORMED_PREFIX):
        return None
    name = text[len(_WELL_FORMED_PREFIX) :]
    return _named_field(name, variant) if name in _vocabulary(variant).ids else None


@cache
def _named_field(name: str, variant: Variant) -> ParseResult:
    # Results are frozen: one per action name is made and shared.
    return ParseResult(
        action=_vocabulary(variant).ids[name],
        name=name,
        stage="field",
        matched=name,
        raw=_WELL_FORMED_PREFIX + name,
    )


def _parse_layered(
    text: str, vocabulary: _Vocabulary, prompt: str | Sequence[str] | None
) -> ParseResult:
    """`parse_action` through its stages, one after another (see the module)."""
    answer = split_reasoning(text).answer

    fields = _fields(answer)
    if fields:
        value = fields[-1][1]
        return _result(text, vocabulary, _resolve_value(value, vocabulary), "field", value.strip())

    whole = _whole(answer, vocabulary)
    if whole is not None:
        return _result(text, vocabulary, whole[0], whole[1], answer.strip())

    pieces = [prompt] if isinstance(prompt, str) else list(prompt or ())
    echoed = frozenset().union(*(_prompt_lines(piece) for piece in pieces))
    lines = [
        line.strip()
        for line in answer.splitlines()
        if line.strip() and _normalise(line) not in echoed
    ]
    line_matches = [(line, _whole(line, vocabulary)) for line in lines]
    whole_lines = [(line, found) for line, found in line_matches if found is not None]
    if len({found[0] for _, found in whole_lines}) >= _LIST_MIN_NAMES:
        # Bare names on lines of their own: an echoed action list or a plan, not one answer.
        return _result(text, vocabulary, None, "invalid", None)
    if whole_lines:
        line, (name, stage) = whole_lines[-1]
        return _result(text, vocabulary, name, stage, line)

    for line in reversed(lines):
        if vocabulary.catalogue_line.match(line) or _PLACEHOLDER.search(line):
            continue
        mentioned = _mentions_in_line(line, vocabulary)
        if len(mentioned) == 1:
            return _result(text, vocabulary, mentioned.pop(), "mention", line)

    if lines:
        fuzzy = _fuzzy(lines[-1], vocabulary)
        if fuzzy is not None:
            return _result(text, vocabulary, fuzzy, "fuzzy", lines[-1])
    return _result(text, vocabulary, None, "invalid", None)
