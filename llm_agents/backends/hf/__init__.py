"""The transformers backend (see `model`): the model and generation (`model`), `loglik` choice
scoring (`scoring`) and the thinking budget (`thinking`)."""

import os

# Set before transformers is imported (by any module of this package): the hub is unreachable
# here and must not be waited on.
os.environ.setdefault("HF_HUB_OFFLINE", "1")

try:
    import torch  # noqa: F401
    import transformers  # noqa: F401
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        f"the hf backend needs {err.name!r}: pip install 'craftext-llm[hf]'", name=err.name
    ) from err

from llm_agents.backends.hf.model import HFModel

__all__ = ["HFModel"]
