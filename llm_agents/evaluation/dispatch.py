"""The dispatcher: every model request of a run goes through it, and answers come back as they
arrive, so each episode can step as soon as its own answer is in."""

from __future__ import annotations

import logging
import queue
import threading

from llm_agents.agents.types import StepPrompt
from llm_agents.backends.base import ChoiceSet, ModelAPI, ModelOutput, OutputSchema

Answer = tuple[StepPrompt, ModelOutput]

logger = logging.getLogger(__name__)


class Dispatcher:
    """Every model request of a run goes through here; answers come back as they arrive.

    A backend with `concurrent_requests` (an HTTP server) gets up to `max_concurrency`
    one-conversation calls in flight, from as many threads; any other (an in-process engine)
    gets one call at a time holding every prompt that is ready, so its own batching does the
    rest. Worker threads are daemons: an interrupted run does not wait for a server's slow
    answer. An engine's call is waited for when the dispatcher closes (see `close`).
    """

    def __init__(
        self, model: ModelAPI, choices: ChoiceSet | None, schema: OutputSchema | None = None
    ):
        self.model = model
        self.choices = choices
        self.schema = schema
        self._requests: queue.SimpleQueue[list[StepPrompt] | None] = queue.SimpleQueue()
        self._answers: queue.SimpleQueue[list[Answer] | BaseException] = queue.SimpleQueue()
        self.in_flight = 0
        self._workers = model.config.max_concurrency if model.concurrent_requests else 1
        self._closed = threading.Event()
        serve = self._serve_one_by_one if model.concurrent_requests else self._serve_batches
        self._threads = [
            threading.Thread(target=serve, name=f"dispatch-{index}", daemon=True)
            for index in range(self._workers)
        ]
        for thread in self._threads:
            thread.start()

    def submit(self, prompts: list[StepPrompt]) -> None:
        """Queue prompts; an engine gets them in one call (with whatever else is waiting)."""
        if not prompts:
            return
        self.in_flight += len(prompts)
        # A prompt without messages (a scripted step) needs no model: it is answered at once.
        silent = [prompt for prompt in prompts if not prompt.messages]
        if silent:
            self._answers.put([(prompt, ModelOutput(text="")) for prompt in silent])
            prompts = [prompt for prompt in prompts if prompt.messages]
            if not prompts:
                return
        if self.model.concurrent_requests:
            for prompt in prompts:
                self._requests.put([prompt])
        else:
            self._requests.put(prompts)

    def wait(self) -> list[Answer]:
        """Block until at least one answer arrives; return every answer that has."""
        got = [self._answers.get()]
        while True:
            try:
                got.append(self._answers.get_nowait())
            except queue.Empty:
                break
        answers: list[Answer] = []
        for item in got:
            if isinstance(item, BaseException):
                raise item
            answers.extend(item)
        self.in_flight -= len(answers)
        return answers

    def close(self) -> None:
        """Start no more calls; wait for an engine's call in progress to end.

        An engine computes in this process: a thread still inside its native code when the
        interpreter exits is torn down there, which aborts the process ("terminate called
        without an active exception", exit 134) after an interrupted run saved its results.
        A server's answer is not waited for: its thread only waits on a socket.
        """
        self._closed.set()
        for _ in range(self._workers):
            self._requests.put(None)
        if self.model.concurrent_requests:
            return
        (engine,) = self._threads
        engine.join(timeout=0.1)  # an idle worker ends at once on its None
        if engine.is_alive():
            logger.warning("waiting for the model's current call to end")
            engine.join()

    def _serve_one_by_one(self) -> None:
        while (item := self._requests.get()) is not None and not self._closed.is_set():
            self._answer(item)

    def _serve_batches(self) -> None:
        while (item := self._requests.get()) is not None and not self._closed.is_set():
            batch = list(item)
            while True:
                try:
                    more = self._requests.get_nowait()
                except queue.Empty:
                    break
                if more is None:  # only `close` queues None
                    return
                batch.extend(more)
            self._answer(batch)

    def _answer(self, prompts: list[StepPrompt]) -> None:
        # Prompts with options of their own (the skills valid now) go in a call per option set.
        groups: dict[ChoiceSet | None, list[StepPrompt]] = {}
        for prompt in prompts:
            key = prompt.choices if prompt.choices is not None else self.choices
            groups.setdefault(key, []).append(prompt)
        answers: list[Answer] = []
        try:
            for choices, group in groups.items():
                outputs = self.model.generate(
                    [p.messages for p in group],
                    choices=choices,
                    schema=self.schema if choices is None else None,
                )
                if len(outputs) != len(group):
                    raise RuntimeError(
                        f"backend {self.model.backend_name} returned {len(outputs)} outputs "
                        f"for {len(group)} conversations"
                    )
                answers.extend(zip(group, outputs, strict=True))
        except BaseException as err:  # handed to the scheduler thread, which raises it
            self._answers.put(err)
            return
        self._answers.put(answers)
