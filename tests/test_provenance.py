"""The code version a run and each of its episodes record: a checkout's `git describe` (with a
digest of the sources when it has uncommitted changes), else the package version with that
digest."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from llm_agents.run_data.provenance import (
    PACKAGES,
    code_version,
    hardware,
    pooled_hardware,
    sources_digest,
)

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")


def sources(root: Path) -> Path:
    """A tree holding the project's packages, one small module each."""
    for package in PACKAGES:
        (root / package).mkdir(parents=True)
        (root / package / "__init__.py").write_text(f"NAME = {package!r}\n")
    return root


def git(root: Path, *args: str) -> str:
    command = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(root), *args]
    return subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip()


def test_an_install_is_its_version_and_a_digest_of_what_its_sources_say(tmp_path: Path) -> None:
    root = sources(tmp_path / "site-packages")
    version = code_version(root)
    assert version.endswith(f"+src.{sources_digest(root)[:12]}")
    (root / "env" / "__pycache__").mkdir()
    (root / "env" / "__pycache__" / "x.pyc").write_bytes(b"compiled")
    (root / "env" / "notes.txt").write_text("not code")
    assert code_version(root) == version
    (root / "prompts" / "step.j2").write_text("{{ observation }}")
    assert code_version(root) != version


def test_a_checkout_is_its_git_describe_and_an_edited_one_adds_the_digest(tmp_path: Path) -> None:
    root = sources(tmp_path / "checkout")
    git(root, "init", "-q")
    git(root, "add", ".")
    git(root, "commit", "-q", "-m", "first")
    commit = git(root, "rev-parse", "--short=12", "HEAD")
    assert code_version(root) == commit
    git(root, "tag", "v1.2")
    assert code_version(root) == "v1.2"

    (root / "llm_agents" / "__init__.py").write_text("NAME = 'edited'\n")
    edited = code_version(root)
    assert edited == f"v1.2-dirty+src.{sources_digest(root)[:12]}"
    (root / "llm_agents" / "__init__.py").write_text("NAME = 'edited again'\n")
    assert code_version(root) not in (edited, "v1.2")


def test_packages_inside_another_repository_are_not_its_code(tmp_path: Path) -> None:
    project = tmp_path / "project"
    project.mkdir()
    git(project, "init", "-q")
    (project / "README").write_text("someone else's project")
    git(project, "add", ".")
    git(project, "commit", "-q", "-m", "theirs")
    root = sources(project / ".venv" / "site-packages")
    assert code_version(root).endswith(f"+src.{sources_digest(root)[:12]}")
    assert not code_version(root).startswith(git(project, "rev-parse", "--short=12", "HEAD"))


def test_the_running_code_is_this_checkout() -> None:
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        pytest.skip("not run from a checkout")
    head = git(root, "describe", "--tags", "--always", "--abbrev=12")
    assert code_version().startswith(head)


def test_hardware_names_this_machine() -> None:
    found = hardware()
    assert found["cpu_cores"] == str(len(os.sched_getaffinity(0)))
    kib = next(
        int(line.split()[1])
        for line in Path("/proc/meminfo").read_text().splitlines()
        if line.startswith("MemTotal:")
    )
    assert float(found["memory_gib"]) == pytest.approx(kib / 2**20, abs=0.05)
    assert ("gpus" in found) == any(Path("/proc/driver/nvidia/gpus").glob("*/information"))


def test_workers_machines_pool_into_one_record_naming_each_distinct_value() -> None:
    a100 = {"cpu": "EPYC", "cpu_cores": "16", "gpus": "NVIDIA A100"}
    h100 = {"cpu": "EPYC", "cpu_cores": "16", "gpus": "NVIDIA H100"}
    assert pooled_hardware([a100, h100, a100]) == {
        "cpu": "EPYC",
        "cpu_cores": "16",
        "gpus": "NVIDIA A100 + NVIDIA H100",
        "workers": "3",
    }
    assert pooled_hardware([hardware()]) == hardware() | {"workers": "1"}
