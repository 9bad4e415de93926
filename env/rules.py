"""Evaluation rules that are settings: how success is scored and how worlds are seeded. Imports
no JAX, so configs can name them cheaply."""

from typing import Literal, get_args

SuccessRule = Literal["game_over_counts", "official"]
"""Whether a goal completed on the step the game ends (the player dies, or Craftax's own time
limit) is a success: `game_over_counts` says yes; `official` says no, as the official CrafText
wrapper scores it (it checks the goal on the state after the automatic reset)."""
SUCCESS_RULES: tuple[SuccessRule, ...] = get_args(SuccessRule)
#: The rule the env, the settings and the `default` protocol start from.
DEFAULT_SUCCESS_RULE: SuccessRule = "game_over_counts"

#: Step cap per episode of the official LLM baseline loop (the paper states none); the env, the
#: settings and both protocols start from it.
STEP_CAP = 250

WorldSeeding = Literal["per_episode", "official"]
"""`per_episode`: each episode's world comes from its own episode key; `official`: every episode
starts in the one world Craftax generates from `PRNGKey(OFFICIAL_WORLD_KEY)`, as the official
LLM baseline loop does."""
WORLD_SEEDINGS: tuple[WorldSeeding, ...] = get_args(WorldSeeding)

#: The reset key of the official LLM baseline loop: `jax.random.PRNGKey(1)`.
OFFICIAL_WORLD_KEY = 1
