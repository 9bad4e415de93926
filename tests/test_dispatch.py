"""The dispatcher's closing: an engine's call in progress is waited for, a server's is not."""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import pytest
from interrupt import interruptible_run

from llm_agents.agents.types import StepPrompt
from llm_agents.backends.base import ChatMessage, ChoiceSet, Conversation, ModelOutput
from llm_agents.backends.mock import MockModel
from llm_agents.evaluation.dispatch import Dispatcher
from llm_agents.run_data.store import read_episodes

REPO = Path(__file__).resolve().parents[1]


class _HeldModel(MockModel):
    """A model whose first call blocks until the test releases it."""

    def __init__(self, *, concurrent_requests: bool) -> None:
        super().__init__(outputs=["noop"])
        self.concurrent_requests = concurrent_requests
        self.started = threading.Event()
        self.release = threading.Event()
        self.calls = 0

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        self.calls += 1
        self.started.set()
        assert self.release.wait(timeout=60)
        return super()._generate(conversations, choices)


def _prompts(slots: range) -> list[StepPrompt]:
    message = [ChatMessage(role="user", content="?")]
    return [StepPrompt(slot=slot, observation=None, messages=message, text="") for slot in slots]


def _close_in_background(dispatcher: Dispatcher) -> threading.Thread:
    closing = threading.Thread(target=dispatcher.close)
    closing.start()
    closing.join(timeout=0.5)
    return closing


def test_closing_waits_for_an_engines_call_and_starts_no_other() -> None:
    engine = _HeldModel(concurrent_requests=False)
    dispatcher = Dispatcher(engine, None)
    dispatcher.submit(_prompts(range(2)))
    assert engine.started.wait(timeout=60)
    dispatcher.submit(_prompts(range(2, 4)))  # queued behind the call in progress
    closing = _close_in_background(dispatcher)
    assert closing.is_alive(), "close returned while the engine was still computing"
    engine.release.set()
    closing.join(timeout=60)
    assert not closing.is_alive()
    assert engine.calls == 1, "a queued call started after close"


def test_closing_does_not_wait_for_a_servers_answer() -> None:
    server = _HeldModel(concurrent_requests=True)
    dispatcher = Dispatcher(server, None)
    dispatcher.submit(_prompts(range(1)))
    assert server.started.wait(timeout=60)
    closing = _close_in_background(dispatcher)
    try:
        assert not closing.is_alive(), "close waited for a server's answer"
    finally:
        server.release.set()


@pytest.mark.slow
def test_ctrl_c_during_a_transformers_call_exits_130_without_aborting(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("transformers")
    out = tmp_path / "interrupted"
    # Long answers for a batch of 4: nearly all of the run's time is inside the model's call, so
    # the signal lands there (where a thread left running at exit aborted the process).
    command = [
        sys.executable, "-m", "llm_agents.cli", "eval", "--model", "hf:smollm2-135m",
        "--variant", "classic", "--categories", "combo", "--max-steps", "3", "--max-tokens", "48",
        "--batch-size", "4", "--limit", "40", "--output-dir", str(out), "--no-progress",
    ]  # fmt: skip
    process = interruptible_run(command, REPO)
    episodes = out / "episodes.jsonl"
    deadline = time.monotonic() + 600
    while process.poll() is None and time.monotonic() < deadline:
        if episodes.exists() and episodes.read_text().strip():
            break
        time.sleep(0.05)
    # The first episodes are just written: the next call (over a second of decoding) has begun.
    time.sleep(0.5)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert len(read_episodes(episodes)) < 40, "the run ended before the signal"
    assert b"terminate called" not in stderr, stderr.decode()[-2000:]
    assert process.returncode == 130, stderr.decode()[-2000:]
