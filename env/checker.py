"""The CrafText "conditional achievements" checker, and the success rule every checker's verdict
goes through, in JAX.

An achievements goal lists required and forbidden achievements over the 22 ids shared by both
Craftax variants. It is reached when every required achievement is unlocked and no forbidden one
is; the order in which they were unlocked does not matter. Whether reaching a goal of any kind
(`env.scenario_checker`) on the step the game ends is a success depends on the success rule
(`env.rules.SuccessRule`).
"""

import jax
import jax.numpy as jnp

from env.rules import SuccessRule


def goal_reached(unlocked: jax.Array, required: jax.Array, forbidden: jax.Array) -> jax.Array:
    """True where all `required` are in `unlocked` and none of `forbidden` is (boolean [..., 22])."""
    all_required = jnp.all(unlocked | ~required, axis=-1)
    any_forbidden = jnp.any(unlocked & forbidden, axis=-1)
    return all_required & ~any_forbidden


def scored_success(
    reached: jax.Array, in_new_world: jax.Array, game_ended: jax.Array, rule: SuccessRule
) -> jax.Array:
    """Whether a step succeeds under `rule`.

    `reached` is the goal's checker verdict after the step; `game_ended` is True where the step
    ended the game (the player died, or Craftax's own time limit); `in_new_world` is the verdict
    on the world Craftax's automatic reset starts there. The official wrapper checks the goal on
    the state its auto-reset env returns, which on the game-over step is that new world, so
    under `official` such a step succeeds exactly when the goal is met there; under
    `game_over_counts` it succeeds when the goal was met as the game ended.
    """
    if rule == "official":
        return jnp.where(game_ended, in_new_world, reached)
    return reached
