"""Pydantic records made without validation, for values the caller's own code just built.

The play loop makes several records per agent-step (an observation and its parts, a message, a
decision, a step record). pydantic's `model_construct` skips validation but, in pydantic 2.14,
costs more than validating (about 6 µs against 3.5 µs for a dozen fields: it walks every field's
aliases and defaults); `trusted` sets the fields directly (under 2 µs). The values must be what
validation would leave (the field's exact types: `int`, not a numpy integer; tuples where the
field is a tuple): the tests compare such records with validated ones, field types included.
"""

from __future__ import annotations

from functools import cache
from typing import Any, TypeVar

from pydantic import BaseModel
from pydantic.fields import FieldInfo

Model = TypeVar("Model", bound=BaseModel)


@cache
def _fields(cls: type[BaseModel]) -> tuple[tuple[str, FieldInfo | None], ...]:
    """Each field in declaration order, with its `FieldInfo` where it has a default."""
    return tuple(
        (name, None if field.is_required() else field) for name, field in cls.model_fields.items()
    )


def trusted(cls: type[Model], /, **values: Any) -> Model:
    """An instance of `cls` holding `values` as they are, unvalidated; a field left out takes
    its default, as validation would give it (and, as there, is not in `model_fields_set`)."""
    if tuple(values) == _names(cls):
        return _made(cls, values, set(values))
    data: dict[str, Any] = {}
    # In declaration order, as validation stores them: serialisation follows this order.
    for name, field in _fields(cls):
        if name in values:
            data[name] = values[name]
        elif field is None:
            raise TypeError(f"{cls.__name__}: no value for the required field {name!r}")
        else:
            data[name] = field.get_default(call_default_factory=True, validated_data=data)
    if not values.keys() <= data.keys():
        raise TypeError(f"{cls.__name__} has no field {sorted(values.keys() - data.keys())}")
    return _made(cls, data, set(values))


@cache
def _names(cls: type[BaseModel]) -> tuple[str, ...]:
    return tuple(name for name, _ in _fields(cls))


# `BaseModel`'s slots, set through their descriptors, and `object.__new__` (no model defines
# `__new__`) called directly: each of the several records an agent-step makes skips the
# attribute lookups `object.__setattr__(instance, name, ...)` and `cls.__new__` pay (a quarter
# of `_made`).
_new = object.__new__
_set_dict = object.__setattr__
_FIELDS_SET = vars(BaseModel)["__pydantic_fields_set__"]
_EXTRA = vars(BaseModel)["__pydantic_extra__"]
_PRIVATE = vars(BaseModel)["__pydantic_private__"]


def _made(cls: type[Model], data: dict[str, Any], fields_set: set[str]) -> Model:
    instance: Model = _new(cls)
    _set_dict(instance, "__dict__", data)
    _FIELDS_SET.__set__(instance, fields_set)
    _EXTRA.__set__(instance, None)
    _PRIVATE.__set__(instance, None)
    return instance
