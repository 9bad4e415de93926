"""Every user mistake: one line on stderr, a non-zero exit, no traceback, and nothing that was
on disk before is changed (nor anything new written).

Each row is a command line (with `{tmp}` for the test's directory), the files to lay out
before it, and a fragment the one error line must contain. The eval rows are otherwise valid
mock runs: a mistake that slipped through would play episodes and write results, which the
unchanged-files check catches.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from env.dataset import Dataset, DatasetSource, Goal
from llm_agents.cli import main

#: A valid, tiny mock evaluation; rows append the mistake.
EVAL = [
    "eval", "--model", "mock:", "--variant", "classic", "--categories", "combo", "--max-steps", "2",
    "--limit", "1", "--batch-size", "1", "--output-dir", "{tmp}/run", "--no-progress",
]  # fmt: skip
LOGLIK_PMI = ["--choice", "loglik", "--choice-scoring", "pmi"]
PLAN = ["plan", "--model", "mock:", "--output", "{tmp}/plans.json", "--no-progress", "--limit", "1"]


@dataclass
class Mistake:
    argv: list[str]
    message: str
    files: dict[str, str] = field(default_factory=dict)
    """Files laid out first: path under {tmp} -> text ("/" at the end: a directory)."""
    setup: Callable[[Path], Any] | None = None


def config_file(name: str, text: str, *flags: str) -> Mistake:
    return Mistake([*EVAL, "--config", "{tmp}/" + name, *flags], "", files={name: text})


def with_message(mistake: Mistake, message: str) -> Mistake:
    mistake.message = message
    return mistake


EASY_ONLY_DATASET = Dataset(
    source=DatasetSource(kind="json", path="easy.json"),
    goals=(
        Goal(
            id="PLACE_TABLE",
            split="easy_train",
            category="one",
            instruction="Place a table.",
            paraphrases=(),
            required=("PLACE_TABLE",),
        ),
    ),
).model_dump_json()

#: An EASY split holding a line goal (only Medium and Hard have building goals).
EASY_LINE_DATASET = json.dumps(
    {
        "source": {"kind": "json", "path": "line.json"},
        "goals": [
            {
                "kind": "build_line",
                "id": "LINE",
                "split": "easy_train",
                "instruction": "Build a line of 2 stones.",
                "paraphrases": [],
                "block": "STONE",
                "size": 2,
                "diagonal": False,
            }
        ],
    }
)
#: One goal twice in a split.
REPEATED_GOAL_DATASET = json.dumps(
    {**json.loads(EASY_ONLY_DATASET), "goals": json.loads(EASY_ONLY_DATASET)["goals"] * 2}
)
BROKEN_STEP = "{{ instruction }\n"
UNDEFINED_STEP = "{{ no_such_variable }}\n"

MISTAKES: dict[str, Mistake] = {
    # model specs
    "unknown backend": Mistake([*EVAL, "--model", "hff:x"], "did you mean hf"),
    "spec without backend": Mistake([*EVAL, "--model", "gpt4"], "no backend"),
    "spec without model": Mistake([*EVAL, "--model", "openai:"], "names no model"),
    "unknown mock script": Mistake([*EVAL, "--model", "mock:dance:A"], "unknown mock script"),
    "empty mock list": Mistake([*EVAL, "--model", "mock:list:"], "lists no answers"),
    "missing mock file": Mistake([*EVAL, "--model", "mock:file:{tmp}/nope.json"], "nope.json"),
    "unknown backend option": Mistake([*EVAL, "--backend-option", "thread=2"], "thread"),
    "model that does not answer": Mistake([*EVAL, "--model", "mock:error:down"], "down"),
    "skills with a model that does not answer": Mistake(
        [*EVAL, "--agent", "skills", "--model", "mock:error:down"], "down"
    ),
    "skills without a backend": Mistake(
        [*EVAL, "--agent", "skills", "--model", "gpt4"], "no backend"
    ),
    "skills with no step budget": Mistake(
        [*EVAL, "--agent", "skills", "--skill-steps", "0"], "skill"
    ),
    "skill demos for an agent that takes none": Mistake(
        [*EVAL, "--skill-demos", "2"], "skill_demos are shown to the skills agent"
    ),
    "more skill demos than the training split gives": Mistake(
        [*EVAL, "--agent", "skills", "--skill-demos", "60"], "--skill-demos 60: the easy training"
    ),
    "a skills grammar for a backend that cannot constrain": Mistake(
        [
            *EVAL,
            "--agent",
            "skills",
            "--choice",
            "guided",
            "--model",
            "openai:m@http://127.0.0.1:9/v1",
            "--backend-option",
            "structured_choice=false",
        ],
        "cannot constrain decoding",
    ),
    "dead server": Mistake(
        [*EVAL, "--model", "openai:m@http://127.0.0.1:9/v1"], "connection refused"
    ),
    "unknown protocol": Mistake([*EVAL, "--protocol", "papers"], "papers"),
    "unknown success rule": Mistake([*EVAL, "--success-rule", "lenient"], "lenient"),
    "protocol overrides set by hand": config_file("run.toml", 'protocol_overrides = ["x"]\n'),
    "report under an unknown success rule": Mistake(
        ["report", "{tmp}/nope", "--success-rule", "lenient"], "lenient"
    ),
    "choice rule the backend lacks": Mistake(
        [*EVAL, "--model", "openai:m@http://127.0.0.1:9/v1", "--choice", "loglik"], "loglik"
    ),
    "unknown choice rule": Mistake([*EVAL, "--choice", "best"], "invalid choice"),
    "unknown choice scoring": Mistake(
        [*EVAL, "--choice", "loglik", "--choice-scoring", "median"], "invalid choice"
    ),
    "unknown choice scoring in a file": with_message(
        config_file("run.toml", 'choice = "loglik"\nchoice_scoring = "median"\n'),
        "choice_scoring",
    ),
    "choice scoring without loglik": Mistake(
        [*EVAL, "--choice", "guided", "--choice-scoring", "bytes"], "scores --choice loglik only"
    ),
    "scoring rule on a server without prompt log-probabilities": Mistake(
        [*EVAL, "--model", "openai:m@http://127.0.0.1:9/v1", *LOGLIK_PMI],
        "log-probabilities",
    ),
    "lettered actions for an agent without a step message": Mistake(
        [*EVAL, "--agent", "skills", "--choice", "loglik", "--choice-scoring", "letters"],
        "letters works with: zero-shot, few-shot",
    ),
    "the hf choice_scoring option that became a setting": Mistake(
        [*EVAL, "--model", "hf:smollm2-135m", "--backend-option", "choice_scoring=mean"],
        "no option 'choice_scoring'",
    ),
    "unknown agent": Mistake([*EVAL, "--agent", "genius"], "genius"),
    "few-shot without demonstrations": Mistake([*EVAL, "--agent", "few-shot"], "demos"),
    # numbers out of range
    "batch size 0": Mistake([*EVAL, "--batch-size", "0"], "batch_size"),
    "max steps 0": Mistake([*EVAL, "--max-steps", "0"], "max_steps"),
    "limit 0": Mistake([*EVAL, "--limit", "0"], "limit"),
    "episodes per instruction 0": Mistake(
        [*EVAL, "--episodes-per-instruction", "0"], "episodes_per_instruction"
    ),
    "negative history": Mistake([*EVAL, "--history-length", "-1"], "history_length"),
    "negative temperature": Mistake([*EVAL, "--temperature", "-1"], "temperature"),
    "top p above 1": Mistake([*EVAL, "--top-p", "2"], "top_p"),
    "max tokens 0": Mistake([*EVAL, "--max-tokens", "0"], "max_tokens"),
    "failure limit 0": Mistake(
        [*EVAL, "--max-consecutive-failures", "0"], "max_consecutive_failures"
    ),
    "not a number": Mistake([*EVAL, "--max-steps", "many"], "invalid int value"),
    # names
    "unknown variant": Mistake([*EVAL, "--variant", "huge"], "invalid choice"),
    "unknown category": Mistake([*EVAL, "--categories", "combo", "hard"], "hard"),
    "unknown difficulty": Mistake([*EVAL, "--difficulty", "medum"], "'medum'"),
    "category of another difficulty": Mistake(
        [*EVAL, "--difficulty", "medium"], "'combo' is not one of medium's"
    ),
    "dataset without the difficulty": Mistake(
        [*EVAL, "--difficulty", "medium", "--categories", "train", "--dataset", "{tmp}/e.json"],
        "has no medium_train goals",
        files={"e.json": EASY_ONLY_DATASET},
    ),
    "split the official data lacks": Mistake(
        [*EVAL, "--difficulty", "hard", "--categories", "paraphrased", "--dataset", "{tmp}/e.json"],
        "has no hard_test_paraphrased goals",
        files={"e.json": EASY_ONLY_DATASET},
    ),
    "unknown renderer": Mistake([*EVAL, "--renderer", "pixels"], "pixels"),
    "unknown fallback action": Mistake([*EVAL, "--fallback-action", "JUMP"], "JUMP"),
    "fallback action of the other variant": Mistake(
        [*EVAL, "--fallback-action", "DESCEND"], "DESCEND"
    ),
    "unknown flag": Mistake([*EVAL, "--max-step", "3", "--frobnicate"], "frobnicate"),
    "backend option without value": Mistake([*EVAL, "--backend-option", "threads"], "KEY=VALUE"),
    # files the run reads
    "missing templates dir": Mistake([*EVAL, "--templates-dir", "{tmp}/nope"], "nope"),
    "template that does not parse": Mistake(
        [*EVAL, "--templates-dir", "{tmp}/tpl"], "step", files={"tpl/step.j2": BROKEN_STEP}
    ),
    "template with an undefined variable": Mistake(
        [*EVAL, "--templates-dir", "{tmp}/tpl"],
        "no_such_variable",
        files={"tpl/step.j2": UNDEFINED_STEP},
    ),
    "missing plans file": Mistake([*EVAL, "--plans", "{tmp}/plans.json"], "plans.json"),
    "plans file not JSON": Mistake(
        [*EVAL, "--plans", "{tmp}/plans.json"], "not valid JSON", files={"plans.json": "{"}
    ),
    "plans file a list": Mistake(
        [*EVAL, "--plans", "{tmp}/plans.json"], "one JSON object", files={"plans.json": "[]"}
    ),
    "plans file with a number": Mistake(
        [*EVAL, "--plans", "{tmp}/plans.json"],
        "is not a string",
        files={"plans.json": '{"Collect wood.": 3}'},
    ),
    "missing dataset": Mistake([*EVAL, "--dataset", "{tmp}/nope.json"], "does not exist"),
    "dataset of another kind": Mistake(
        [*EVAL, "--dataset", "{tmp}/data.txt"], "not a directory", files={"data.txt": "x"}
    ),
    "dataset JSON that is not one": Mistake(
        [*EVAL, "--dataset", "{tmp}/data.json"], "data.json", files={"data.json": "{"}
    ),
    "dataset with a goal kind its difficulty has not": Mistake(
        [*EVAL, "--dataset", "{tmp}/line.json"],
        "goal 'LINE' in easy_train is a build_line goal; easy goals are achievements",
        files={"line.json": EASY_LINE_DATASET},
    ),
    "dataset with a goal twice in a split": Mistake(
        [*EVAL, "--dataset", "{tmp}/twice.json"],
        "goal 'PLACE_TABLE' appears twice in easy_train",
        files={"twice.json": REPEATED_GOAL_DATASET},
    ),
    # output directories
    "output dir is a file": Mistake(
        [*EVAL, "--output-dir", "{tmp}/taken"], "is a file", files={"taken": "x"}
    ),
    "output dir under a file": Mistake(
        [*EVAL, "--output-dir", "{tmp}/taken/run"], "which is a file", files={"taken": "x"}
    ),
    "results file that is a directory": Mistake(
        EVAL, "results.json is not a readable and writable file", files={"run/results.json/": ""}
    ),
    "episodes without results": Mistake(
        EVAL, "no results.json", files={"run/episodes.jsonl": '{"episode_id": "x"}\n'}
    ),
    "results of another version": Mistake(
        EVAL, "results.json", files={"run/results.json": '{"config": {}}'}
    ),
    # config files
    "missing config": Mistake([*EVAL, "--config", "{tmp}/run.toml"], "run.toml"),
    "config of unknown kind": config_file("run.ini", "x=1"),
    "config that does not parse": config_file("run.toml", "max_steps = = 3"),
    "config that is a list": config_file("run.yaml", "- 1\n- 2\n"),
    "generation a string": config_file("run.toml", 'generation = "fast"\n'),
    "generation a number": config_file("run.yaml", "generation: 5\n"),
    "backend options a list plus a flag": config_file(
        "run.toml", 'backend_options = ["a"]\n', "--backend-option", "threads=1"
    ),
    "misspelt config key": config_file("run.toml", "max_step = 3\n"),
    "unknown generation key": config_file("run.toml", "[generation]\ntemprature = 0.5\n"),
    "config value of the wrong type": config_file("run.toml", 'history_length = "many"\n'),
    # report
    "report of a missing directory": Mistake(["report", "{tmp}/nope"], "does not exist"),
    "report of a directory without results": Mistake(
        ["report", "{tmp}/run"], "not a run directory", files={"run/": ""}
    ),
    # card, leaderboard
    "card of a missing directory": Mistake(["card", "{tmp}/nope"], "does not exist"),
    "card of a directory without results": Mistake(
        ["card", "{tmp}/run"], "not a run directory", files={"run/": ""}
    ),
    "verify a file that is not a card": Mistake(
        ["card", "--verify", "{tmp}/card.json", "{tmp}/run"],
        "not a results card",
        files={"card.json": "[1, 2]", "run/": ""},
    ),
    # Refused before the replay: a run with no records at all would fail it otherwise.
    "card into a directory that does not exist": Mistake(
        ["card", "{tmp}/run", "--out", "{tmp}/nowhere"],
        "not a directory to write the card into",
        files={"run/": ""},
    ),
    "card with zero do-nothing worlds": Mistake(
        ["card", "{tmp}/run", "--goal-flags", "--do-nothing-worlds", "0"], "at least 1"
    ),
    "leaderboard of a card that is not JSON": Mistake(
        ["leaderboard", "{tmp}/card.json", "--out", "{tmp}/site"],
        "not JSON",
        files={"card.json": "{card"},
    ),
    "leaderboard of a missing card": Mistake(
        ["leaderboard", "{tmp}/card.json", "--out", "{tmp}/site"], "cannot read card"
    ),
    # plan
    "plan output is a directory": Mistake(
        [*PLAN, "--output", "{tmp}/out"], "is a directory", files={"out/": ""}
    ),
    "plan output under a file": Mistake(
        [*PLAN, "--output", "{tmp}/taken/plans.json"], "taken is a file", files={"taken": "x"}
    ),
    "plan of an unknown category": Mistake([*PLAN, "--categories", "easy_hard"], "easy_hard"),
    "plan of another difficulty's category": Mistake(
        [*PLAN, "--difficulty", "hard", "--categories", "one"], "not one of hard's"
    ),
    "plan of splits of two difficulties": Mistake(
        [*PLAN, "--categories", "easy_train", "medium_train"], "one difficulty at a time"
    ),
    "plan requests per call 0": Mistake([*PLAN, "--requests-per-call", "0"], "requests_per_call"),
    "plan limit 0": Mistake([*PLAN, "--limit", "0"], "limit"),
    "plan config with generation a string": Mistake(
        [*PLAN, "--config", "{tmp}/plan.toml"],
        "generation",
        files={"plan.toml": 'generation = "x"'},
    ),
    "plan without output": Mistake(["plan", "--model", "mock:", "--no-progress"], "output"),
    # image observations
    "images for a backend that takes none": Mistake(
        [*EVAL, "--observation", "image"], "the mock backend takes no images"
    ),
    "frame history below 0": Mistake(
        [*EVAL, "--observation", "both", "--frame-history", "-1"], "frame_history"
    ),
    "frame history of a text observation": Mistake(
        [*EVAL, "--frame-history", "2"], "frame_history counts the frames"
    ),
    "images for the expert": Mistake(
        [*EVAL, "--agent", "expert", "--observation", "image"], "the expert agent shows"
    ),
    "images scored by loglik": Mistake(
        [*EVAL, "--observation", "image", "--choice", "loglik"], "scores text prompts only"
    ),
}

for name, fragment in {
    "config of unknown kind": "must end in .toml",
    "config that does not parse": "does not parse",
    "config that is a list": "table of settings",
    "generation a string": "generation",
    "generation a number": "generation",
    "backend options a list plus a flag": "backend_options",
    "misspelt config key": "did you mean 'max_steps'",
    "unknown generation key": "temprature",
    "config value of the wrong type": "history_length",
    "protocol overrides set by hand": "protocol_overrides",
}.items():
    MISTAKES[name].message = fragment


def snapshot(root: Path) -> dict[str, bytes | None]:
    found: dict[str, bytes | None] = {}
    for path in sorted(root.rglob("*")):
        key = str(path.relative_to(root))
        found[key] = path.read_bytes() if path.is_file() else None
    return found


def invoke(argv: list[str], capsys: Any) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = int(exit_.code or 0)
    return code, capsys.readouterr().err


def lay_out(tmp: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = tmp / name
        if name.endswith("/"):
            path.mkdir(parents=True, exist_ok=True)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_table_is_large() -> None:
    assert len(MISTAKES) >= 40


@pytest.mark.parametrize("name", list(MISTAKES))
def test_a_mistake_is_one_line_and_changes_nothing(name: str, tmp_path: Path, capsys: Any) -> None:
    mistake = MISTAKES[name]
    lay_out(tmp_path, mistake.files)
    before = snapshot(tmp_path)
    argv = [arg.replace("{tmp}", str(tmp_path)) for arg in mistake.argv]

    code, err = invoke(argv, capsys)

    assert code != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("craftext-llm"), lines[0]
    assert mistake.message in lines[0], lines[0]
    assert "Traceback" not in err
    assert snapshot(tmp_path) == before


@contextlib.contextmanager
def _real_user_nobody() -> Iterator[None]:
    """Root may write to read-only directories. The output-directory check asks access(2), which
    judges by the real user: as root (CI), make that `nobody` meanwhile, keeping root as the
    effective user so the process can still read its own installation."""
    if os.geteuid() != 0:
        yield
        return
    os.setresuid(65534, 0, 0)
    try:
        yield
    finally:
        os.setresuid(0, 0, 0)


def test_a_read_only_output_directory_is_one_line(tmp_path: Path, capsys: Any) -> None:
    # Under /tmp itself, not the per-user pytest folder `nobody` cannot enter.
    locked = Path(tempfile.mkdtemp(prefix="craftext-locked-"))
    locked.chmod(0o555)
    try:
        argv = [a.replace("{tmp}/run", str(locked / "run")) for a in EVAL]
        with _real_user_nobody():
            code, err = invoke(argv, capsys)
    finally:
        locked.chmod(0o755)
    assert code != 0 and "not writable" in err
    assert not (locked / "run").exists()
    shutil.rmtree(locked)
