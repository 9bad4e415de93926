"""Agents from outside `llm_agents/`: the example of docs/writing-an-agent.md, written to a folder
put on `sys.path` (on `PYTHONPATH` for the command line), plays, resumes (refused under another
version of the agent), is reported and viewed; installed packages' entry points register short
names, read through `importlib.metadata` from real `*.dist-info` folders; and every mistake in
naming an agent is one line, exit 2, nothing written."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from outside_agents import (
    EXAMPLE_AGENT,
    REPO,
    page_distribution,
    write_distribution,
    write_outside_package,
)

from env.errors import UserError
from llm_agents.agents import AGENT_PROTOCOL_VERSION, agent_class
from llm_agents.agents.loading import agent_identity, agent_shipment, registered_agents
from llm_agents.cli import EXIT_USER_ERROR, main
from llm_agents.judging.report import report_run
from llm_agents.run_data.store import read_episodes, read_results
from llm_agents.viewer import build_view

MAX_STEPS = 6
SCRIPT = "mock:hash:LEFT|DO|I would go UP|zzz"


def eval_argv(out: Path, agent: str = EXAMPLE_AGENT, limit: int = 3) -> list[str]:
    return [
        "eval", "--agent", agent, "--model", SCRIPT, "--variant", "classic",
        "--categories", "combo", "new_objects", "--max-steps", str(MAX_STEPS),
        "--batch-size", "2", "--limit", str(limit), "--output-dir", str(out), "--no-progress",
    ]  # fmt: skip


@pytest.fixture(scope="module")
def outside(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder holding `my_agents` (the page's example) and `bad_agents`."""
    return write_outside_package(tmp_path_factory.mktemp("outside"))


@pytest.fixture
def on_path(outside: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.syspath_prepend(str(outside))
    return outside


def invoke(argv: list[str], capsys: Any) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


def snapshot(root: Path) -> dict[str, bytes | None]:
    return {
        str(path.relative_to(root)): path.read_bytes() if path.is_file() else None
        for path in sorted(root.rglob("*"))
    }


def episodes(run_dir: Path) -> list[dict[str, Any]]:
    found = (e.model_dump(exclude={"code"}) for e in read_episodes(run_dir / "episodes.jsonl"))
    return sorted(found, key=lambda e: e["episode_id"])


def decisions(run_dir: Path) -> list[tuple[str, int, str, str, str]]:
    lines = (run_dir / "steps.jsonl").read_text().splitlines()
    steps = [json.loads(line) for line in lines]
    return sorted(
        (s["episode_id"], s["step"], s["prompt_hash"], s["raw_output"], s["action_name"])
        for s in steps
    )


@pytest.fixture(scope="module")
def played(outside: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run of the page's example, uninterrupted."""
    out = tmp_path_factory.mktemp("played") / "run"
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(outside))
        assert main(eval_argv(out)) == 0
    return out


def test_the_page_example_plays_with_its_path_and_version_recorded(played: Path) -> None:
    results = read_results(played / "results.json")
    assert results.status == "complete" and results.finished == 3
    assert results.config["agent"] == EXAMPLE_AGENT
    agent = results.identity.agent
    assert agent is not None
    assert (agent.path, agent.version, agent.version_from) == (EXAMPLE_AGENT, "1.0", "attribute")
    steps = [json.loads(line) for line in (played / "steps.jsonl").read_text().splitlines()]
    # The agent's own prompt reached the model, and its answers were read by the parser: "zzz"
    # names no action and plays the fallback, counted invalid.
    assert len(steps) == 3 * MAX_STEPS
    fallbacks = [s for s in steps if s["raw_output"] == "zzz"]
    assert fallbacks and all(s["fallback_used"] and s["action_name"] == "NOOP" for s in fallbacks)
    assert {s["action_name"] for s in steps if s["raw_output"] == "I would go UP"} == {"UP"}
    assert sum(e.invalid_actions for e in read_episodes(played / "episodes.jsonl")) == len(
        fallbacks
    )


def test_a_resumed_run_ends_with_the_episodes_of_an_uninterrupted_one(
    on_path: Path, played: Path, tmp_path: Path, capsys: Any
) -> None:
    out = tmp_path / "run"
    assert invoke(eval_argv(out, limit=1), capsys)[0] == 0
    assert read_results(out / "results.json").finished == 1
    assert invoke(eval_argv(out), capsys)[0] == 0
    assert read_results(out / "results.json").finished == 3
    assert episodes(out) == episodes(played)
    assert decisions(out) == decisions(played)


def test_a_resume_under_another_version_of_the_agent_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    # A package of its own: its module is edited and imported afresh.
    folder = write_outside_package(tmp_path / "pkg", package="resumable_agents")
    monkeypatch.syspath_prepend(str(folder))
    agent = "resumable_agents.terse:TerseAgent"
    out = tmp_path / "run"
    assert invoke(eval_argv(out, agent=agent, limit=1), capsys)[0] == 0
    module = folder / "resumable_agents" / "terse.py"
    module.write_text(
        module.read_text().replace('version: ClassVar[str] = "1.0"', 'version = "1.1"')
    )
    monkeypatch.delitem(sys.modules, "resumable_agents.terse")
    before = snapshot(tmp_path)

    code, err = invoke(eval_argv(out, agent=agent), capsys)

    assert code == EXIT_USER_ERROR
    assert err.count("\n") == 1, err
    assert f"agent ({agent} (version 1.0) before, {agent} (version 1.1) now)" in err, err
    assert snapshot(tmp_path) == before


def test_without_a_version_the_agent_is_its_modules_source(on_path: Path) -> None:
    identity = agent_identity("bad_agents.kinds:UnversionedAgent")
    assert identity is not None and identity.version_from == "source"
    source = (on_path / "bad_agents" / "kinds.py").read_bytes()
    assert identity.version == hashlib.sha256(source).hexdigest()
    # A built-in agent is this package's code: no agent identity.
    assert agent_identity("zero-shot") is None


@pytest.mark.slow
def test_the_command_line_plays_it_and_report_and_view_read_it_back_without_it(
    outside: Path, played: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    environment = os.environ | {"PYTHONPATH": os.pathsep.join([str(REPO), str(outside)])}
    command = [sys.executable, "-m", "llm_agents.cli"]
    done = subprocess.run(
        [*command, *eval_argv(out)], cwd=REPO, env=environment, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert episodes(out) == episodes(played)
    # Reading a run back needs neither the agent's package nor the model.
    bare = os.environ | {"PYTHONPATH": str(REPO)}
    report = subprocess.run(
        [*command, "report", str(out)], cwd=REPO, env=bare, capture_output=True, text=True
    )
    assert report.returncode == 0, report.stderr[-2000:]
    assert report.stdout.strip() == report_run(out).strip()
    assert f"Agent: {EXAMPLE_AGENT} (version 1.0), from outside craftext-llm." in report.stdout
    viewed = build_view(out, progress=False)
    assert {status.state for status in viewed.statuses.values()} == {"reproduced"}
    assert len(viewed.statuses) == 3


# ------------------------------------------------------------------------------ entry points


def test_an_installed_package_registers_a_short_name(
    outside: Path, played: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    # The page's pyproject.toml, installed beside the package it names.
    page_distribution(tmp_path / "site")
    monkeypatch.syspath_prepend(str(outside))
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    registration = registered_agents()["terse"]
    assert registration.target == EXAMPLE_AGENT
    assert "distribution my-agents" in registration.origin
    assert agent_class("terse") is agent_class(EXAMPLE_AGENT)

    out = tmp_path / "run"
    assert invoke(eval_argv(out, agent="terse"), capsys)[0] == 0
    agent = read_results(out / "results.json").identity.agent
    assert agent is not None
    assert (agent.path, agent.version, agent.version_from, agent.distribution) == (
        EXAMPLE_AGENT,
        "1.2",
        "distribution",
        "my-agents",
    )
    # The same class under its short name plays the same episodes.
    assert episodes(out) == episodes(played)
    # Installed, it is named by its distribution's version under its path too.
    by_path = agent_identity(EXAMPLE_AGENT)
    assert by_path is not None and by_path.version == "1.2"


def test_a_name_a_built_in_has_is_an_error_naming_both(
    on_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    write_distribution(tmp_path / "site", "greedy-agents", "0.1", {"zero-shot": EXAMPLE_AGENT})
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    before = snapshot(tmp_path)

    code, err = invoke(eval_argv(tmp_path / "run", agent="zero-shot"), capsys)

    assert code == EXIT_USER_ERROR and err.count("\n") == 1, err
    assert f"entry point zero-shot = {EXAMPLE_AGENT} of distribution greedy-agents" in err
    assert (
        "the built-in agent zero-shot (llm_agents.agents.strategies.zero_shot:ZeroShotAgent)" in err
    )
    assert snapshot(tmp_path) == before


def test_a_name_two_packages_register_is_an_error_naming_both(
    on_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    write_distribution(tmp_path / "one", "first-agents", "1.0", {"twin": EXAMPLE_AGENT})
    write_distribution(tmp_path / "two", "second-agents", "1.0", {"twin": EXAMPLE_AGENT})
    monkeypatch.syspath_prepend(str(tmp_path / "one"))
    monkeypatch.syspath_prepend(str(tmp_path / "two"))

    code, err = invoke(eval_argv(tmp_path / "run", agent="twin"), capsys)

    assert code == EXIT_USER_ERROR and err.count("\n") == 1, err
    assert "first-agents" in err and "second-agents" in err and "'twin'" in err
    assert not (tmp_path / "run").exists()


def test_an_entry_point_that_names_no_class_is_an_error_naming_it(
    on_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    write_distribution(tmp_path / "site", "vague-agents", "0.3", {"vague": "my_agents.terse"})
    monkeypatch.syspath_prepend(str(tmp_path / "site"))

    code, err = invoke(eval_argv(tmp_path / "run", agent="vague"), capsys)

    assert code == EXIT_USER_ERROR and err.count("\n") == 1, err
    assert "entry point vague = my_agents.terse of distribution vague-agents" in err
    assert "does not name a class as package.module:Class" in err
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------------------ mistakes

MISTAKES = {
    "a path that does not import": (
        "no_such_agents.terse:TerseAgent",
        "agent no_such_agents.terse:TerseAgent does not import: ModuleNotFoundError",
    ),
    "a module that needs what is not installed": (
        "bad_agents.unimportable:Agent",
        "No module named 'no_such_module_for_craftext_tests'",
    ),
    "a module that raises on import": (
        "bad_agents.raising:Agent",
        "importing bad_agents.raising failed: RuntimeError: this module breaks on import",
    ),
    "a class that is not there": (
        "my_agents.terse:TersAgent",
        "module my_agents.terse has no 'TersAgent'",
    ),
    "a name that is not registered": ("genius", "unknown agent 'genius'"),
    "a misspelt built-in": ("zero-shoot", "did you mean zero-shot?"),
    "a path that is not one": ("my_agents/terse.py:TerseAgent", "is not a class path"),
    "not a class": ("bad_agents.kinds:NOT_A_CLASS", "is not a class but a int"),
    "a class that is not an agent": (
        "bad_agents.kinds:NotAnAgent",
        "is not an agent: it lacks protocol_version, needs_model, templates, from_config, "
        "start_episode, end_episode, check_templates, decide",
    ),
    "a class that builds what is not an agent": (
        "bad_agents.kinds:HalfAgent",
        "what its from_config builds lacks fallback_id, choices",
    ),
    "an agent of another protocol version": (
        "bad_agents.kinds:FutureAgent",
        f"is written for agent protocol 2; this craftext-llm speaks protocol "
        f"{AGENT_PROTOCOL_VERSION}",
    ),
}


@pytest.mark.parametrize("name", list(MISTAKES))
def test_a_mistaken_agent_is_one_line_exit_2_and_nothing_written(
    name: str, on_path: Path, tmp_path: Path, capsys: Any
) -> None:
    agent, message = MISTAKES[name]
    before = snapshot(tmp_path)

    code, err = invoke(eval_argv(tmp_path / "run", agent=agent), capsys)

    assert code == EXIT_USER_ERROR
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("craftext-llm: error: "), err
    assert message in lines[0], lines[0]
    assert snapshot(tmp_path) == before


def test_an_agent_from_a_folder_is_shipped_to_ray_workers_an_installed_one_is_not(
    on_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert agent_shipment(EXAMPLE_AGENT) == on_path / "my_agents"
    assert agent_shipment("zero-shot") is None
    # What is installed (in a site-packages folder) is the cluster's to install.
    site = write_outside_package(tmp_path / "lib" / "site-packages", package="installed_agents")
    monkeypatch.syspath_prepend(str(site))
    assert agent_shipment("installed_agents.terse:TerseAgent") is None


def test_a_ray_worker_with_another_version_of_the_agent_is_refused() -> None:
    from llm_agents.evaluation.ray_runner import WorkerReady, _check_worker_agent
    from llm_agents.run_data.store import AgentIdentity

    driver = AgentIdentity(path=EXAMPLE_AGENT, version="1.0", version_from="attribute")
    _check_worker_agent(WorkerReady(agent=driver), driver)
    other = driver.model_copy(update={"version": "0.9"})
    with pytest.raises(UserError, match=r"plays agent .*\(version 0\.9\), the driver .*1\.0\)"):
        _check_worker_agent(WorkerReady(agent=other), driver)
    with pytest.raises(UserError, match="plays agent built-in"):
        _check_worker_agent(WorkerReady(), driver)
