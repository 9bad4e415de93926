"""Which device JAX runs the env on.

An LLM evaluation gives the accelerator to the model. JAX on a GPU would claim most of its memory
the moment it starts (XLA preallocates 75% by default) and compile every small eager operation
for it, while a batch of at most a few hundred Craftax worlds steps in milliseconds on the CPU.
So the env runs on the CPU unless asked otherwise.
"""

from typing import Literal

EnvDevice = Literal["cpu", "default"]
"""`cpu`: JAX never touches an accelerator; `default`: JAX's default device (a GPU when JAX was
installed with CUDA), for env-only work such as training where the env is the whole load."""


def place_env(device: EnvDevice) -> None:
    """Point JAX at `device` for the rest of the process (the env is the only JAX user)."""
    if device != "cpu":
        return
    # Here, not at the top: configs name `EnvDevice` without loading JAX.
    import jax
    from jax._src import xla_bridge

    if not xla_bridge.backends_are_initialized():
        # Only the CPU client is ever created: no memory claimed on the accelerator.
        jax.config.update("jax_platforms", "cpu")
    # When another part of the process already started JAX on an accelerator, the env's arrays
    # and computations still go to the CPU.
    jax.config.update("jax_default_device", jax.devices("cpu")[0])
