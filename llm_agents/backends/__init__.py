"""Backend registry: a model spec such as `hf:smollm2-135m` names a backend and a model.

Backends are imported lazily, so the core installs and runs without torch, vLLM or openai.
"""

from __future__ import annotations

import difflib
import importlib
import re
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from env.errors import UserError
from llm_agents.backends.base import ChatMessage, GenerateConfig, ModelAPI, ModelOutput, hub_id_of
from llm_agents.backends.cache import CachedModel
from llm_agents.backends.redaction import REDACTED, redact_secrets, redact_settings

__all__ = [
    "BACKENDS",
    "REDACTED",
    "BackendNotInstalled",
    "CachedModel",
    "ChatMessage",
    "GenerateConfig",
    "ModelAPI",
    "ModelOutput",
    "ModelSpec",
    "get_model",
    "model_revision",
    "parse_model_spec",
    "redact_secrets",
    "redact_settings",
]

#: backend name -> "module:Class"
BACKENDS: dict[str, str] = {
    "mock": "llm_agents.backends.mock:MockModel",
    "hf": "llm_agents.backends.hf:HFModel",
    "vllm": "llm_agents.backends.vllm:VLLMModel",
    "openai": "llm_agents.backends.openai:OpenAIModel",
}

#: backend name -> the extra that installs its dependencies
EXTRAS: dict[str, str] = {"hf": "hf", "vllm": "vllm", "openai": "openai"}


class BackendNotInstalled(UserError):
    """A backend's optional dependencies are missing."""


class ModelSpec(BaseModel):
    """A parsed model spec: `backend:name`, with `@base_url` for HTTP backends."""

    backend: str
    """Registry name of the backend."""
    name: str
    """Model name, path or (for mock) script."""
    base_url: str | None = None
    """Server URL for the openai backend."""


def parse_model_spec(spec: str) -> ModelSpec:
    """Split `backend:name[@base_url]`, checking the backend exists."""
    # Messages quote the spec without its credentials.
    shown = redact_secrets(spec)
    backend, sep, rest = spec.partition(":")
    if not sep:
        raise UserError(
            f"model spec {shown!r} has no backend; write BACKEND:MODEL, e.g. hf:smollm2-135m "
            f"(backends: {', '.join(BACKENDS)})"
        )
    backend = backend.strip().lower()
    if backend not in BACKENDS:
        close = difflib.get_close_matches(backend, BACKENDS, n=2)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        raise UserError(
            f"unknown backend {backend!r} in model spec {shown!r}{hint} (backends: {', '.join(BACKENDS)})"
        )
    base_url = None
    if backend == "openai" and "@" in rest:
        # The first `@http(s)://` starts the URL(s): model names may hold `@`, and so may the
        # credentials of a URL, and a list of URLs holds several `@http`.
        found = re.search(r"@(?=https?://)", rest)
        if found:
            rest, base_url = rest[: found.start()], rest[found.end() :]
        else:
            rest, _, base_url = rest.rpartition("@")
    if not rest and backend != "mock":
        raise UserError(f"model spec {shown!r} names no model after {backend}:")
    # `mock:` is the script that answers NOOP, named as the model it builds names itself.
    rest = rest or "noop"
    return ModelSpec(backend=backend, name=rest, base_url=base_url)


def load_backend_class(backend: str) -> type[ModelAPI]:
    """Import a backend's class, turning a missing optional dependency into an install hint."""
    module_name, _, class_name = BACKENDS[backend].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        extra = EXTRAS.get(backend)
        if extra is None or (err.name or "").startswith("llm_agents"):
            raise
        # A package may raise this itself for a missing piece of its own, naming no module.
        missing = f"the package {err.name!r}" if err.name else f"a package it imports ({err})"
        raise BackendNotInstalled(
            f"the {backend} backend needs {missing}: pip install 'craftext-llm[{extra}]'"
        ) from err
    cls: type[ModelAPI] = getattr(module, class_name)
    return cls


def get_model(spec: str, config: GenerateConfig | None = None, **options: Any) -> ModelAPI:
    """Build the backend a model spec names, after refusing settings it would ignore.

    The check (`ModelAPI.check_settings`) runs before the backend is built, so a typo in an
    option fails before any model is loaded.
    """
    parsed = parse_model_spec(spec)
    cls = load_backend_class(parsed.backend)
    if parsed.base_url is not None:
        options.setdefault("base_url", parsed.base_url)
    cls.check_settings(config, options)
    return cls(parsed.name, config, **options)


def model_revision(spec: str, options: Mapping[str, Any]) -> str | None:
    """The hub commit a model spec's hub id is at now (its `revision` backend option, else
    `main`; offline, as the local hub cache holds it), None for any other model: what a run's
    identity records before the model is loaded. Downloads nothing; a hub that cannot say is a
    `UserError` naming why."""
    from llm_agents.backends.hub import resolve

    parsed = parse_model_spec(spec)
    hub_id = hub_id_of(parsed.backend, parsed.name)
    if hub_id is None:
        return None
    revision = options.get("revision")
    if revision is not None and not isinstance(revision, str):
        raise UserError(f"the revision option is a branch, tag or commit name, not {revision!r}")
    return resolve(hub_id, revision).commit
