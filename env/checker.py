"""The CrafText "conditional achievements" success checker, in JAX.

A goal lists required and forbidden achievements over the 22 ids shared by both Craftax variants.
It is reached when every required achievement is unlocked and no forbidden one is; the order in
which they were unlocked does not matter.
"""

import jax
import jax.numpy as jnp


def goal_reached(unlocked: jax.Array, required: jax.Array, forbidden: jax.Array) -> jax.Array:
    """True where all `required` are in `unlocked` and none of `forbidden` is (boolean [..., 22])."""
    all_required = jnp.all(unlocked | ~required, axis=-1)
    any_forbidden = jnp.any(unlocked & forbidden, axis=-1)
    return all_required & ~any_forbidden
