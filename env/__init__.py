"""The CrafText environment over Craftax, its success checker and its instruction dataset.

This is the only package that imports JAX, and only when an env name is first used: importing
`env.errors` or `env.achievements` from another package stays cheap.
"""

from typing import TYPE_CHECKING, Any

from env.achievements import ACHIEVEMENT_IDS, ACHIEVEMENTS, NUM_ACHIEVEMENTS
from env.dataset import (
    CATEGORIES,
    SPLITS,
    Dataset,
    DatasetSource,
    Goal,
    Instruction,
    goal_masks,
    load_dataset,
    parse_categories,
)
from env.errors import UserError
from env.termination import Termination
from env.variant import Variant

if TYPE_CHECKING:
    from env.craftext_env import (
        CrafTextEnv,
        EnvConfig,
        EpisodeState,
        HostBatch,
        StepInfo,
        Task,
        VectorEnv,
        episode_key,
        make_task,
        shared_env,
    )

_LAZY = {
    "CrafTextEnv",
    "EnvConfig",
    "EpisodeState",
    "HostBatch",
    "StepInfo",
    "Task",
    "VectorEnv",
    "episode_key",
    "make_task",
    "shared_env",
}

__all__ = [
    "ACHIEVEMENTS",
    "ACHIEVEMENT_IDS",
    "CATEGORIES",
    "NUM_ACHIEVEMENTS",
    "SPLITS",
    "CrafTextEnv",
    "Dataset",
    "DatasetSource",
    "EnvConfig",
    "EpisodeState",
    "Goal",
    "HostBatch",
    "Instruction",
    "StepInfo",
    "Task",
    "Termination",
    "UserError",
    "Variant",
    "VectorEnv",
    "episode_key",
    "goal_masks",
    "load_dataset",
    "make_task",
    "parse_categories",
    "shared_env",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from env import craftext_env

        return getattr(craftext_env, name)
    raise AttributeError(f"module 'env' has no attribute {name!r}")
