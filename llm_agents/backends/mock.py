"""A scripted, deterministic backend for tests and offline pipeline runs.

Spec forms (`mock:<script>`):
- `mock:` or `mock:noop` answers "NOOP" forever;
- `mock:cycle:A|B|C` answers A, B, C, A, ... (one counter over all requests, in order);
- `mock:list:A|B|C` answers A, B, C, then fails with an error output;
- `mock:file:PATH` reads a JSON list of answers and cycles through it;
- `mock:hash:A|B|C` picks the answer from a hash of the conversation, so the same prompt always
  gets the same answer whatever the batch or request order (resume tests rely on this);
- `mock:error` or `mock:error:MESSAGE` fails every request with an error output, as a backend
  whose server went away does (its probe fails too).
From Python, `MockModel(outputs=callable)` answers `callable(conversation)`.
Every request is recorded in `requests`. Both choice rules are accepted and answered alike: the
scripted answer when it is one of the options, else the first option (under
`--choice-scoring letters` the options are letters, so a script names letters: `cycle:A|C`).
Under a JSON schema (`--structured-output`) the scripted answer is returned when it is JSON that
follows the schema (checked by `jsonschema`), else as an error output saying so: a script stands
for a backend whose structured outputs hold, so one that breaks them is a broken script.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar

from env.errors import UserError
from llm_agents.backends.base import (
    ChatMessage,
    ChoiceRule,
    ChoiceSet,
    Conversation,
    GenerateConfig,
    ModelAPI,
    ModelOutput,
    OutputSchema,
)

Responder = Callable[[Sequence[ChatMessage]], str]


class MockModel(ModelAPI):
    """Answers from a script; optional fixed latency per batch for benchmarks."""

    backend_name = "mock"
    # Scripted answers depend on no generation setting, by design: a dry run takes real ones.
    honoured_config = frozenset(GenerateConfig.model_fields)
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset({"loglik", "guided"})

    def __init__(
        self,
        model_name: str = "",
        config: GenerateConfig | None = None,
        *,
        outputs: Sequence[str] | Responder | None = None,
        cycle: bool = True,
        latency_s: float = 0.0,
        **options: Any,
    ):
        super().__init__(model_name or "noop", config, **options)
        self.latency_s = latency_s
        self.requests: list[tuple[list[ChatMessage], ChoiceSet | None]] = []
        #: (conversation, schema) of every request made under a JSON schema.
        self.schemas: list[tuple[list[ChatMessage], OutputSchema]] = []
        self._count = 0
        self._responder: Responder | None = None
        self._outputs: list[str] = []
        self._mode = "cycle" if cycle else "list"
        self._error = ""
        if callable(outputs):
            self._responder = outputs
        elif outputs is not None:
            self._outputs = list(outputs)
        else:
            self._outputs, self._mode = _parse_script(model_name)
            if self._mode == "error":
                self._error = self._outputs[0]

    def cannot_sample(self) -> str | None:
        # Only a cycle of several answers (or a responder) answers one prompt differently.
        if self._responder is not None or (self._mode == "cycle" and len(set(self._outputs)) > 1):
            return None
        return f"mock:{self.model_name} answers a prompt always alike: it cannot sample"

    def probe(self) -> None:
        # A script always answers, and probing must not use up a `list:` script's answers.
        if self._mode == "error":
            raise UserError(f"mock:{self.model_name} does not answer: {self._error}")

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        if self.latency_s:
            time.sleep(self.latency_s)
        results = []
        for conversation in conversations:
            self.requests.append((list(conversation), choices))
            results.append(self._answer(conversation, choices.options if choices else None))
        return results

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        import jsonschema

        validator = jsonschema.Draft202012Validator(schema.as_data())
        self.schemas += [(list(conversation), schema) for conversation in conversations]
        outputs = self._generate(conversations, None)
        for index, output in enumerate(outputs):
            if output.finish_reason == "error":
                continue
            try:
                validator.validate(json.loads(output.text))
            except (json.JSONDecodeError, jsonschema.ValidationError) as err:
                why = err.msg if isinstance(err, json.JSONDecodeError) else err.message
                outputs[index] = output.model_copy(
                    update={
                        "finish_reason": "error",
                        "error": f"scripted answer does not follow the {schema.name} schema: {why}",
                    }
                )
        return outputs

    def check_schema(self, schema: OutputSchema) -> None:
        import jsonschema

        try:
            jsonschema.Draft202012Validator.check_schema(schema.as_data())
        except jsonschema.SchemaError as err:
            raise UserError(
                f"the mock backend cannot take the {schema.name} schema: {err.message}"
            ) from None

    def _answer(self, conversation: Conversation, choices: Sequence[str] | None) -> ModelOutput:
        index = self._count
        self._count += 1
        if self._mode == "error":
            return ModelOutput(text="", finish_reason="error", error=self._error)
        if self._responder is not None:
            text = self._responder(conversation)
        elif self._mode == "hash":
            digest = hashlib.sha256(
                "\x1e".join(f"{m.role}\x1f{m.content}" for m in conversation).encode()
            ).digest()
            text = self._outputs[int.from_bytes(digest[:8], "big") % len(self._outputs)]
        elif self._mode == "cycle" and self._outputs:
            text = self._outputs[index % len(self._outputs)]
        elif index < len(self._outputs):
            text = self._outputs[index]
        else:
            return ModelOutput(
                text="", finish_reason="error", error=f"mock script exhausted after {index} answers"
            )
        prompt_words = sum(_word_count(m.content) for m in conversation)
        if choices:
            finish = "choice"
            if text not in choices:
                text = choices[0]
        else:
            finish = "stop"
        return ModelOutput(
            text=text,
            prompt_tokens=prompt_words,
            completion_tokens=len(text.split()),
            latency_s=self.latency_s,
            finish_reason=finish,
        )


@lru_cache(maxsize=256)
def _word_count(text: str) -> int:
    # Cached: the system prompt every step repeats is counted once.
    return len(text.split())


def _parse_script(script: str) -> tuple[list[str], str]:
    kind, _, arg = script.partition(":")
    if kind in ("", "noop"):
        return ["NOOP"], "cycle"
    if kind == "error":
        return [arg or "scripted mock error"], "error"
    if kind in ("cycle", "list", "hash"):
        outputs = [part for part in arg.split("|") if part]
        if not outputs:
            raise UserError(f"mock script {script!r} lists no answers; write mock:{kind}:A|B")
        return outputs, kind
    if kind == "file":
        path = Path(arg)
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise UserError(f"cannot read mock script file {path}: {err}") from err
        if not isinstance(data, list) or not all(isinstance(x, str) for x in data) or not data:
            raise UserError(f"mock script file {path} must hold a non-empty JSON list of strings")
        return data, "cycle"
    raise UserError(
        f"unknown mock script {script!r}; use noop, cycle:A|B, list:A|B, hash:A|B, file:PATH or error"
    )
