"""Hub ids (`hf:ORG/NAME`, `hf:ORG/NAME:FILE.gguf`, `vllm:ORG/NAME`) downloaded on first use:
the real `huggingface_hub` client against a hub served on loopback (`hub_server.py`), serving
a tiny model built here (`tiny_llm.py`).

The client reads its environment (`HF_HOME`, `HF_ENDPOINT`, `HF_HUB_OFFLINE`) once, when it is
imported: the first test runs the CLI in a fresh process, as a user does; the others set the
variables in this process and have the client read them again (`hub_environment`).
"""

from __future__ import annotations

import importlib
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hub_server import GRANTED_TOKEN, UNGRANTED_TOKEN, HubServer
from tiny_llm import build_tiny_gguf, build_tiny_llm, folder_files
from tqdm import tqdm

from env.errors import UserError
from llm_agents.backends import get_model, model_revision
from llm_agents.backends.base import ChatMessage, GenerateConfig, locate_model
from llm_agents.cli import main

REPO = Path(__file__).resolve().parents[1]
TINY = "tiny-org/tiny-llm"
GGUF_REPO = "tiny-org/tiny-llm-GGUF"
GGUF_FILE = "tiny-llm-f32.gguf"
GATED = "tiny-org/gated-llm"
HUGE = "tiny-org/huge-llm"
MOVING = "tiny-org/moving-llm"
#: What a bad input may take, from the command to its one line (the issue's bound).
FAILS_WITHIN_S = 30.0
HUB_VARIABLES = (
    "HF_HOME",
    "HF_HUB_CACHE",
    "HF_ENDPOINT",
    "HF_TOKEN",
    "HF_HUB_OFFLINE",
    "TRANSFORMERS_OFFLINE",
)


def eval_args(model: str, out: Path, *extra: str) -> list[str]:
    return [
        "eval", "--model", model, "--variant", "classic", "--categories", "combo",
        "--max-steps", "2", "--limit", "1", "--batch-size", "1", "--max-tokens", "4",
        "--backend-option", "threads=1", "--output-dir", str(out), "--no-progress", *extra,
    ]  # fmt: skip


@dataclass
class Hub:
    server: HubServer
    commits: dict[str, str]
    folder: Path
    moved_folder: Path = field(default_factory=Path)

    @property
    def url(self) -> str:
        return self.server.url


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The tiny model as a folder, a second folder of other weights, and a GGUF file."""
    from llm_agents.backends.embedded import embedded_model_dir

    root = tmp_path_factory.mktemp("tiny-llm")
    tokenizer = embedded_model_dir()
    return (
        build_tiny_llm(root / "tiny-llm", tokenizer, seed=0),
        build_tiny_llm(root / "tiny-llm-moved", tokenizer, seed=1),
        build_tiny_gguf(root / GGUF_FILE, tokenizer),
    )


@pytest.fixture(scope="module")
def hub(tiny_model: tuple[Path, Path, Path]) -> Iterator[Hub]:
    folder, moved, gguf = tiny_model
    server = HubServer()
    files = folder_files(folder)
    commits = {
        TINY: server.commit(TINY, files),
        GGUF_REPO: server.commit(
            GGUF_REPO, {GGUF_FILE: gguf.read_bytes(), "README.md": b"# tiny GGUF\n"}
        ),
        GATED: server.commit(GATED, files, gated=True),
        HUGE: server.commit(HUGE, files),
        MOVING: server.commit(MOVING, files),
    }
    server.repos[HUGE].claimed_sizes["model.safetensors"] = 10**15
    with server.running():
        yield Hub(server, commits, folder, moved)


@pytest.fixture
def hub_environment() -> Iterator[Callable[..., Path]]:
    """Set the hub's environment variables in this process (every one of `HUB_VARIABLES` not
    given is unset) and have huggingface_hub read them again, as a fresh process would; the
    hub cache is the returned folder's unless `HF_HOME` is given. Restored afterwards."""
    import huggingface_hub.constants

    saved = {name: os.environ.get(name) for name in HUB_VARIABLES}

    def use(**variables: str) -> Path:
        for name in HUB_VARIABLES:
            os.environ.pop(name, None)
        os.environ.update(variables)
        importlib.reload(huggingface_hub.constants)
        return Path(huggingface_hub.constants.HF_HUB_CACHE)

    yield use
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    importlib.reload(huggingface_hub.constants)


def process_environment(base: dict[str, str], **variables: str) -> dict[str, str]:
    """A child process's environment: `base` with only the given hub variables set."""
    kept = {name: value for name, value in base.items() if name not in HUB_VARIABLES}
    return kept | variables


def invoke(argv: list[str], capsys: Any) -> tuple[int, str, float]:
    start = time.perf_counter()
    code = main(argv)
    return code, capsys.readouterr().err, time.perf_counter() - start


def results(out: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((out / "results.json").read_text())
    return data


def snapshot(cache: Path, repo_id: str, commit: str) -> Path:
    return cache / f"models--{repo_id.replace('/', '--')}" / "snapshots" / commit


# ---------------------------------------------------------------------------- first use


@pytest.mark.slow
def test_a_hub_id_downloads_into_an_empty_cache_then_evaluates(hub: Hub, tmp_path: Path) -> None:
    """As a user runs it: a fresh process, HF_ENDPOINT and an empty HF_HOME in its environment."""
    home, out = tmp_path / "hf-home", tmp_path / "run"
    env = process_environment(
        {**os.environ, "PYTHONPATH": str(REPO)}, HF_HOME=str(home), HF_ENDPOINT=hub.url
    )
    done = subprocess.run(
        [sys.executable, "-m", "llm_agents.cli", *eval_args(f"hf:{TINY}", out)],
        env=env,
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    commit = hub.commits[TINY]
    # One progress bar, counting every byte of the model's files.
    total = sum(len(data) for data in folder_files(hub.folder).values())
    bar = done.stderr.replace("\r", "\n")
    assert f"downloading {TINY} ({commit[:12]})" in bar
    shown = tqdm.format_sizeof(total)
    assert f"100%|██████████| {shown}/{shown}" in bar
    # The standard hub cache under HF_HOME, the weights byte for byte.
    folder = snapshot(home / "hub", TINY, commit)
    assert (folder / "model.safetensors").read_bytes() == (
        hub.folder / "model.safetensors"
    ).read_bytes()
    recorded = results(out)
    assert recorded["status"] == "complete"
    assert recorded["identity"]["model_revision"] == commit
    assert recorded["versions"]["model.revision"] == commit
    assert recorded["versions"]["model.model_path"] == str(folder)


@pytest.mark.slow
def test_offline_a_cached_hub_id_evaluates_without_a_request(
    hub: Hub, tmp_path: Path, capsys: Any, hub_environment: Callable[..., Path]
) -> None:
    cache = hub_environment(HF_HOME=str(tmp_path / "hf-home"), HF_ENDPOINT=hub.url)
    located = locate_model("hf", TINY, None)
    assert located.path == snapshot(cache, TINY, hub.commits[TINY])
    hub_environment(HF_HOME=str(tmp_path / "hf-home"), HF_ENDPOINT=hub.url, HF_HUB_OFFLINE="1")
    asked = len(hub.server.requests)
    code, err, _ = invoke(eval_args(f"hf:{TINY}", tmp_path / "run"), capsys)
    assert code == 0, err
    assert len(hub.server.requests) == asked
    assert results(tmp_path / "run")["identity"]["model_revision"] == hub.commits[TINY]


@pytest.mark.slow
def test_a_gguf_file_of_a_repository_downloads_alone_and_answers(
    hub: Hub, tmp_path: Path, hub_environment: Callable[..., Path]
) -> None:
    cache = hub_environment(HF_HOME=str(tmp_path / "hf-home"), HF_ENDPOINT=hub.url)
    commit = hub.commits[GGUF_REPO]
    model = get_model(f"hf:{GGUF_REPO}:{GGUF_FILE}", GenerateConfig(max_tokens=2), threads=1)
    [output] = model.generate([[ChatMessage(role="user", content="Say OK.")]])
    assert output.finish_reason in ("stop", "length"), output.error
    assert output.completion_tokens >= 1
    folder = snapshot(cache, GGUF_REPO, commit)
    assert model.info()["model_path"] == str(folder / GGUF_FILE)
    assert model.info()["revision"] == commit
    # Only the file the spec names: not the repository's other files.
    assert sorted(path.name for path in folder.iterdir()) == [GGUF_FILE]


def test_vllm_is_handed_the_local_snapshot_and_its_commit(
    hub: Hub, tmp_path: Path, hub_environment: Callable[..., Path]
) -> None:
    """What the vllm backend gives vLLM (`locate_model`, before the engine is built): a local
    folder, or the GGUF file, never the hub id."""
    cache = hub_environment(HF_HOME=str(tmp_path / "hf-home"), HF_ENDPOINT=hub.url)
    folder = locate_model("vllm", TINY, None)
    assert folder.path == snapshot(cache, TINY, hub.commits[TINY])
    assert folder.hub_model is not None and folder.hub_model.commit == hub.commits[TINY]
    assert (folder.path / "config.json").is_file()
    pinned = locate_model("vllm", f"{GGUF_REPO}:{GGUF_FILE}", hub.commits[GGUF_REPO])
    assert pinned.path == snapshot(cache, GGUF_REPO, hub.commits[GGUF_REPO]) / GGUF_FILE
    assert model_revision(f"vllm:{TINY}", {}) == hub.commits[TINY]
    assert model_revision("vllm:smollm2-135m", {}) is None
    assert model_revision(f"openai:{TINY}@http://127.0.0.1:1/v1", {}) is None


#: Runs in the vLLM environment (spawned engine children re-import it: the __main__ guard).
VLLM_SCRIPT = """
import json, sys
from llm_agents.backends import get_model, model_revision
from llm_agents.backends.base import ChatMessage, GenerateConfig

def main():
    spec, out = sys.argv[1], sys.argv[2]
    commit = model_revision(spec, {})
    model = get_model(spec, GenerateConfig(max_tokens=2), enforce_eager=True, max_model_len=512)
    [answer] = model.generate([[ChatMessage(role="user", content="Say OK.")]])
    with open(out, "w") as file:
        json.dump({"commit": commit, "info": model.info(), "answer": answer.model_dump()}, file)
    model.close()

if __name__ == "__main__":
    main()
"""


@pytest.mark.vllm
@pytest.mark.slow
def test_vllm_loads_a_hub_id_it_never_downloads_itself(hub: Hub, tmp_path: Path) -> None:
    from vllm_serve import START_TIMEOUT_S, VLLM_VENV, vllm_environment, vllm_environment_ready

    if not vllm_environment_ready():
        pytest.skip(f"no vLLM environment at {VLLM_VENV}; build it with scripts/setup_vllm_cpu.sh")
    script, out, home = tmp_path / "load.py", tmp_path / "out.json", tmp_path / "hf-home"
    script.write_text(VLLM_SCRIPT)
    env = process_environment(
        vllm_environment() | {"VLLM_ENABLE_V1_MULTIPROCESSING": "0"},
        HF_HOME=str(home),
        HF_ENDPOINT=hub.url,
    )
    asked = len(hub.server.requests)
    run = subprocess.run(
        [str(VLLM_VENV / "bin" / "python"), str(script), f"vllm:{TINY}", str(out)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S + 120,
    )
    assert run.returncode == 0, run.stderr[-4000:]
    loaded = json.loads(out.read_text())
    commit = hub.commits[TINY]
    assert loaded["commit"] == commit
    assert loaded["info"]["revision"] == commit
    assert loaded["info"]["model_path"] == str(snapshot(home / "hub", TINY, commit))
    assert loaded["answer"]["finish_reason"] in ("stop", "length"), loaded["answer"]
    # Every request was our code's, none vLLM's own: the model info of `main`, then the files
    # by their commit (beside the client's own telemetry, which asks for a list of agents).
    paths = [
        request.path
        for request in hub.server.requests[asked:]
        if request.path != "/api/agent-harnesses"
    ]
    assert paths[0] == f"/api/models/{TINY}/revision/main"
    assert all(
        path.startswith((f"/api/models/{TINY}/revision/", f"/{TINY}/resolve/{commit}/", "/cdn/"))
        for path in paths
    ), paths


# ---------------------------------------------------------------------------- revisions


@pytest.mark.slow
def test_a_resume_after_the_branch_moved_is_refused_naming_both_commits(
    hub: Hub, tmp_path: Path, capsys: Any, hub_environment: Callable[..., Path]
) -> None:
    hub_environment(HF_HOME=str(tmp_path / "hf-home"), HF_ENDPOINT=hub.url)
    first = hub.commits[MOVING]
    out = tmp_path / "run"
    code, err, _ = invoke(eval_args(f"hf:{MOVING}", out), capsys)
    assert code == 0, err
    assert results(out)["identity"]["model_revision"] == first
    before = {path.name: path.read_bytes() for path in out.iterdir()}

    moved = hub.server.commit(MOVING, folder_files(hub.folder) | {"README.md": b"moved\n"})
    code, err, elapsed = invoke(eval_args(f"hf:{MOVING}", out), capsys)
    assert code == 2
    [line] = [line for line in err.splitlines() if line.strip()]
    assert "model revision" in line and first in line and moved in line
    assert {path.name: path.read_bytes() for path in out.iterdir()} == before
    assert elapsed < FAILS_WITHIN_S

    # A pinned revision plays its own commit, wherever the branch is now.
    pinned = tmp_path / "pinned"
    code, err, _ = invoke(
        eval_args(f"hf:{MOVING}", pinned, "--backend-option", f"revision={first}"), capsys
    )
    assert code == 0, err
    assert results(pinned)["identity"]["model_revision"] == first
    assert results(pinned)["versions"]["model.revision"] == first


# ---------------------------------------------------------------------------- bad input


@dataclass
class BadInput:
    model: str
    message: str
    env: dict[str, str] = field(default_factory=dict)
    """Variables beside HF_HOME; `{hub}` is the hub's URL, `{dead}` a port nobody listens on."""
    extra: tuple[str, ...] = ()


BAD_INPUTS = {
    "unknown repository": BadInput("hf:tiny-org/no-such-model", "no model repository"),
    "unknown revision": BadInput(
        f"hf:{TINY}", "has no revision 'v9'", extra=("--backend-option", "revision=v9")
    ),
    "unreachable hub": BadInput(f"hf:{TINY}", "cannot reach the hub", {"HF_ENDPOINT": "{dead}"}),
    "gated without a token": BadInput(f"vllm:{GATED}", "gated repository"),
    "gated, a token without access": BadInput(
        f"hf:{GATED}", "has no access", {"HF_TOKEN": UNGRANTED_TOKEN}
    ),
    "a token the hub refuses": BadInput(f"hf:{TINY}", "refused the token", {"HF_TOKEN": "hf_x"}),
    "not cached, offline": BadInput(
        f"hf:{TINY}", "not in the local hub cache", {"HF_HUB_OFFLINE": "1"}
    ),
    "disk too small": BadInput(f"hf:{HUGE}", "needs 1000000.0 GB free"),
    "no such GGUF file": BadInput(f"hf:{GGUF_REPO}:missing.gguf", f"its GGUF files: {GGUF_FILE}"),
    "a GGUF repository named as a folder": BadInput(f"hf:{GGUF_REPO}", "no config.json"),
    "a misspelled named model": BadInput("hf:smollm2-135", "did you mean hf:smollm2-135m?"),
    # Ids the hub's own rules reject, refused before any request, online or not.
    "a hub id ending in a dot": BadInput("hf:tiny-org/name.", "'tiny-org/name.' is not a valid"),
    "a hub id with a double dash": BadInput(
        "vllm:tiny-org/a--b", "not a valid hub id", {"HF_HUB_OFFLINE": "1"}
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_a_hub_mistake_is_one_line_exit_2_and_writes_nothing(
    case: str, hub: Hub, tmp_path: Path, capsys: Any, hub_environment: Callable[..., Path]
) -> None:
    bad = BAD_INPUTS[case]
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{probe.getsockname()[1]}"
    env = {"HF_ENDPOINT": hub.url} | {
        name: value.format(hub=hub.url, dead=dead) for name, value in bad.env.items()
    }
    hub_environment(HF_HOME=str(tmp_path / "hf-home"), **env)
    out = tmp_path / "run"
    code, err, elapsed = invoke(eval_args(bad.model, out, *bad.extra), capsys)
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("craftext-llm: error: ") and bad.message in lines[0], lines[0]
    assert not out.exists()
    assert elapsed < FAILS_WITHIN_S
    for token in (GRANTED_TOKEN, UNGRANTED_TOKEN, "hf_x"):
        assert token not in err


def test_a_revision_of_a_local_folder_is_refused(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no hub id"):
        locate_model("hf", str(tmp_path), "main")


def test_a_colon_names_only_a_gguf_file() -> None:
    with pytest.raises(UserError, match="names a GGUF file"):
        model_revision(f"hf:{TINY}:model.safetensors", {})
