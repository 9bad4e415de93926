"""Hub ids: a model spec's `ORG/NAME` (or `ORG/NAME:FILE.gguf`) resolved to one commit of the
repository and a local copy of it in the standard hub cache, downloaded on first use.

Everything goes through `huggingface_hub`, so its environment holds as it does for every tool of
the ecosystem: `HF_HOME` / `HF_HUB_CACHE` (where the cache is), `HF_ENDPOINT` (which hub),
`HF_TOKEN` (gated and private repositories) and `HF_HUB_OFFLINE=1` (the local cache only: the
hub is never contacted). A spec resolves to a commit first (`resolve`: the hub's model info, or
the cache's ref offline), so the commit a run plays is known before anything is written and
goes into its identity; `fetch` then downloads that commit's files that are not cached yet,
after checking the disk holds them, under one progress bar.

Every failure (an unreachable hub, an unknown repository or revision, a gated repository
without a token, a model not cached offline, too little disk) is a one-line `UserError` naming
the cause and what to do; the token never appears in one.
"""

from __future__ import annotations

import errno
import fnmatch
import importlib
import os
import re
import shutil
import sys
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from env.errors import UserError

#: A GGUF file of a repository: `ORG/NAME:FILE.gguf` (the file may lie in a folder of it).
GGUF_SUFFIX = ".gguf"
#: Seconds the hub may take to answer one metadata request before it counts as unreachable:
#: a failure must be told within seconds, not after the client's own patience.
HUB_TIMEOUT_S = 10.0
#: A hub id: `NAME` or `ORG/NAME`, the characters the hub allows in each part.
_REPO_ID = re.compile(r"[\w.-]+(/[\w.-]+)?")
#: The files of a model folder transformers and vLLM read: configs, tokenizers, chat templates
#: and weights. Only top-level files: repositories keep other formats (`onnx/`, `original/`)
#: in folders.
_FOLDER_FILES = ("*.json", "*.model", "*.txt", "*.tiktoken", "*.jinja")
_SAFETENSORS = "*.safetensors"
_PYTORCH_WEIGHTS = "*.bin"
#: Kept free beside a download, so the cache's disk is never filled to the last byte.
_FREE_SPACE_MARGIN = 100_000_000


class HubRevision(BaseModel):
    """The hub options of the backends that load hub ids (hf, vllm)."""

    model_config = ConfigDict(extra="forbid")

    revision: str | None = None
    """Branch, tag or commit of a hub-id model (`ORG/NAME`); None: its `main` branch. The commit
    it resolves to is recorded in the run's identity."""


class HubId(BaseModel):
    """A hub id as a model spec names it."""

    model_config = ConfigDict(frozen=True)

    repo_id: str
    filename: str | None = None
    """The GGUF file of `ORG/NAME:FILE.gguf`; None: the repository is a model folder."""

    @property
    def spec(self) -> str:
        return f"{self.repo_id}:{self.filename}" if self.filename else self.repo_id


class HubModel(BaseModel):
    """A hub id resolved to one commit; `path` is set once its files are in the cache."""

    model_config = ConfigDict(frozen=True)

    hub_id: HubId
    revision: str
    """The revision asked for (a branch, tag or commit)."""
    commit: str
    """The commit `revision` resolved to: what the run plays, recorded in its identity."""
    files: dict[str, int | None] = {}
    """File -> size in bytes (None: not told) of the files the model needs, where the hub
    listed them (online)."""
    path: Path | None = None
    """The snapshot folder of the commit in the hub cache, or the GGUF file in it."""


def parse_hub_id(name: str) -> HubId | None:
    """The hub id a model name spells, or None when it spells none (a path, or text no hub id
    can be)."""
    if name.startswith((".", "/", "~")):
        return None
    repo_id, colon, filename = name.partition(":")
    if not _REPO_ID.fullmatch(repo_id):
        return None
    if colon and not (filename.endswith(GGUF_SUFFIX) and filename.strip("/")):
        raise UserError(
            f"model {name!r}: after the hub id, `:` names a GGUF file of the repository "
            f"(ORG/NAME:FILE{GGUF_SUFFIX})"
        )
    return HubId(repo_id=repo_id, filename=filename.strip("/") or None)


def _hub() -> Any:
    try:
        return importlib.import_module("huggingface_hub")
    except ModuleNotFoundError:
        raise UserError(
            "hub ids are downloaded through huggingface_hub: pip install 'craftext-llm[hf]'"
        ) from None


def _constants() -> Any:
    return importlib.import_module("huggingface_hub.constants")


def cache_dir() -> Path:
    """The hub cache (`HF_HUB_CACHE`, else `HF_HOME/hub`, else `~/.cache/huggingface/hub`)."""
    return Path(_constants().HF_HUB_CACHE)


def offline() -> bool:
    """Whether `HF_HUB_OFFLINE` (or `TRANSFORMERS_OFFLINE`) forbids contacting the hub."""
    return bool(_constants().HF_HUB_OFFLINE)


def _endpoint() -> str:
    return str(_constants().ENDPOINT)


def resolve(hub_id: HubId, revision: str | None = None) -> HubModel:
    """The commit `revision` (None: `main`) of the hub id is at now: asked of the hub, or
    offline read from the cache's ref. Downloads nothing."""
    asked = revision or "main"
    hub = _hub()
    _check_repo_id(hub_id)
    if offline():
        return _cached(hub_id, asked)
    try:
        info = hub.HfApi().model_info(
            hub_id.repo_id, revision=asked, files_metadata=True, timeout=HUB_TIMEOUT_S
        )
    except Exception as err:
        raise _hub_error(err, hub_id, asked) from None
    siblings = {sibling.rfilename: sibling.size for sibling in info.siblings or ()}
    files = _needed_files(hub_id, siblings, info.sha)
    if info.gated and not hub.get_token():
        raise UserError(
            f"{hub_id.repo_id} is a gated repository: accept its terms at "
            f"{_endpoint()}/{hub_id.repo_id} and set HF_TOKEN to a token of that account"
        )
    return HubModel(hub_id=hub_id, revision=asked, commit=info.sha, files=files)


def _check_repo_id(hub_id: HubId) -> None:
    """Refuse an id the hub's own rules reject (`org/name.`, `org/a--b`), before any request:
    its client would raise the same from deep inside a download."""
    from huggingface_hub.errors import HFValidationError
    from huggingface_hub.utils import validate_repo_id

    try:
        validate_repo_id(hub_id.repo_id)
    except HFValidationError as err:
        raise UserError(f"{hub_id.repo_id!r} is not a valid hub id (ORG/NAME): {err}") from None


def fetch(hub_id: HubId, revision: str | None = None) -> HubModel:
    """`resolve`, then the commit's files in the hub cache, downloading those it lacks."""
    model = resolve(hub_id, revision)
    if model.path is not None:
        return model
    hub = _hub()
    missing = {
        name: size
        for name, size in model.files.items()
        if not isinstance(
            hub.try_to_load_from_cache(hub_id.repo_id, name, revision=model.commit), str
        )
    }
    _check_free_space(hub_id, missing)
    if missing:
        _download(hub_id, model.commit, missing)
    _remember_revision(hub_id, model.revision, model.commit)
    first = hub_id.filename or next(iter(model.files))
    located = hub.try_to_load_from_cache(hub_id.repo_id, first, revision=model.commit)
    file = Path(str(located))
    path = file if hub_id.filename else _snapshot_of(file, first)
    return model.model_copy(update={"path": path})


def _remember_revision(hub_id: HubId, revision: str, commit: str) -> None:
    """Record in the cache's refs that `revision` (a branch or tag) is at `commit`, as the
    client's own snapshot download does, so an offline run finds it. Files are downloaded by
    their commit, which records no ref."""
    if revision == commit:
        return
    from huggingface_hub.file_download import repo_folder_name

    folder = repo_folder_name(repo_id=hub_id.repo_id, repo_type="model")
    ref = cache_dir() / folder / "refs" / revision
    if ref.is_file() and ref.read_text() == commit:
        return
    ref.parent.mkdir(parents=True, exist_ok=True)
    partial = ref.with_name(f".{ref.name}.{os.getpid()}.tmp")
    partial.write_text(commit)
    partial.replace(ref)


def _needed_files(hub_id: HubId, siblings: dict[str, int | None], commit: str) -> dict[str, Any]:
    """The files of the repository the model needs: its GGUF file, or a model folder's
    configs, tokenizer and weights (safetensors where it has them, else PyTorch's)."""
    if hub_id.filename is not None:
        if hub_id.filename not in siblings:
            ggufs = sorted(name for name in siblings if name.endswith(GGUF_SUFFIX))
            listed = ", ".join(ggufs[:8]) + (", ..." if len(ggufs) > 8 else "") or "none"
            raise UserError(
                f"{hub_id.repo_id} (commit {commit[:12]}) has no file {hub_id.filename} "
                f"(its GGUF files: {listed})"
            )
        return {hub_id.filename: siblings[hub_id.filename]}
    top = {name: size for name, size in siblings.items() if "/" not in name}
    weights = _SAFETENSORS if any(fnmatch.fnmatch(n, _SAFETENSORS) for n in top) else None
    weights = weights or _PYTORCH_WEIGHTS
    wanted = {
        name: size
        for name, size in top.items()
        if any(fnmatch.fnmatch(name, pattern) for pattern in (*_FOLDER_FILES, weights))
    }
    if "config.json" not in wanted:
        ggufs = [name for name in siblings if name.endswith(GGUF_SUFFIX)]
        hint = f"; it holds GGUF files: name one, {hub_id.repo_id}:{ggufs[0]}" if ggufs else ""
        raise UserError(
            f"{hub_id.repo_id} (commit {commit[:12]}) holds no transformers model (no "
            f"config.json){hint}"
        )
    return wanted


def _cached(hub_id: HubId, revision: str) -> HubModel:
    """The hub id as the local hub cache holds it at `revision` (offline)."""
    hub = _hub()
    first = hub_id.filename or "config.json"
    located = hub.try_to_load_from_cache(hub_id.repo_id, first, revision=revision)
    if not isinstance(located, str):
        raise UserError(
            f"{hub_id.spec} (revision {revision}) is not in the local hub cache "
            f"({cache_dir()}) and HF_HUB_OFFLINE=1 forbids downloading it: unset "
            "HF_HUB_OFFLINE to download it, or pass a local model folder (hf:/path/to/model)"
        )
    file = Path(located)
    snapshot = _snapshot_of(file, first)
    return HubModel(
        hub_id=hub_id,
        revision=revision,
        commit=snapshot.name,
        path=file if hub_id.filename else snapshot,
    )


def _snapshot_of(file: Path, name: str) -> Path:
    """The snapshot folder holding `file`, the repository's file `name`."""
    return Path(file.as_posix().removesuffix("/" + name))


def _check_free_space(hub_id: HubId, missing: dict[str, int | None]) -> None:
    """Refuse a download the cache's disk cannot hold, by the sizes the hub gave."""
    needed = sum(size or 0 for size in missing.values())
    if not needed:
        return
    folder = cache_dir()
    existing = folder
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    free = shutil.disk_usage(existing).free
    if free < needed + _FREE_SPACE_MARGIN:
        raise UserError(
            f"downloading {hub_id.spec} needs {_size(needed)} free in {folder}, "
            f"{_size(free)} are: free some, or set HF_HOME to a folder on a larger disk"
        )


def _size(count: int) -> str:
    return f"{count / 1e9:.1f} GB" if count >= 1e8 else f"{count / 1e6:.1f} MB"


def _download(hub_id: HubId, commit: str, files: dict[str, int | None]) -> None:
    """Download `files` of `commit` into the hub cache under one progress bar on stderr."""
    from tqdm import tqdm

    hub = _hub()
    # The files' access is asked first (one HEAD), so a gated repository's refusal is told
    # alone, not under a progress bar left at 0%.
    try:
        hub.get_hf_file_metadata(
            hub.hf_hub_url(hub_id.repo_id, next(iter(files)), revision=commit),
            timeout=HUB_TIMEOUT_S,
        )
    except Exception as err:
        raise _hub_error(err, hub_id, commit) from None
    with tqdm(
        total=sum(size or 0 for size in files.values()),
        desc=f"downloading {hub_id.spec} ({commit[:12]})",
        unit="B",
        unit_scale=True,
        file=sys.stderr,
        # Shown even when stderr is no terminal: a download of gigabytes must show progress
        # in a log too.
        mininterval=0.5,
    ) as bar:

        class _IntoBar:
            """What huggingface_hub takes as a file's progress bar: counts into `bar`."""

            def __init__(self, *args: Any, **kwargs: Any) -> None:
                pass

            def __enter__(self) -> _IntoBar:
                return self

            def __exit__(self, *exc: object) -> None:
                pass

            def update(self, count: float | None = 1) -> None:
                bar.update(count or 0)

            def close(self) -> None:
                pass

        for number, name in enumerate(files, start=1):
            bar.set_postfix_str(f"file {number}/{len(files)}", refresh=False)
            try:
                hub.hf_hub_download(
                    hub_id.repo_id,
                    name,
                    revision=commit,
                    etag_timeout=HUB_TIMEOUT_S,
                    tqdm_class=_IntoBar,
                )
            except OSError as err:
                if err.errno == errno.ENOSPC:
                    raise UserError(
                        f"the disk filled while downloading {hub_id.spec} into {cache_dir()}: "
                        "free some, or set HF_HOME to a folder on a larger disk"
                    ) from None
                raise _hub_error(err, hub_id, commit) from None
            except Exception as err:
                raise _hub_error(err, hub_id, commit) from None


def _transport_errors() -> tuple[type[BaseException], ...]:
    """The exceptions of the HTTP client huggingface_hub uses when no answer came at all."""
    found: list[type[BaseException]] = [ConnectionError, TimeoutError]
    for module, name in (("httpx2", "TransportError"), ("httpx", "TransportError")):
        try:
            found.append(getattr(importlib.import_module(module), name))
        except (ModuleNotFoundError, AttributeError):
            continue
    return tuple(found)


def _hub_error(err: BaseException, hub_id: HubId, revision: str) -> BaseException:
    """One line naming why the hub refused `hub_id` and what to do; an error that is not the
    hub's (a bug) is returned as it is."""
    from huggingface_hub import errors

    endpoint = _endpoint()
    if isinstance(err, errors.LocalEntryNotFoundError) and err.__cause__ is not None:
        # What a download says when the hub could not be asked and the cache lacks the file.
        return _hub_error(err.__cause__, hub_id, revision)
    if isinstance(err, errors.GatedRepoError):
        token = "the token in HF_TOKEN has no access" if _hub().get_token() else "no HF_TOKEN"
        return UserError(
            f"{hub_id.repo_id} is a gated repository and {token}: accept its terms at "
            f"{endpoint}/{hub_id.repo_id} and set HF_TOKEN to a token of that account"
        )
    if isinstance(err, errors.RevisionNotFoundError):
        return UserError(
            f"{hub_id.repo_id} has no revision {revision!r} on {endpoint}: give a branch, tag "
            "or commit it has (--backend-option revision=...)"
        )
    if isinstance(err, errors.RepositoryNotFoundError):
        return UserError(
            f"no model repository {hub_id.repo_id!r} on {endpoint}: check the id (ORG/NAME); "
            "a private one needs HF_TOKEN set to a token that can read it"
        )
    if isinstance(err, errors.HfHubHTTPError):
        status = err.response.status_code if err.response is not None else "an error"
        if status == 401:
            return UserError(
                f"the hub at {endpoint} refused the token in HF_TOKEN (401): set a valid one, "
                "or unset it for public models"
            )
        return UserError(
            f"the hub at {endpoint} answered {status} for {hub_id.spec}: retry later, or set "
            "HF_HUB_OFFLINE=1 to use the local hub cache"
        )
    if isinstance(err, errors.OfflineModeIsEnabled):
        return UserError(f"{hub_id.spec} is not in the local hub cache and HF_HUB_OFFLINE is set")
    if isinstance(err, _transport_errors()):
        return UserError(
            f"cannot reach the hub at {endpoint} ({type(err).__name__}): check the network "
            "and HF_ENDPOINT, or set HF_HUB_OFFLINE=1 to use the models already in the local "
            "hub cache"
        )
    return err
