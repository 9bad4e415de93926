"""`--observation image|both`: the frame Craftax's own pixel renderer draws reaches the model.

A loopback OpenAI server sees every step's request carry the step's frame (after the frames of
the steps before it, `--frame-history`), and each decodes to what craftax's renderer, at its
Pixels env's block size, draws of the state the step was played from (the episode replayed
here from its recorded key and actions), pixel for pixel; the step records keep those exact
PNGs for `view`. A tiny image-text model built from a config (random weights, no download)
answers frames through the hf backend, alone and in a whole run; a text-only model, or a server
that refuses images, stops the run before anything is written.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fault_server import Fault, FaultServer
from tiny_vlm import build_tiny_vlm

from env.errors import UserError
from llm_agents.agents.types import messages_hash
from llm_agents.backends.base import ChatMessage, GenerateConfig, ImagePart
from llm_agents.cli import main
from llm_agents.evaluation.config import EvalConfig, build_config
from llm_agents.evaluation.runner import open_model, run_eval
from llm_agents.run_data.store import EPISODES_FILE, STEPS_FILE, read_episodes, read_steps

MAX_STEPS = 4
ANSWERS = ["ACTION: LEFT", "ACTION: DO", "ACTION: UP", "ACTION: RIGHT", "ACTION: DOWN"]


@pytest.fixture(scope="module")
def short_env() -> Any:
    from env import EnvConfig, Variant, shared_env

    return shared_env(EnvConfig(variant=Variant.CLASSIC, max_steps=MAX_STEPS))


def image_run(out: Path, model: str, **settings: Any) -> EvalConfig:
    return build_config(
        {
            "model": model,
            "task": "open_ended",
            "variant": "classic",
            "categories": ["combo"],
            "max_steps": MAX_STEPS,
            "output_dir": str(out),
            **settings,
        }
    )


def request_messages(body: dict[str, Any]) -> list[ChatMessage]:
    """A request's messages read back: each image part's data URL as the PNG it carries."""
    messages = []
    for message in body["messages"]:
        content = message["content"]
        if isinstance(content, str):
            messages.append(ChatMessage(role=message["role"], content=content))
            continue
        images = []
        for part in content[:-1]:
            assert part["type"] == "image_url"
            prefix, _, data = part["image_url"]["url"].partition(",")
            assert prefix == "data:image/png;base64"
            images.append(ImagePart(png_base64=data))
        assert content[-1]["type"] == "text"
        messages.append(
            ChatMessage(role=message["role"], content=content[-1]["text"], images=tuple(images))
        )
    return messages


def craftax_frames(reset_key: list[int], actions: list[int], env: Any) -> list[np.ndarray]:
    """Craftax's own render of each state the episode was played from, at its Pixels env's
    block size (`BLOCK_PIXEL_SIZE_AGENT`), replayed from the recorded key and actions; and
    checked against the Pixels env's observation itself (its render / 255)."""
    import jax
    from craftax.craftax_classic.constants import BLOCK_PIXEL_SIZE_AGENT
    from craftax.craftax_classic.envs.craftax_pixels_env import CraftaxClassicPixelsEnv
    from craftax.craftax_classic.renderer import make_craftax_pixel_renderer

    from env import make_task

    render = jax.jit(make_craftax_pixel_renderer(BLOCK_PIXEL_SIZE_AGENT))
    pixels_env = CraftaxClassicPixelsEnv()
    # The game does not depend on the goal: any task replays it.
    state = env.jitted_reset(
        jax.numpy.asarray(np.asarray(reset_key, np.uint32)),
        make_task(np.zeros(22, bool), np.zeros(22, bool)),
    )
    step = jax.jit(env.step_from_episode_key)
    frames = []
    for action in [*actions, None]:
        drawn = np.asarray(render(state.game))
        observed = np.asarray(pixels_env.get_obs(state.game))
        assert np.abs(observed * 255 - drawn).max() < 1e-3
        frames.append(np.clip(np.round(drawn), 0, 255).astype(np.uint8))
        if action is not None:
            state, _ = step(state, jax.numpy.int32(action))
    return frames


@pytest.mark.slow
def test_every_request_carries_its_steps_frames_pixel_for_pixel(
    tmp_path: Path, short_env: Any
) -> None:
    answers = itertools.cycle(ANSWERS)
    server = FaultServer(answer=lambda body: {"role": "assistant", "content": next(answers)})
    server.start()
    try:
        config = image_run(
            tmp_path / "run",
            f"openai:test-model@{server.url}",
            observation="both",
            frame_history=2,
            episodes_per_instruction=2,
            batch_size=2,
        )
        with open_model(config) as model:
            run_eval(config, model, env=short_env)
    finally:
        server.stop()

    steps = list(read_steps(tmp_path / "run" / STEPS_FILE))
    episodes = read_episodes(tmp_path / "run" / EPISODES_FILE)
    assert len(episodes) == 2 and len(steps) == 2 * MAX_STEPS
    by_hash = {step.prompt_hash: step for step in steps}
    played = [request_messages(r.body) for r in server.requests if "messages" in r.body]
    # The image check and the probe ask a one-token answer; every other request is a step's.
    step_requests = [m for m in played if m[0].role == "system"]
    assert len(step_requests) == len(steps)
    assert played[0][-1].images, "the image check sends an image"
    for episode in episodes:
        own = sorted(
            (step for step in steps if step.episode_id == episode.episode_id),
            key=lambda s: s.step,
        )
        expected = craftax_frames(episode.reset_key, [s.action_id for s in own], short_env)
        for step in own:
            [messages] = [m for m in step_requests if messages_hash(m) == step.prompt_hash]
            assert by_hash[step.prompt_hash] is step
            *earlier, last = messages
            assert not any(message.images for message in earlier)
            sent = [image.array() for image in last.images]
            shown = list(range(max(0, step.step - 2), step.step + 1))
            assert len(sent) == len(shown)
            for image, index in zip(sent, shown, strict=True):
                np.testing.assert_array_equal(image, expected[index])
            # `both`: the text observation is there too, and what the images are is said.
            assert "Current observation:" in last.content
            assert "attached to this message" in last.content
            # The record keeps the very PNG sent (view shows it).
            assert step.frame_png == last.images[-1].png_base64

    # `view`'s episode page shows each step's sent images: the recorded PNGs themselves.
    from llm_agents.viewer.pages import sent_images

    for episode in episodes:
        own = [step for step in steps if step.episode_id == episode.episode_id]
        urls, sent = sent_images(own, 2)
        for step in own:
            [messages] = [m for m in step_requests if messages_hash(m) == step.prompt_hash]
            shown = [urls[index] for index in sent[step.step]]
            assert shown == [image.data_url for image in messages[-1].images]


def test_a_server_refusing_images_stops_the_run_before_anything_is_written(
    tmp_path: Path,
) -> None:
    blank = ImagePart.from_frame(np.zeros((8, 8, 3), np.uint8))
    key = str(
        [
            {"type": "image_url", "image_url": {"url": blank.data_url}},
            {"type": "text", "text": "Say OK."},
        ]
    )
    server = FaultServer(plan={key: [Fault("status", status=400, body="no images")]}).start()
    try:
        config = image_run(tmp_path / "run", f"openai:text-model@{server.url}", observation="image")
        with pytest.raises(UserError, match="refuses a request with an image"):
            open_model(config)
    finally:
        server.stop()
    assert not (tmp_path / "run").exists()


def test_a_text_only_hf_model_given_images_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["eval", "--model", "hf:smollm2-135m", "--observation", "image", "--variant"]
    argv += ["classic", "--task", "open_ended", "--categories", "combo"]
    code = main([*argv, "--output-dir", str(tmp_path / "run"), "--no-progress"])
    assert code == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and "is a text-only model" in lines[0], lines
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def tiny_vlm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from llm_agents.backends.embedded import embedded_model_dir

    return build_tiny_vlm(tmp_path_factory.mktemp("tiny-vlm"), embedded_model_dir())


@pytest.mark.slow
def test_a_tiny_image_text_model_answers_frames_through_hf(tiny_vlm: Path) -> None:
    from llm_agents.backends import get_model

    model = get_model(f"hf:{tiny_vlm}", GenerateConfig(max_tokens=4), threads=1)
    model.check_images()
    frames = [np.zeros((63, 63, 3), np.uint8), np.full((63, 63, 3), 255, np.uint8)]
    conversations = [
        [
            ChatMessage(role="system", content="You play a survival game."),
            ChatMessage(role="user", content="What now?", images=(ImagePart.from_frame(f),)),
        ]
        for f in frames
    ]
    outputs = model.generate([*conversations, [ChatMessage(role="user", content="no image")]])
    assert [o.finish_reason for o in outputs] == ["length"] * 3
    assert all(o.completion_tokens == 4 and o.text for o in outputs)
    # The image is read: the image tokens stand in the prompt, and another image moves the
    # model's first-token distribution.
    assert outputs[0].prompt_tokens > outputs[2].prompt_tokens
    processor, torch_model = model.processor, model.model  # type: ignore[attr-defined]
    import torch

    from llm_agents.backends.hf.vision import processor_messages

    logits = []
    for conversation in conversations:
        inputs = processor.apply_chat_template(
            processor_messages(conversation),
            add_generation_prompt=True,
            tokenize=True,
            return_dict=True,
            return_tensors="pt",
        )
        with torch.inference_mode():
            logits.append(torch_model(**inputs).logits[0, -1])
    assert not torch.allclose(logits[0], logits[1])


@pytest.mark.slow
def test_a_run_of_the_tiny_image_text_model_through_hf(
    tiny_vlm: Path, tmp_path: Path, short_env: Any
) -> None:
    config = image_run(
        tmp_path / "run",
        f"hf:{tiny_vlm}",
        observation="image",
        generation={"max_tokens": 3},
        backend_options={"threads": 1},
        batch_size=1,
    )
    with open_model(config) as model:
        run_eval(config, model, env=short_env)
    steps = list(read_steps(tmp_path / "run" / STEPS_FILE))
    assert len(steps) == MAX_STEPS
    assert all(step.frame_png and step.finish_reason != "error" for step in steps)
    # `image`: no text observation in the prompt, what the image is said instead.
    assert all("attached to this message" in step.observation for step in steps)
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    assert results["config"]["observation"] == "image"
