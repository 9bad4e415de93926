"""Evaluation rules that are settings: how success is scored and how worlds are seeded. Imports
no JAX, so configs can name them cheaply."""

from typing import Literal, get_args

SuccessRule = Literal["game_over_counts", "official"]
"""How the step the game ends on (the player dies, or Craftax's own time limit) is scored:
`game_over_counts` checks the goal on the state the game ended in; `official` checks it, as the
official CrafText wrapper does, on the step from the state before to the world Craftax's
automatic reset starts (`GameData.from_state(previous, new world)`). There nothing is unlocked,
so an achievements goal never succeeds; a placing or building goal sometimes does (the new
world's inventory is empty, its blocks lie around the new spawn)."""
SUCCESS_RULES: tuple[SuccessRule, ...] = get_args(SuccessRule)
#: The rule the env, the settings and the `default` protocol start from.
DEFAULT_SUCCESS_RULE: SuccessRule = "game_over_counts"

StepKeys = Literal["auto_reset", "whole"]
"""How a step's key is spent. `auto_reset`, as Craftax's `EnvironmentAutoReset.step` (the
official wrapper's inner env) spends it: split in two, the game steps with the first half and
the world a game-over step starts is made from the second. `whole`: the game steps with the
whole key, the new world still from its second half, a key the game step itself draws from, so
that world is not the one the official wrapper checks (runs recorded before this setting played
so)."""
STEP_KEYS: tuple[StepKeys, ...] = get_args(StepKeys)
DEFAULT_STEP_KEYS: StepKeys = "auto_reset"

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
