"""Shared fixtures: one compiled env per variant for the whole session (compiles are the slow part)."""

from __future__ import annotations

import os
import zipfile
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
# CI has ../shared/data, the vLLM environment and Chromium: a skip there would hide a check that
# silently stopped running (the differential against the official checkers among them), so under
# `CI` every skip but a GPU test's is reported as a failure with its reason.
IN_CI = bool(os.environ.get("CI"))


def pytest_configure(config: pytest.Config) -> None:
    """Each pytest worker's thread pools sized to its share of the cores, before any test module
    imports torch.

    Torch (and vLLM on CPU, OpenMP both) start one thread per core and spin while waiting. Beside
    another busy worker, a pool of two on two cores runs slower than a pool of one: the embedded
    model's grounding test took 38 s beside a busy core with two threads, 21 s with one (14 s
    alone). Child processes (vLLM, CLI runs) inherit the setting; one set by hand is kept.
    """
    # Only in xdist's workers: one pytest process may use every core, and the controller's
    # environment, which the workers inherit, must not pass its own choice on as the user's.
    worker = getattr(config, "workerinput", None)
    if worker is None:
        return
    share = max(1, len(os.sched_getaffinity(0)) // worker["workercount"])
    for variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(variable, str(share))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report = yield
    if IN_CI and report.skipped and item.get_closest_marker("gpu") is None:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else report.longrepr
        report.outcome = "failed"
        report.longrepr = f"skipped under CI (only GPU tests may skip there): {reason}"
    return report


# A worker that crashes in native code (a rare segmentation fault inside XLA, seen late in a long
# worker's life) stops the run at once (`make test` passes --max-worker-restart=0). `make test`
# then runs what the crash left unfinished once more, in fresh workers: the controller writes the
# collected tests that never finished, the crashed one included, to the file this names (nothing
# when another test failed: that fails the run).
UNFINISHED_TESTS_FILE = os.environ.get("CRAFTEXT_UNFINISHED_TESTS")
_collected: list[str] = []
_finished: set[str] = set()
_crashed: set[str] = set()
_failed: set[str] = set()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node: Any, ids: list[str]) -> None:
    if not _collected:
        _collected.extend(ids)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "teardown":
        _finished.add(report.nodeid)
    elif report.when == "???":  # xdist's report of the test a worker crashed in
        _crashed.add(report.nodeid)
    elif report.failed:
        _failed.add(report.nodeid)


def pytest_sessionfinish(session: pytest.Session) -> None:
    # Only a crash is run again: a test that failed on its own fails the run as it is.
    if (
        UNFINISHED_TESTS_FILE
        and _crashed
        and not _failed
        and not hasattr(session.config, "workerinput")
    ):
        unfinished = [test for test in _collected if test not in _finished]
        Path(UNFINISHED_TESTS_FILE).write_text("".join(f"{test}\n" for test in unfinished))


# Port 9 (discard) on loopback refuses connections: no test reaches the real code host.
UNREACHABLE_CODE_HOST = "http://127.0.0.1:9"


@pytest.fixture(scope="session", autouse=True)
def _no_real_code_host() -> Iterator[None]:
    """Point the official-data download at a refusing loopback port; tests that download serve
    their own archive and set the variable themselves."""
    from env.downloads import CODE_HOST_ENV_VAR

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(CODE_HOST_ENV_VAR, UNREACHABLE_CODE_HOST)
        yield


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """`../shared/data` beside the checkout (reference copies; never committed)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"reference data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def official_repository(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The official CrafText repository at 1c518ae, unpacked from the shared reference zip."""
    archive = shared_data / "craftext_official_1c518ae.zip"
    if not archive.is_file():
        pytest.skip(f"reference archive {archive} is absent")
    target = tmp_path_factory.mktemp("official-repository")
    with zipfile.ZipFile(archive) as opened:
        opened.extractall(target)
    (root,) = target.iterdir()
    return root


@dataclass
class CompiledEnv:
    """A CrafText env with its single-episode functions jitted once."""

    env: Any
    reset: Any
    step: Any


def _compiled(variant: str) -> CompiledEnv:
    import jax

    from env import EnvConfig, Variant, shared_env

    env = shared_env(EnvConfig(variant=Variant(variant)))
    # The env already holds a jitted reset (VectorEnv refills use it); reuse its trace.
    return CompiledEnv(env=env, reset=env.jitted_reset, step=jax.jit(env.step_from_episode_key))


@pytest.fixture(scope="session")
def classic_env() -> CompiledEnv:
    return _compiled("classic")


@pytest.fixture(scope="session")
def full_env() -> CompiledEnv:
    return _compiled("full")


@pytest.fixture(scope="session", params=["classic", "full"])
def any_env(
    request: pytest.FixtureRequest, classic_env: CompiledEnv, full_env: CompiledEnv
) -> CompiledEnv:
    return classic_env if request.param == "classic" else full_env
