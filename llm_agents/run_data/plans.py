"""Plans files: one JSON object mapping instruction text to plan text (the shape of CrafText's
official plan file), read by the runner and written by the planner, or to a list of candidate
plans (`plan --candidates`), read with plans files by `plan-score`."""

from __future__ import annotations

import json
import os
from pathlib import Path

from env.errors import UserError

_SHAPES = "{text: plan} (a plans file) or {text: [plan, ...]} (a candidates file)"


def _read_object(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"plans file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f"cannot read plans file {path}: {err}") from err
    except json.JSONDecodeError as err:
        raise UserError(f"plans file {path} is not valid JSON: {err}") from err


def load_plans(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a plans file (instruction text -> plan text), such as CrafText's official one."""
    path = Path(path)
    data = _read_object(path)
    if not isinstance(data, dict):
        raise UserError(
            f"plans file {path} must hold one JSON object mapping instruction text to plan text, "
            f"not a {type(data).__name__}"
        )
    bad = [key for key, value in data.items() if not isinstance(value, str)]
    if bad:
        raise UserError(
            f"plans file {path}: the plan of {bad[0]!r} is not a string "
            f"({len(bad)} such entr{'y' if len(bad) == 1 else 'ies'})"
        )
    if not data:
        raise UserError(f"plans file {path} holds no plans")
    return data


def load_candidates(path: str | os.PathLike[str]) -> dict[str, list[str]]:
    """Read a plans file or a candidates file as text -> candidate plans (a plans file's text
    has one candidate)."""
    path = Path(path)
    data = _read_object(path)
    if not isinstance(data, dict) or not data:
        raise UserError(f"plans file {path} must be one non-empty JSON object, {_SHAPES}")
    if all(isinstance(value, str) for value in data.values()):
        return {text: [plan] for text, plan in data.items()}
    if all(
        isinstance(value, list) and value and all(isinstance(p, str) for p in value)
        for value in data.values()
    ):
        return {text: list(plans) for text, plans in data.items()}
    raise UserError(f"plans file {path} is neither shape: it must be {_SHAPES}")
