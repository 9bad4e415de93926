"""Packaging: `env/` stays tracked, and the built wheel alone makes a working install.

The wheel is built from a copy of the checkout, unpacked, and imported in a child process whose
only project code is the unpacked wheel (an empty temporary directory as working directory), so a
module or template missing from the wheel fails here even though the source tree has it.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("env", "textualizer", "prompts", "llm_agents")
CONSOLE_SCRIPT = "craftext-llm = llm_agents.cli:main"
#: Not copied into the build folder: environments, caches, earlier build outputs, run results.
COPY_IGNORE = shutil.ignore_patterns(
    ".git",
    ".venv*",
    "__pycache__",
    "*.egg-info",
    ".*_cache",
    ".hypothesis",
    "build",
    "dist",
    "runs",
    "results",
)


def _git(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=False)


def test_env_package_is_not_git_ignored() -> None:
    if shutil.which("git") is None or _git("rev-parse", "--is-inside-work-tree").returncode != 0:
        pytest.skip("not a git checkout")
    # --no-index: judge by the ignore patterns alone, even for files already tracked.
    # check-ignore exits 0 when the path is ignored, 1 when it is not.
    for path in ("env/__init__.py", "env/dataset.py"):
        result = _git("check-ignore", "--no-index", "-v", path)
        assert result.returncode == 1, f"{path} is git-ignored by: {result.stdout.strip()}"
    # The virtualenv patterns themselves still work at the root.
    # .venv-vllm is a link to the shared vLLM environment (to git, a file, not a folder; nothing
    # beyond it can be asked about) or an older build in the clone.
    for path in (".venv/bin/python", ".venv-older/bin/python", ".venv-vllm"):
        assert _git("check-ignore", "--no-index", "-q", path).returncode == 0, path


def _source_files() -> dict[str, Path]:
    """Wheel member name -> source file, for every file the wheel must hold."""
    wanted: dict[str, Path] = {}
    for package in PACKAGES:
        for init in sorted((REPO / package).rglob("__init__.py")):
            for file in sorted(init.parent.glob("*.py")):
                wanted[file.relative_to(REPO).as_posix()] = file
    # Prompt templates, and the HTML templates of `view` (llm_agents/viewer/templates/).
    for package in PACKAGES:
        for template in sorted((REPO / package).rglob("*.j2")):
            wanted[template.relative_to(REPO).as_posix()] = template
    return wanted


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"
    shutil.copytree(REPO, source, ignore=COPY_IGNORE)
    wheelhouse = root / "wheelhouse"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "--disable-pip-version-check",
            "-w",
            str(wheelhouse),
            str(source),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, f"wheel build failed:\n{result.stdout}\n{result.stderr}"
    wheels = sorted(wheelhouse.glob("craftext_llm-*.whl"))
    assert len(wheels) == 1, f"expected one craftext_llm wheel, found {wheels}"
    yield wheels[0]


def test_wheel_holds_every_package_module_and_template(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        dist_info = sorted({n.split("/")[0] for n in names if ".dist-info/" in n})
        assert len(dist_info) == 1, dist_info
        entry_points = archive.read(f"{dist_info[0]}/entry_points.txt").decode()
    wanted = _source_files()
    assert any(n.endswith(".j2") for n in wanted), "no prompt templates found in the source tree"
    missing = sorted(set(wanted) - names)
    assert not missing, f"missing from the wheel: {missing}"
    top_level = {name.split("/")[0] for name in names} - set(dist_info)
    assert top_level == set(PACKAGES), f"unexpected top-level entries: {top_level - set(PACKAGES)}"
    assert CONSOLE_SCRIPT in entry_points.replace("  ", " ")


CHILD = r"""
import importlib, importlib.resources, json, pkgutil, sys

modules = sys.argv[1:]
found = {name: importlib.import_module(name).__file__ for name in modules}

import prompts

templates = sorted(
    entry.name for entry in importlib.resources.files("prompts").iterdir()
    if entry.name.endswith(".j2")
)
rendered = prompts.render_template("answer_only", {"has_partial_answer": False})
system_path = str(prompts.template_path("system"))

entry_point = None
if "llm_agents.cli" in modules:
    main = pkgutil.resolve_name("llm_agents.cli:main")
    entry_point = callable(main)

print(json.dumps({
    "files": found,
    "templates": templates,
    "rendered": rendered,
    "system_path": system_path,
    "entry_point": entry_point,
}))
"""


def test_unpacked_wheel_imports_and_renders_templates(wheel: Path, tmp_path: Path) -> None:
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    workdir = tmp_path / "cwd"
    workdir.mkdir()

    modules = [*PACKAGES, "llm_agents.backends"]
    # The lead's CLI module: required in the wheel as soon as the source tree has it.
    if (REPO / "llm_agents" / "cli.py").is_file():
        modules.append("llm_agents.cli")

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONPATH"] = str(site)
    env["PYTHONNOUSERSITE"] = "1"
    result = subprocess.run(
        [sys.executable, "-c", CHILD, *modules],
        cwd=workdir,
        env=env,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert result.returncode == 0, f"import from the wheel failed:\n{result.stderr}"
    report = json.loads(result.stdout.strip().splitlines()[-1])

    site_resolved = site.resolve()
    for name, file in report["files"].items():
        assert file is not None, f"{name} has no __file__ (namespace package?)"
        location = Path(file).resolve()
        assert location.is_relative_to(site_resolved), f"{name} imported from {location}"
        assert not location.is_relative_to(REPO), f"{name} imported from the source tree"

    expected = sorted(p.name for p in (REPO / "prompts").glob("*.j2"))
    assert report["templates"] == expected
    assert Path(report["system_path"]).resolve().is_relative_to(site_resolved)
    # Same text as the source tree's template renders in this process.
    from prompts import render_template

    assert report["rendered"] == render_template("answer_only", {"has_partial_answer": False})
    assert report["rendered"]
    if "llm_agents.cli" in modules:
        assert report["entry_point"] is True
