"""`env.trusted`: records made unvalidated are the records validation makes."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, Field

from env.trusted import trusted


class _Record(BaseModel):
    model_config = ConfigDict(frozen=True)

    name: str
    count: int = 3
    tags: list[str] = Field(default_factory=list)
    note: str | None = None


def test_a_trusted_record_equals_the_validated_one() -> None:
    given = trusted(_Record, name="a", note="n")
    validated = _Record(name="a", note="n")
    assert given == validated
    assert given.model_dump_json() == validated.model_dump_json()
    assert given.model_fields_set == validated.model_fields_set == {"name", "note"}
    # A default factory gives each record its own value, as validation does.
    assert trusted(_Record, name="b").tags is not trusted(_Record, name="c").tags
    assert given.model_copy(update={"count": 4}) == _Record(name="a", note="n", count=4)


def test_a_missing_or_unknown_field_is_refused() -> None:
    with pytest.raises(TypeError, match="'name'"):
        trusted(_Record, count=1)
    with pytest.raises(TypeError, match="colour"):
        trusted(_Record, name="a", colour="red")
