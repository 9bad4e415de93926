"""How an episode ends: the codes the env's JAX state holds, and the labels records carry.

Imports no JAX, so records and reports can name terminations cheaply.
"""

from enum import IntEnum


class Termination(IntEnum):
    """Why an episode ended; RUNNING while it has not. `success` wins when the goal is met on
    the step the agent dies."""

    RUNNING = 0
    SUCCESS = 1
    DEATH = 2
    TIMEOUT = 3

    @property
    def label(self) -> str:
        return self.name.lower()


TERMINATIONS: tuple[str, ...] = tuple(t.label for t in Termination if t is not Termination.RUNNING)
"""The labels of a finished episode's termination: `success`, `death`, `timeout`."""
