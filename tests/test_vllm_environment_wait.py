"""`make test` builds the vLLM environment beside pytest: the vLLM tests wait for the setup
script's lock rather than skip while the build runs."""

from __future__ import annotations

import subprocess
import time
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


@pytest.mark.parametrize("built", [True, False])
def test_a_build_in_progress_is_waited_for_then_its_outcome_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, built: bool
) -> None:
    venv = _fake_environment(tmp_path, built=built)
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", venv)
    # The lock taken as scripts/setup_vllm_cpu.sh takes it, by flock(1), for 2 s.
    holder = subprocess.Popen(["flock", f"{venv}.lock", "sleep", "2"])
    try:
        while not Path(f"{venv}.lock").exists():
            time.sleep(0.05)
        time.sleep(0.2)  # flock(1) creates the file, then takes the lock
        start = time.monotonic()
        ready = vllm_serve.vllm_environment_ready()
        waited = time.monotonic() - start
    finally:
        holder.wait(timeout=30)
    assert ready is built
    assert waited > 1.0


def test_a_build_that_outlasts_the_wait_is_an_error_not_a_skip(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    venv = _fake_environment(tmp_path, built=True)
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", venv)
    holder = subprocess.Popen(["flock", f"{venv}.lock", "sleep", "30"])
    try:
        while not Path(f"{venv}.lock").exists():
            time.sleep(0.05)
        time.sleep(0.2)
        with pytest.raises(TimeoutError, match="still building"):
            vllm_serve.vllm_environment_ready(timeout_s=1)
    finally:
        holder.kill()
        holder.wait(timeout=30)


def test_no_lock_and_no_environment_is_not_ready(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(vllm_serve, "VLLM_VENV", tmp_path / "absent")
    assert vllm_serve.vllm_environment_ready(timeout_s=1) is False
