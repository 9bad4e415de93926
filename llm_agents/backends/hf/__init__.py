"""The transformers backend (see `model`): the model and generation (`model`), `loglik` choice
scoring (`scoring`) and the thinking budget (`thinking`)."""

from llm_agents.backends.hf.model import HFModel

__all__ = ["HFModel"]
