"""`--structured-output` against real vLLM on CPU: the offline engine (the vllm backend) and
`vllm serve` through the openai backend's `response_format`, both running SmolLM2, a model far
too small to read goals right, whose every answer must still be a reading that parses."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from vllm_serve import (
    START_TIMEOUT_S,
    VLLM_VENV,
    ServerDidNotStart,
    vllm_environment,
    vllm_environment_ready,
    vllm_serve,
)

from env import Variant
from llm_agents.agents.answer_schemas import action_schema, answered_action, reading_schema
from llm_agents.agents.answers.actions import action_names
from llm_agents.agents.grounding import grounding_messages, parse_grounding
from llm_agents.backends.base import ChatMessage, GenerateConfig
from llm_agents.backends.embedded import embedded_model_dir
from llm_agents.backends.openai import OpenAIModel

pytestmark = [pytest.mark.vllm, pytest.mark.slow]

CLASSIC = Variant.CLASSIC
TEXTS = (
    "Collect wood.",
    "Make a table but do not collect saplings.",
    "Drink some water, then eat a cow.",
)
SERVED_NAME = "smollm2"


@pytest.fixture(scope="module", autouse=True)
def _vllm_built() -> None:
    if not vllm_environment_ready():
        pytest.skip(f"no vLLM environment at {VLLM_VENV}; build it with scripts/setup_vllm_cpu.sh")


ENGINE_SCRIPT = """
import json, sys
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, GenerateConfig, OutputSchema

def main():
    model_dir, in_path, out_path = sys.argv[1:4]
    request = json.load(open(in_path))
    reading = OutputSchema.model_validate(request["reading"])
    action = OutputSchema.model_validate(request["action"])
    with get_model("vllm:" + model_dir, GenerateConfig(max_tokens=96), enforce_eager=True,
                   max_model_len=4096, dtype="float32", max_num_seqs=8,
                   engine_args={"distributed_executor_backend": "uni"}) as model:
        model.check_schema(reading)
        conversations = [[ChatMessage(**m) for m in c] for c in request["conversations"]]
        readings = model.generate(conversations, schema=reading)
        actions = model.generate([[ChatMessage(role="user", content="Which action now?")]],
                                 schema=action)
        refused = None
        try:
            model.check_schema(OutputSchema.of("broken", {"type": "object", "required": 5}))
        except Exception as err:
            refused = f"{type(err).__name__}: {err}"
    with open(out_path, "w") as f:
        json.dump({"readings": [o.model_dump() for o in readings],
                   "actions": [o.model_dump() for o in actions], "refused": refused}, f)

if __name__ == "__main__":
    main()
"""


def requests() -> list[list[dict[str, str]]]:
    return [
        [message.model_dump(exclude={"images"}) for message in grounding_messages(text, CLASSIC)]
        for text in TEXTS
    ]


def assert_every_reading_parses(texts: list[str]) -> None:
    for text in texts:
        grounding = parse_grounding(text, CLASSIC)
        assert grounding.outcome == "valid" and grounding.stage == "json", text


def test_the_vllm_engine_holds_readings_and_actions_to_their_schemas(tmp_path: Path) -> None:
    script = tmp_path / "engine.py"
    script.write_text(ENGINE_SCRIPT)
    request = tmp_path / "request.json"
    request.write_text(
        json.dumps(
            {
                "reading": reading_schema(CLASSIC, "easy").model_dump(),
                "action": action_schema(CLASSIC).model_dump(),
                "conversations": requests(),
            }
        )
    )
    out = tmp_path / "out.json"
    run = subprocess.run(
        [str(VLLM_VENV / "bin" / "python"), str(script), str(embedded_model_dir()), str(request),
         str(out)],
        cwd=tmp_path,
        env=vllm_environment() | {"VLLM_ENABLE_V1_MULTIPROCESSING": "0"},
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S + 900,  # an engine start and three answers on 2 busy cores
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-4000:]
    result = json.loads(out.read_text())
    readings = result["readings"]
    assert len(readings) == len(TEXTS) and all(o["finish_reason"] == "stop" for o in readings)
    assert_every_reading_parses([o["text"] for o in readings])
    [chosen] = result["actions"]
    assert answered_action(chosen["text"]) in action_names(CLASSIC)
    assert result["refused"] and "vllm backend cannot take the broken" in result["refused"]


@pytest.fixture(scope="module")
def vllm_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log_path = tmp_path_factory.mktemp("vllm-serve") / "server.log"
    try:
        with vllm_serve(
            embedded_model_dir(),
            log_path,
            served_name=SERVED_NAME,
            max_model_len=4096,
            max_num_seqs=4,
        ) as url:
            yield url
    except ServerDidNotStart as err:
        pytest.fail(str(err))


def test_the_openai_backend_gets_readings_that_parse_from_vllm_serve(vllm_server: str) -> None:
    config = GenerateConfig(max_tokens=96, timeout_s=300, max_retries=1, max_concurrency=3)
    model = OpenAIModel(SERVED_NAME, config, base_url=vllm_server)
    schema = reading_schema(CLASSIC, "easy")
    model.check_schema(schema)  # the server takes response_format
    conversations = [[ChatMessage(**m) for m in c] for c in requests()]
    outputs = model.generate(conversations, schema=schema)
    assert all(o.error is None and o.finish_reason == "stop" for o in outputs), outputs
    assert_every_reading_parses([o.text for o in outputs])
    [chosen] = model.generate(
        [[ChatMessage(role="user", content="Which action now?")]], schema=action_schema(CLASSIC)
    )
    assert answered_action(chosen.text) in action_names(CLASSIC)
