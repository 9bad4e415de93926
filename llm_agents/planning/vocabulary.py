"""Which words a plan may use: the Craftax names of the variant and common words."""

from __future__ import annotations

import re
from functools import cache

from env import craftax_names as names
from env.variant import Variant

#: Enum members that are engine bookkeeping, not things a plan can name.
_INTERNAL_NAMES = frozenset(
    {"INVALID", "OUT_OF_BOUNDS", "DARKNESS", "NONE", "LADDER_DOWN_BLOCKED", "ARROW2"}
    | {"FIREBALL2", "ICEBALL2", "GRAVE2", "GRAVE3", "NECROMANCER_VULNERABLE"}
)
#: Achievement prefixes followed by a creature's name (DEFEAT_ZOMBIE, EAT_COW).
_CREATURE_PREFIXES = ("DEFEAT_", "EAT_")

#: Words any plan may use besides Craftax names: function words, generic verbs, directions,
#: counts, units of space, the shapes Medium and Hard goals build (lines, squares, stars of
#: straight, diagonal or combined arms) and words about the plan itself. Synonyms of Craftax things ("rock",
#: "smelter", "workbench", "seeds") are deliberately absent: a plan must use the game's names.
_COMMON_WORDS_TEXT = """
    a an the this that these those it its them they their there here you your yourself player agent
    i me my we our us he she his her itself themselves one's
    and or but then if until while when once before after again also only just still so as than
    to of in on at by for from with without into onto near next beside nearby nearest close closer
    closest around between behind front above below under over top bottom side sides edge
    beneath underneath atop upon within through across along toward towards away off out ahead
    against among about per via
    left right up down north south east west forward back backward straight horizontal vertical
    diagonal upper lower middle center centre corner adjacent opposite
    is are be been being was were have has had do does done did can could will would should must
    may might need needed not no all any each every both some more most less least few many much
    enough another other same new several single multiple additional extra remaining total
    one two three four five six seven eight nine ten eleven twelve first second third fourth fifth
    last final initial current previous original twice thrice times time day night
    go went gone move walk head turn face stand stay step return reach approach navigate travel
    explore find found locate look search spot identify check ensure keep continue repeat wait
    get got take took gather collect obtain acquire harvest mine chop cut dig break hit strike use
    make made craft build create place put set position drop plant
    eat drink sleep rest wake attack fight kill defeat avoid protect survive
    start begin proceed finish complete end stop confirm verify validate select choose pick
    count measure observe inspect examine scan view see watch note remember determine decide
    prepare arrange align fill clear leave hold carry bring follow seek hunt slay encounter
    engage interact perform apply add remove replace adjust ready
    block blocks tile tiles square squares space spaces cell cells spot area location position
    distance direction way path ground surface floor row column line grid pattern shape form
    unit units point spot zone region site
    item items object objects resource resources material materials inventory health food energy
    task goal plan action instruction step steps game map world environment surroundings
    desired required necessary suitable specific specified designated chosen selected existing
    appropriate correct correctly available visible empty full small large big
    piece pieces number size length sequence target source based surrounding consecutive further
    successful accordingly strategically presence existence report work
    consume deposit retrieve destroy construct assemble
    creature creatures enemy monster animal tool weapon
    star cross plus arm ray combined long wide tall pair exactly apart lay structure formation
    layout figure outline border perimeter solid
"""
COMMON_WORDS = frozenset(_COMMON_WORDS_TEXT.split())
#: Derivational endings stripped to reach a known word (wooden -> wood, upwards -> up).
_DERIVATIONAL_SUFFIXES = ("wards", "ward", "ment", "ion", "ly", "en", "er")

#: Words of letters; tokens holding digits (2x2, 1st) are counts, never names.
_WORD = re.compile(r"\b[a-z]+(?:'[a-z]+)?\b")


@cache
def craftax_things(variant: Variant) -> tuple[str, ...]:
    """Names of blocks, items, projectiles and creatures of the variant, e.g. `CRAFTING_TABLE`."""
    enums: tuple[tuple[str, ...], ...]
    if variant is Variant.FULL:
        enums = (names.FULL_BLOCKS, names.FULL_ITEMS, names.FULL_PROJECTILES)
    else:
        enums = (names.CLASSIC_BLOCKS,)
    # Creatures are named as their achievements name them (DEFEAT_ZOMBIE, EAT_COW).
    creatures = [
        name.removeprefix(prefix)
        for name in variant.achievement_names
        for prefix in _CREATURE_PREFIXES
        if name.startswith(prefix)
    ]
    things = [name for enum in enums for name in enum if name not in _INTERNAL_NAMES]
    return tuple(dict.fromkeys(things + creatures))


@cache
def craftax_vocabulary(variant: Variant = Variant.FULL) -> frozenset[str]:
    """Lower-case words of every Craftax name of the variant: things, creatures, actions, achievements."""
    every = [*craftax_things(variant), *variant.achievement_names, *variant.action_names]
    return frozenset(word for name in every for word in name.lower().split("_") if word.isalpha())


def _known(word: str, vocabulary: frozenset[str]) -> bool:
    """Whether a word or a plain inflection or derivation of it (stones, placing, wooden) is known."""
    word = word.removesuffix("'s")
    stems = {word}
    if word.endswith(("ies", "ied")):
        stems.add(word[:-3] + "y")
    for suffix in ("es", "s", "ing", "ed", *_DERIVATIONAL_SUFFIXES):
        if word.endswith(suffix) and len(word) > len(suffix) + 1:
            base = word[: -len(suffix)]
            stems |= {base, base + "e", base[:-1]}
    return any(stem in vocabulary or stem in COMMON_WORDS for stem in stems)


def word_tokens(text: str) -> list[str]:
    """The lower-case words of a text that the vocabulary check looks at (no numbers)."""
    return _WORD.findall(text.lower())


def is_known(word: str, variant: Variant = Variant.FULL) -> bool:
    """Whether a lower-case word is a Craftax name of the variant, a common word, or a form of one."""
    return _known(word, craftax_vocabulary(variant))


def unknown_words(text: str, variant: Variant = Variant.FULL) -> list[str]:
    """Words of `text` that are neither Craftax names of the variant nor common words, each once."""
    return list(dict.fromkeys(w for w in word_tokens(text) if not is_known(w, variant)))
