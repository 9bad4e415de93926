"""`make test` builds the vLLM environment beside pytest: the vLLM tests wait for the setup
script's lock rather than skip while the build runs."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import vllm_serve


def _fake_environment(root: Path, *, built: bool) -> Path:
    venv = root / "venv-vllm"
    (venv / "bin").mkdir(parents=True)
    if built:
        (venv / "bin" / "vllm").write_text("")
        (venv / ".craftext-vllm-ready").write_text("setup-v2\n")
    return venv


@contextlib.contextmanager
def _build_running(venv: Path, seconds: int) -> Iterator[None]:
    """The lock held as scripts/setup_vllm_cpu.sh holds it, by flock(1), for `seconds`."""
    holder = subprocess.Popen(
        ["flock", f"{venv}.lock", "sleep", str(seconds)], start_new_session=True
    )
    try:
        while not Path(f"{venv}.lock").exists():
            time.sleep(0.05)
        time.sleep(0.2)  # flock(1) creates the file, then takes the lock
        yield
    finally:
        os.killpg(holder.pid, signal.SIGKILL)  # flock(1) and the sleep that inherited the lock
        holder.wait(timeout=30)


@pytest.mark.parametrize("built", [True, False])
def test_a_build_in_progress_is_waited_for_then_its_outcome_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, built: bool
) -> None:
    venv = _fake_environment(tmp_path, built=built)
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", venv)
    with _build_running(venv, seconds=2):
        start = time.monotonic()
        ready = vllm_serve.vllm_environment_ready()
        waited = time.monotonic() - start
    assert ready is built
    assert waited > 1.0


def test_a_build_that_outlasts_the_wait_is_an_error_not_a_skip(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    venv = _fake_environment(tmp_path, built=True)
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", venv)
    with _build_running(venv, seconds=30), pytest.raises(TimeoutError, match="still building"):
        vllm_serve.vllm_environment_ready(timeout_s=1)


def test_no_lock_and_no_environment_is_not_ready(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", tmp_path / "absent")
    assert vllm_serve.vllm_environment_ready(timeout_s=1) is False
