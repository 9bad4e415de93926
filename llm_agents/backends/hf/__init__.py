"""The transformers backend (see `model`): the model and generation (`model`), `loglik` choice
scoring (`scoring`) and the thinking budget (`thinking`)."""

# Transformers only ever reads local files here (every load passes `local_files_only`): a hub
# id is downloaded first by `backends.hub`, which honours the user's HF_HUB_OFFLINE. Setting
# that variable here would hide the user's choice from huggingface_hub, which reads it once.
try:
    import torch  # noqa: F401
    import transformers  # noqa: F401
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        f"the hf backend needs {err.name!r}: pip install 'craftext-llm[hf]'", name=err.name
    ) from err

from llm_agents.backends.hf.model import HFModel

__all__ = ["HFModel"]
