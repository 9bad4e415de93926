"""The vllm backend and `vllm serve`, really running SmolLM2 on CPU in the vLLM environment.

vLLM lives in its own environment (built by scripts/setup_vllm_cpu.sh), so each test drives it in
a subprocess with that environment's interpreter and checks what comes back.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, get_args

import pytest
from vllm_serve import (
    REPO,
    START_TIMEOUT_S,
    VLLM_VENV,
    ServerDidNotStart,
    vllm_environment,
    vllm_environment_ready,
    vllm_serve,
)

from env.errors import UserError
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, ChoiceScoring, ChoiceSet, GenerateConfig
from llm_agents.backends.embedded import embedded_model_dir
from llm_agents.backends.openai import OpenAIModel

VLLM_PYTHON = VLLM_VENV / "bin" / "python"
ACTIONS = ["NOOP", "MOVE_LEFT", "MOVE_RIGHT", "DO"]
SERVED_NAME = "smollm2"

pytestmark = [pytest.mark.vllm, pytest.mark.slow]


@pytest.fixture(scope="module", autouse=True)
def _vllm_built() -> None:
    """`make test` builds the environment beside the tests: wait for that build, then skip
    without an environment (a failure under CI, by conftest's rule)."""
    if not vllm_environment_ready():
        pytest.skip(f"no vLLM environment at {VLLM_VENV}; build it with scripts/setup_vllm_cpu.sh")


# Runs inside the vLLM environment; the spawn start method re-imports this file in the engine's children,
# hence the __main__ guard. One engine serves both tests below: an engine start is a minute or
# more on two busy cores. Its window (4096 tokens) is the loglik test's; the engine test's
# over-long prompt is longer than it.
ENGINE_SCRIPT = """
import json, sys
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, ChoiceSet, GenerateConfig, scored_choices

def conv(text):
    return [ChatMessage(role="system", content="You play a survival game."),
            ChatMessage(role="user", content=text)]

def engine_checks(model, actions):
    model.config = GenerateConfig(max_tokens=12, temperature=0.0)
    free = model.generate([
        conv("Say hello."),
        conv("Name one tool you can craft from wood, please, in a few words."),
        conv("Say hello."),
        conv("Write a very long story about a tree. " * 3),
    ])
    choice = model.generate([conv("A tree is to your left. Which action?"),
                             conv("Nothing is around. Which action?")],
                            choices=ChoiceSet(options=tuple(actions), rule="guided"))
    too_long = model.generate([conv("Say hi."), conv("wood " * 5000)])
    return {"free": [o.model_dump() for o in free],
            "choice": [o.model_dump() for o in choice],
            "too_long": [o.model_dump() for o in too_long],
            "info": model.info()}

def loglik_checks(model, request):
    model.config = GenerateConfig(max_tokens=4)
    conversations = [[ChatMessage(**m) for m in c] for c in request["conversations"]]
    options = tuple(request["options"])
    # One scoring pass gives every rule (vLLM on CPU pays per option request).
    prompts = [model._prompt_ids(c) for c in conversations]
    candidates = model._candidate_ids(options)
    raw = model._log_likelihoods(prompts, candidates)
    scores = {}
    for rule in request["rules"]:
        choices = ChoiceSet(options=options, rule="loglik", scoring=rule)
        free = model._content_free_rows(conversations, choices, candidates)
        scores[rule] = scored_choices(choices, candidates, raw, free)
    # The whole path of an answer, the content-free prompt's cached scores included.
    picked = ChoiceSet(options=options, rule="loglik", scoring=request["answer_rule"])
    outputs = model.generate(conversations, picked)
    # Prompts cut to end on a KV-cache block boundary, and two tokens before one: there
    # the prefix cache reaches into the options, which must then be scored without it.
    block = model.llm.llm_engine.vllm_config.cache_config.block_size
    prompt = prompts[0]
    cut = block * (len(prompt) // block)
    cut_prompts = [prompt[:cut], prompt[: cut - 2]]
    cut_scores = model._log_likelihoods(cut_prompts, model._candidate_ids(request["cut_options"]))
    # Lettered actions (`letters`): the labels' scores, and the labels the whole path picks.
    lettered = [[ChatMessage(**m) for m in c] for c in request["letters"]["conversations"]]
    labels = ChoiceSet(options=tuple(request["letters"]["options"]), rule="loglik",
                       scoring="letters")
    letters = {"scores": model.choice_scores(lettered, labels),
               "outputs": [o.model_dump() for o in model.generate(lettered, labels)]}
    return {"scores": scores, "outputs": [o.model_dump() for o in outputs],
            "cut_prompts": cut_prompts, "cut_scores": cut_scores, "letters": letters}

def main():
    import llm_agents
    model_dir, in_path, out_path = sys.argv[1:4]
    request = json.load(open(in_path))
    # The engine runs in this process (VLLM_ENABLE_V1_MULTIPROCESSING=0 and the "uni"
    # executor): the same engine, without two more processes importing vLLM (about 20 s).
    with get_model("vllm:" + model_dir, GenerateConfig(), enforce_eager=True,
                   max_model_len=4096, dtype="float32", max_num_seqs=32,
                   engine_args={"distributed_executor_backend": "uni"}) as model:
        # The loglik checks first: the engine test's prompts must not warm its prefix cache.
        loglik = loglik_checks(model, request["loglik"])
        engine = engine_checks(model, request["actions"])
    with open(out_path, "w") as f:
        json.dump({"engine": engine, "loglik": loglik, "project": llm_agents.__file__}, f)

if __name__ == "__main__":
    main()
"""


@pytest.fixture(scope="module")
def model_dir() -> Path:
    return embedded_model_dir()


SCORED_OPTIONS = ("UP", "DO", "PLACE_STONE", "PLACE_FURNACE", "MAKE_WOOD_SWORD", "MAKE_IRON_SWORD")


@pytest.fixture(scope="module")
def loglik_request(classic_env: Any) -> dict[str, Any]:
    """Real agent conversations and the options and rules to score them under."""
    conversations, actions = real_agent_conversations(classic_env)
    lettered, labels = real_agent_conversations(classic_env, "letters")
    # vLLM on CPU scores each option as a request of its own, the whole prompt included: six
    # names (one token or several, sharing prefixes, each conversation's favourite among them)
    # prove the agreement in a quarter of the time all 17 took.
    return {
        "conversations": [[m.model_dump() for m in c] for c in conversations],
        "options": [name for name in actions if name in SCORED_OPTIONS],
        # `letters` scores labels of a lettered list, not names: asked below, of its own prompts.
        "rules": [rule for rule in get_args(ChoiceScoring) if rule != "letters"],
        "answer_rule": "pmi",
        # A cut prompt's every option misses the cache and is computed again in full: a name of
        # one token and one of several cover both paths at a third of the six names' cost.
        "cut_options": ["DO", "MAKE_IRON_SWORD"],
        # Four of the 17 labels: each is a request of its own there too.
        "letters": {
            "conversations": [[m.model_dump() for m in c] for c in lettered],
            "options": labels[:4],
        },
    }


@pytest.fixture(scope="module")
def engine_results(
    model_dir: Path, loglik_request: dict[str, Any], tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    """What one offline engine answered to both tests' requests (ENGINE_SCRIPT)."""
    folder = tmp_path_factory.mktemp("vllm-engine")
    script = folder / "run_engine.py"
    script.write_text(ENGINE_SCRIPT)
    request = folder / "request.json"
    request.write_text(json.dumps({"actions": ACTIONS, "loglik": loglik_request}))
    out = folder / "outputs.json"
    run = subprocess.run(
        [str(VLLM_PYTHON), str(script), str(model_dir), str(request), str(out)],
        cwd=folder,
        env=vllm_environment() | {"VLLM_ENABLE_V1_MULTIPROCESSING": "0"},
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S + 420,
    )
    assert run.returncode == 0, run.stderr[-4000:]
    result: dict[str, Any] = json.loads(out.read_text())
    return result


def test_offline_engine_generates_free_text_and_constrained_choices(
    engine_results: dict[str, Any],
) -> None:
    # The environment is shared by checkouts, its editable install that of whichever set it up
    # last: the engine ran this checkout's code all the same (vllm_environment's PYTHONPATH).
    assert Path(engine_results["project"]).resolve().is_relative_to(REPO)
    result = engine_results["engine"]

    free = result["free"]
    assert all(o["finish_reason"] in ("stop", "length") and o["text"].strip() for o in free)
    assert all(0 < o["completion_tokens"] <= 12 for o in free)
    # Outputs come back in request order: prompt lengths follow the conversations'.
    tokens = [o["prompt_tokens"] for o in free]
    assert tokens[0] == tokens[2] < tokens[1] < tokens[3]
    assert free[0]["text"] == free[2]["text"]  # greedy decoding is deterministic
    assert free[3]["finish_reason"] == "length" and free[3]["completion_tokens"] == 12
    # vLLM says how much of each prompt its prefix cache served.
    assert all(0 <= o["computed_prompt_tokens"] <= o["prompt_tokens"] for o in free)

    choice = result["choice"]
    assert all(o["text"] in ACTIONS and o["finish_reason"] == "choice" for o in choice)

    fine, bad = result["too_long"]
    assert fine["finish_reason"] in ("stop", "length") and fine["text"].strip()
    assert bad["finish_reason"] == "error" and "vLLM failed" in bad["error"]
    assert result["info"]["backend"] == "vllm" and result["info"]["vllm"]


def real_agent_conversations(
    classic_env: Any, scoring: ChoiceScoring = "pmi"
) -> tuple[list[list[ChatMessage]], list[str]]:
    """The agent's messages over real classic episodes: first steps, and steps with history;
    and the options its answers are picked among (under `letters`, the labels)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from env import ACHIEVEMENT_IDS, NUM_ACHIEVEMENTS, episode_key, make_task
    from llm_agents.agents.answers.actions import action_names
    from llm_agents.agents.strategies.zero_shot import ZeroShotAgent
    from llm_agents.agents.types import EpisodeStart
    from textualizer import observe

    agent = ZeroShotAgent("classic", choice_rule="loglik", choice_scoring=scoring)
    assert agent.choices is not None
    names = action_names("classic")
    required = np.zeros(NUM_ACHIEVEMENTS, dtype=bool)
    required[ACHIEVEMENT_IDS["COLLECT_WOOD"]] = True
    task = make_task(required, np.zeros_like(required))
    conversations = []
    for slot, actions in enumerate([[], [5, 2, 2], [1, 3]]):
        state = classic_env.reset(jnp.asarray(episode_key(0, "loglik", 0, slot)), task)
        agent.start_episode(slot, EpisodeStart("Collect some wood.", episode=f"loglik/{slot}"))
        for action in [*actions, None]:
            observation = observe(jax.tree.map(np.asarray, state.game), "classic")
            messages, _ = agent.build_messages(slot, observation)
            if action is None:
                break
            agent._episodes[slot].pending = (names[action], observation)
            agent._episodes[slot].step += 1
            state, _ = classic_env.step(state, jnp.int32(action))
        conversations.append(messages)
    return conversations, list(agent.choices.options)


def test_hf_and_vllm_agree_under_every_loglik_rule_on_real_prompts(
    loglik_request: dict[str, Any], engine_results: dict[str, Any]
) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("transformers")
    from llm_agents.backends.hf import HFModel

    conversations = [[ChatMessage(**m) for m in c] for c in loglik_request["conversations"]]
    options, rules = loglik_request["options"], loglik_request["rules"]
    result = engine_results["loglik"]

    hf = HFModel("smollm2-135m", GenerateConfig(max_tokens=4), dtype="float32")
    hf_scores = {
        rule: hf.choice_scores(
            conversations, ChoiceSet(options=tuple(options), rule="loglik", scoring=rule)
        )
        for rule in rules
    }
    assert set(result["scores"]) == set(rules)
    for rule in rules:
        worst = max(
            abs(a - b)
            for hf_row, vllm_row in zip(hf_scores[rule], result["scores"][rule], strict=True)
            for a, b in zip(hf_row, vllm_row, strict=True)
        )
        print(f"hf vs vllm loglik scores ({rule}), float32: largest difference {worst:.2e}")
        assert worst < 0.01, rule
    # The rules really rank differently, so agreeing under each is not one check four times.
    best = {
        rule: [max(range(len(options)), key=row.__getitem__) for row in hf_scores[rule]]
        for rule in rules
    }
    assert len({tuple(picks) for picks in best.values()}) > 1
    cut_candidates = hf._candidate_ids(loglik_request["cut_options"])
    assert min(map(len, cut_candidates)) == 1 < max(map(len, cut_candidates))
    hf_cut = hf._option_logliks(result["cut_prompts"], cut_candidates)
    cut_worst = max(
        abs(a - b)
        for hf_row, vllm_row in zip(hf_cut, result["cut_scores"], strict=True)
        for hf_score, vllm_score in zip(hf_row, vllm_row, strict=True)
        for a, b in zip(hf_score, vllm_score, strict=True)
    )
    assert cut_worst < 0.01
    # `letters`: the labels' next-token scores (hf's one pass over the prompt) agree, and so
    # does the label each backend picks.
    lettered = result["letters"]
    letter_conversations = [
        [ChatMessage(**m) for m in c] for c in loglik_request["letters"]["conversations"]
    ]
    labels = ChoiceSet(
        options=tuple(loglik_request["letters"]["options"]), rule="loglik", scoring="letters"
    )
    hf_letters = hf.choice_scores(letter_conversations, labels)
    letters_worst = max(
        abs(a - b)
        for hf_row, vllm_row in zip(hf_letters, lettered["scores"], strict=True)
        for a, b in zip(hf_row, vllm_row, strict=True)
    )
    print(f"hf vs vllm loglik scores (letters), float32: largest difference {letters_worst:.2e}")
    assert letters_worst < 0.01
    hf_picks = [o.text for o in hf.generate(letter_conversations, labels)]
    assert hf_picks == [o["text"] for o in lettered["outputs"]]
    assert all(o["finish_reason"] == "choice" for o in lettered["outputs"])
    # hf's answers are its scores' best options (its own tests check that `generate` picks
    # them), so vLLM's answers are compared with those instead of scoring everything again.
    vllm_outputs = result["outputs"]
    assert [o["text"] for o in vllm_outputs] == [options[i] for i in best["pmi"]]
    prompt_tokens = [len(ids) for ids in hf._prompt_ids(conversations)]
    assert [o["prompt_tokens"] for o in vllm_outputs] == prompt_tokens
    assert all(o["finish_reason"] == "choice" for o in vllm_outputs)
    # Real prompts of different situations: the models do not pick one answer everywhere.
    assert len({max(range(len(options)), key=row.__getitem__) for row in hf_scores["sum"]}) > 1


@pytest.fixture(scope="module")
def vllm_server(model_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log_path = tmp_path_factory.mktemp("vllm-serve") / "server.log"
    try:
        with vllm_serve(
            model_dir, log_path, served_name=SERVED_NAME, max_model_len=512, max_num_seqs=8
        ) as url:
            yield url
    except ServerDidNotStart as err:
        pytest.fail(str(err))


def test_openai_backend_against_vllm_serve(vllm_server: str) -> None:
    def conv(text: str) -> list[ChatMessage]:
        return [ChatMessage(role="user", content=text)]

    config = GenerateConfig(max_tokens=12, timeout_s=120, max_retries=1, max_concurrency=4)
    model = OpenAIModel(SERVED_NAME, config, base_url=vllm_server)
    model.probe()
    choice = model.generate(
        [conv("A tree is to your left. Which action?"), conv("Nothing around. Which action?")],
        choices=ChoiceSet(options=tuple(ACTIONS), rule="guided"),
    )
    assert all(o.finish_reason == "choice" and o.text in ACTIONS for o in choice), choice
    assert model.structured_choice  # the server accepted structured outputs
    free = model.generate([conv("Say hello."), conv("Write a long story about a tree.")])
    assert all(o.error is None and o.text.strip() for o in free), free
    assert all(0 < o.completion_tokens <= 12 and o.prompt_tokens > 0 for o in free)
    assert free[1].finish_reason == "length"
    # The server's prefix cache serves a repeated prompt (--enable-prompt-tokens-details). It
    # keeps whole blocks only (128 tokens on the CPU), so the prompt spans more than two.
    story = [ChatMessage(role="system", content=" ".join(ACTIONS * 30)), *conv("Which action?")]
    first, again = (model.generate([story])[0] for _ in range(2))
    assert first.computed_prompt_tokens is not None and again.computed_prompt_tokens is not None
    assert again.computed_prompt_tokens < again.prompt_tokens == first.prompt_tokens
    # A model the server does not serve is a client error: reported, not retried.
    [missing] = OpenAIModel("no-such-model", config, base_url=vllm_server).generate([conv("hi")])
    assert missing.finish_reason == "error" and "HTTP 404" in (missing.error or "")


def test_the_probe_against_vllm_serve_names_a_wrong_model(vllm_server: str) -> None:
    typo = get_model(f"openai:smollm@{vllm_server}", GenerateConfig(timeout_s=30))
    start = time.monotonic()
    with pytest.raises(UserError) as caught:
        typo.probe()
    assert time.monotonic() - start < 15
    assert str(caught.value).startswith("model 'smollm' is not served at")
    assert "did you mean 'smollm2'?" in str(caught.value)


def test_setup_script_second_run_is_a_quick_no_op() -> None:
    start = time.monotonic()
    run = subprocess.run(
        ["bash", str(REPO / "scripts" / "setup_vllm_cpu.sh")],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHON": sys.executable},
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "already built" in run.stdout
    assert time.monotonic() - start < 120
