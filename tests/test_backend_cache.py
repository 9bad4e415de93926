"""The sqlite response cache: hits skip the model, and only deterministic requests are kept."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from env.errors import UserError
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig
from llm_agents.backends.cache import CachedModel
from llm_agents.backends.mock import MockModel

LOGLIK = ChoiceSet(options=("NOOP", "DO"), rule="loglik")


def ask(text: str) -> list[ChatMessage]:
    return [ChatMessage(role="user", content=text)]


def counting_model(config: GenerateConfig | None = None) -> MockModel:
    # Answers carry the call number, so a replayed answer is distinguishable from a fresh one.
    calls = iter(range(1000))
    return MockModel(
        "", config, outputs=lambda conversation: f"{conversation[-1].content}#{next(calls)}"
    )


def test_a_repeated_request_is_served_without_calling_the_model(tmp_path: Path) -> None:
    inner = counting_model()
    cached = CachedModel(inner, tmp_path / "cache.sqlite")
    first = cached.generate([ask("a"), ask("b")])
    again = cached.generate([ask("b"), ask("c"), ask("a")])
    assert [o.text for o in first] == ["a#0", "b#1"]
    assert [o.text for o in again] == ["b#1", "c#2", "a#0"]
    assert [o.cached for o in again] == [True, False, True]
    assert not any(o.cached for o in first)
    # Only the one new conversation reached the model on the second call.
    assert [request[0][-1].content for request in inner.requests] == ["a", "b", "c"]
    hit = again[0]
    # The same answer; what it cost differs: a cache hit computes no prompt token.
    cost = {"cached", "latency_s", "computed_prompt_tokens"}
    assert hit.model_dump(exclude=cost) == first[1].model_dump(exclude=cost)
    assert hit.computed_prompt_tokens == 0


def test_the_cache_survives_a_new_process_view(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    CachedModel(counting_model(), path).generate([ask("a")])
    fresh_inner = counting_model()
    # A second connection (as another process would open) sees the stored answer.
    [output] = CachedModel(fresh_inner, path).generate([ask("a")])
    assert output.cached and output.text == "a#0"
    assert fresh_inner.requests == []
    assert sqlite3.connect(path).execute("PRAGMA journal_mode").fetchone()[0] == "wal"


@pytest.mark.parametrize(
    ("first", "second"),
    [
        ((GenerateConfig(), None), (GenerateConfig(max_tokens=7), None)),
        ((GenerateConfig(), None), (GenerateConfig(), LOGLIK)),
        (
            (GenerateConfig(), LOGLIK),
            (GenerateConfig(), ChoiceSet(options=("DO", "NOOP"), rule="loglik")),
        ),
        # The same options picked by another rule can give another answer.
        (
            (GenerateConfig(), LOGLIK),
            (GenerateConfig(), ChoiceSet(options=("NOOP", "DO"), rule="guided")),
        ),
    ],
)
def test_different_parameters_or_choices_are_different_requests(
    tmp_path: Path,
    first: tuple[GenerateConfig, ChoiceSet | None],
    second: tuple[GenerateConfig, ChoiceSet | None],
) -> None:
    path = tmp_path / "cache.sqlite"
    config_a, choices_a = first
    config_b, choices_b = second
    CachedModel(counting_model(config_a), path).generate([ask("NOOP")], choices_a)
    inner = counting_model(config_b)
    [output] = CachedModel(inner, path).generate([ask("NOOP")], choices_b)
    assert not output.cached
    assert len(inner.requests) == 1


def test_transport_settings_do_not_split_the_cache(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    CachedModel(counting_model(GenerateConfig(timeout_s=5)), path).generate([ask("a")])
    [output] = CachedModel(counting_model(GenerateConfig(timeout_s=99)), path).generate([ask("a")])
    assert output.cached


def test_sampled_requests_are_not_cached_unless_asked(tmp_path: Path) -> None:
    sampled = GenerateConfig(temperature=0.7)
    cached = CachedModel(counting_model(sampled), tmp_path / "c.sqlite")
    texts = [cached.generate([ask("a")])[0].text for _ in range(2)]
    assert texts == ["a#0", "a#1"]
    opted_in = CachedModel(counting_model(sampled), tmp_path / "d.sqlite", cache_sampled=True)
    outputs = [opted_in.generate([ask("a")])[0] for _ in range(2)]
    assert [o.text for o in outputs] == ["a#0", "a#0"]
    assert outputs[1].cached


def test_errors_are_not_cached(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    [failed] = CachedModel(MockModel("noop", outputs=[], cycle=False), path).generate([ask("a")])
    assert failed.finish_reason == "error"
    inner = MockModel("noop", outputs=["DO"])
    [output] = CachedModel(inner, path).generate([ask("a")])
    assert output.text == "DO" and not output.cached


def test_an_unusable_cache_path_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="response cache"):
        CachedModel(MockModel(), tmp_path)
