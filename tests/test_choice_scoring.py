"""The `loglik` scoring rules (`--choice-scoring`): how an option's log-probabilities become the
score that ranks it, in `ranked_choices`, the one place every backend ranks through."""

from __future__ import annotations

import math

import pytest

from llm_agents.backends.base import (
    ChatMessage,
    ChoiceSet,
    ContentFreeScores,
    OptionLoglik,
    choice_score,
    content_free_conversation,
    ranked_choices,
)

#: A name that is a token prefix of another: under the summed rule it never scores lower, but
#: the model would rather go on than stop after it (its end of turn is unlikely).
PREFIX, LONGER = "MAKE", "MAKE_WOOD_PICKAXE"
PREFIX_TOKENS, LONGER_TOKENS = [1], [1, 2, 3]
SCORES = [OptionLoglik(option=-1.0, end=-9.0), OptionLoglik(option=-1.5, end=-0.1)]


def pick(scoring: str, content_free: list[OptionLoglik] | None = None) -> str:
    choices = ChoiceSet(options=(PREFIX, LONGER), rule="loglik", scoring=scoring)  # type: ignore[arg-type]
    [output] = ranked_choices(
        choices,
        [[0] * 7],
        [PREFIX_TOKENS, LONGER_TOKENS],
        [SCORES],
        0.0,
        [content_free] if content_free is not None else None,
    )
    assert output.finish_reason == "choice"
    return output.text


def test_the_summed_rule_lets_a_prefix_win_and_the_others_make_it_pay_for_stopping() -> None:
    neutral = [OptionLoglik(option=-2.0, end=-1.0), OptionLoglik(option=-2.0, end=-1.0)]
    assert pick("sum") == PREFIX
    assert {pick(rule, neutral) for rule in ("mean", "bytes", "pmi")} == {LONGER}


def test_each_rule_is_its_formula() -> None:
    score = OptionLoglik(option=-3.0, end=-0.5)
    prior = OptionLoglik(option=-4.0, end=-2.0)
    assert choice_score("sum", "DO", 1, score) == -3.0
    assert choice_score("mean", "MAKE_WOOD", 3, score) == pytest.approx(-3.5 / 4)
    # Per byte of the option's text, not per token or character.
    assert choice_score("bytes", "MAKE_WOOD", 3, score) == pytest.approx(-3.5 / 9)
    assert choice_score("bytes", "é", 1, score) == pytest.approx(-3.5 / 2)
    assert choice_score("pmi", "DO", 1, score, prior) == pytest.approx(-3.5 + 6.0)


def test_pmi_ranks_by_what_the_prompt_adds_to_the_prior() -> None:
    # The longer name is likelier after the prompt, but the prefix gains more over its prior.
    prior = [OptionLoglik(option=-5.0, end=-5.0), OptionLoglik(option=-1.0, end=-0.1)]
    assert pick("pmi", prior) == PREFIX
    with pytest.raises(ValueError, match="content-free"):
        choice_score("pmi", "DO", 1, SCORES[0])


def test_the_content_free_prompt_keeps_only_the_system_message() -> None:
    system = ChatMessage(role="system", content="You play Crafter. Actions: DO, NOOP.")
    conversation = [
        system,
        ChatMessage(role="user", content="A tree is in front of you."),
        ChatMessage(role="assistant", content="DO"),
        ChatMessage(role="user", content="Now?"),
    ]
    free = content_free_conversation(conversation)
    assert free[0] == system and len(free) == 2
    assert free[1].role == "user" and "tree" not in free[1].content


def test_content_free_scores_are_computed_once_per_prompt_and_options() -> None:
    asked: list[list[list[int]]] = []

    def score(prompts: list[list[int]]) -> list[list[OptionLoglik]]:
        asked.append(prompts)
        return [[OptionLoglik(option=-float(sum(p)), end=math.log(0.5))] for p in prompts]

    kept = ContentFreeScores()
    first = kept.rows([[1, 2], [1, 2], [4]], ["DO"], score)
    assert asked == [[[1, 2], [4]]]
    assert first[0] == first[1] != first[2]
    again = kept.rows([[4], [1, 2]], ["DO"], score)
    assert again == [first[2], first[0]] and len(asked) == 1
    # Other options after the same prompt are scored anew.
    kept.rows([[4]], ["NOOP"], score)
    assert asked[-1] == [[4]] and len(asked) == 2
