"""The skills catalogue's grammar under vLLM's structured outputs (`--choice guided` for the
skills agent), with SmolLM2 on CPU in the vLLM environment: every answer to a real skills
request is a catalogue skill."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from test_skill_grammar import INSTRUCTIONS, guided_prompt
from vllm_serve import START_TIMEOUT_S, VLLM_VENV, vllm_environment, vllm_environment_ready

from env import Variant
from llm_agents.agents.skills.catalogue import read_skill, skill_offer
from llm_agents.agents.strategies.skills import SkillsAgent
from llm_agents.backends.embedded import embedded_model_dir

pytestmark = [pytest.mark.vllm, pytest.mark.slow]

# Runs inside the vLLM environment (the engine in this process, as tests/test_backend_vllm.py).
SCRIPT = """
import json, sys
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig

def main():
    model_dir, in_path, out_path = sys.argv[1:4]
    request = json.load(open(in_path))
    conversations = [[ChatMessage(**m) for m in c] for c in request["conversations"]]
    grammar = ChoiceSet(options=tuple(request["grammar"]), rule="guided")
    with get_model("vllm:" + model_dir, GenerateConfig(max_tokens=24), enforce_eager=True,
                   max_model_len=4096, dtype="float32", max_num_seqs=8,
                   engine_args={"distributed_executor_backend": "uni"}) as model:
        outputs = model.generate(conversations, grammar)
    json.dump([o.model_dump() for o in outputs], open(out_path, "w"))

if __name__ == "__main__":
    main()
"""


def test_vllm_structured_outputs_hold_every_answer_to_the_catalogue(tmp_path: Path) -> None:
    if not vllm_environment_ready():
        pytest.skip(f"no vLLM environment at {VLLM_VENV}; build it with scripts/setup_vllm_cpu.sh")
    agent = SkillsAgent(Variant.CLASSIC, difficulty="medium", choice_rule="guided")
    prompts = [guided_prompt(agent, text) for text in INSTRUCTIONS]
    grammar = prompts[0].choices
    assert grammar is not None
    (tmp_path / "run.py").write_text(SCRIPT)
    request = {
        "conversations": [[m.model_dump() for m in p.messages] for p in prompts],
        "grammar": list(grammar.options),
    }
    (tmp_path / "request.json").write_text(json.dumps(request))
    run = subprocess.run(
        [str(VLLM_VENV / "bin" / "python"), "run.py", str(embedded_model_dir()), "request.json",
         "out.json"],
        cwd=tmp_path,
        env=vllm_environment() | {"VLLM_ENABLE_V1_MULTIPROCESSING": "0"},
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S + 300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-4000:]
    outputs = json.loads((tmp_path / "out.json").read_text())
    offer = skill_offer(Variant.CLASSIC, "medium")
    assert len(outputs) == len(prompts)
    for output in outputs:
        assert output["text"] in grammar.options and output["finish_reason"] == "choice"
        assert read_skill(output["text"], offer).text == output["text"]
