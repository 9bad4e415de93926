"""The plans file: one JSON object mapping instruction text to plan text (the shape of
CrafText's official plan file), read by the runner and written by the planner."""

from __future__ import annotations

import json
import os
from pathlib import Path

from env.errors import UserError


def load_plans(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a plans file (instruction text -> plan text), such as CrafText's official one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"plans file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f"cannot read plans file {path}: {err}") from err
    except json.JSONDecodeError as err:
        raise UserError(f"plans file {path} is not valid JSON: {err}") from err
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
