"""The transformers backend (see `model`): the model and generation (`model`), `loglik` choice
scoring (`scoring`) and the thinking budget (`thinking`)."""

# Transformers only ever reads local files here (every load passes `local_files_only`): a hub
# id is downloaded first by `backends.hub`, which honours the user's HF_HUB_OFFLINE. Setting
# that variable here would hide the user's choice from huggingface_hub, which reads it once.
try:
    import torch  # noqa: F401
    import transformers
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        f"the hf backend needs {err.name!r}: pip install 'craftext-llm[hf]'", name=err.name
    ) from err

from packaging.version import Version

from llm_agents.backends import BackendNotInstalled

#: The oldest transformers the decoding works with: it reads and builds the per-layer key/value
#: caches (`DynamicCache(config=...)`, `cache.layers`, `DynamicLayer`) of transformers 5.
MIN_TRANSFORMERS = "5.0"

if Version(transformers.__version__) < Version(MIN_TRANSFORMERS):
    raise BackendNotInstalled(
        f"the hf backend needs transformers>={MIN_TRANSFORMERS}, this environment has "
        f"{transformers.__version__}: pip install -U 'craftext-llm[hf]'"
    )

from llm_agents.backends.hf.model import HFModel  # noqa: E402

__all__ = ["HFModel"]
