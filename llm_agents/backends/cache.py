"""An optional response cache, so an interrupted or repeated run does not pay twice.

`CachedModel(model, path)` wraps any backend. A request's key is a digest of everything that
decides the answer: the backend's identity (`model.info()`: backend, model, and the versions and
settings it reports), the generation parameters that shape the output, the messages, and the
choice options with the rule that picks among them. Hits come back with `cached=True` and
`latency_s=0`.

What is cached: only deterministic requests, i.e. temperature 0 (greedy decoding, and choice
mode, which is greedy by construction). A sampled answer is a draw, and replaying it would hide
the variance a repeated run is meant to measure; `cache_sampled=True` caches those as well (a
rerun then replays the same draws). Error outputs are never cached, so a rerun retries them.

The store is one sqlite file in WAL mode, so several processes can share it: readers never block,
and a writer waits (up to `busy_timeout_s`) for another writer to finish.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from env.errors import UserError
from llm_agents.backends.base import (
    TRANSPORT_FIELDS,
    ChoiceRule,
    ChoiceSet,
    Conversation,
    ModelAPI,
    ModelOutput,
    OutputSchema,
)
from llm_agents.backends.endpoints import EndpointStats

_SCHEMA = """
CREATE TABLE IF NOT EXISTS responses (
    key TEXT PRIMARY KEY,
    output TEXT NOT NULL,
    created REAL NOT NULL
)
"""


class CachedModel(ModelAPI):
    """Serves repeated requests from a sqlite file and forwards the rest to `model`."""

    def __init__(
        self,
        model: ModelAPI,
        path: str | Path,
        *,
        cache_sampled: bool = False,
        busy_timeout_s: float = 60.0,
    ):
        super().__init__(model.model_name, model.config)
        self.model = model
        self.backend_name = model.backend_name
        self.concurrent_requests = model.concurrent_requests
        self.path = Path(path).expanduser()
        self.cache_sampled = cache_sampled
        self._lock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(
                self.path, timeout=busy_timeout_s, check_same_thread=False, isolation_level=None
            )
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(_SCHEMA)
        except (OSError, sqlite3.Error) as err:
            raise UserError(f"cannot open the response cache {self.path}: {err}") from err

    @property
    def caching(self) -> bool:
        """Whether the current generation settings are cached (see the module docstring)."""
        return self.model.config.temperature == 0 or self.cache_sampled

    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        return self._served(conversations, choices, None)

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        return self._served(conversations, None, schema)

    def check_schema(self, schema: OutputSchema) -> None:
        self.model.check_schema(schema)

    def _served(
        self,
        conversations: Sequence[Conversation],
        choices: ChoiceSet | None,
        schema: OutputSchema | None,
    ) -> list[ModelOutput]:
        if not self.caching:
            return self.model.generate(conversations, choices, schema)
        keys = [self.request_key(conversation, choices, schema) for conversation in conversations]
        found = self._lookup(keys)
        missing = [i for i, key in enumerate(keys) if key not in found]
        fresh = (
            self.model.generate([conversations[i] for i in missing], choices, schema)
            if missing
            else []
        )
        self._store(
            [
                (keys[i], output)
                for i, output in zip(missing, fresh, strict=True)
                if output.finish_reason != "error"
            ]
        )
        outputs: list[ModelOutput] = [
            # Nothing is computed for a cached answer now.
            found[key].model_copy(
                update={"cached": True, "latency_s": 0.0, "computed_prompt_tokens": 0}
            )
            if key in found
            else ModelOutput(text="")
            for key in keys
        ]
        for i, output in zip(missing, fresh, strict=True):
            outputs[i] = output
        return outputs

    def check_choice_rule(self, rule: ChoiceRule) -> None:
        self.model.check_choice_rule(rule)

    def request_key(
        self,
        conversation: Conversation,
        choices: ChoiceSet | None,
        schema: OutputSchema | None = None,
    ) -> str:
        """The digest that identifies one request (stable across processes and runs)."""
        payload: dict[str, Any] = {
            "model": self.model.info(),
            "config": self.model.config.model_dump(exclude=set(TRANSPORT_FIELDS)),
            "messages": [message.key_data() for message in conversation],
            "choices": choices.model_dump(mode="json") if choices else None,
        }
        if schema is not None:
            # Only with a schema: the keys of requests without one stay as they were.
            payload["schema"] = schema.json_schema
        encoded = json.dumps(payload, sort_keys=True, ensure_ascii=False).encode()
        return hashlib.sha256(encoded).hexdigest()

    def cannot_sample(self) -> str | None:
        return self.model.cannot_sample()

    def probe(self) -> None:
        self.model.probe()

    def check_images(self) -> None:
        self.model.check_images()

    def endpoint_stats(self) -> list[EndpointStats]:
        return self.model.endpoint_stats()

    def info(self) -> dict[str, str]:
        return {**self.model.info(), "response_cache": str(self.path)}

    def close(self) -> None:
        with self._lock:
            self._db.close()
        self.model.close()

    def _lookup(self, keys: list[str]) -> dict[str, ModelOutput]:
        unique = sorted(set(keys))
        found: dict[str, ModelOutput] = {}
        with self._lock:
            # sqlite caps the number of bound parameters, so look up in slices.
            for begin in range(0, len(unique), 500):
                chunk = unique[begin : begin + 500]
                marks = ",".join("?" * len(chunk))
                rows = self._db.execute(
                    f"SELECT key, output FROM responses WHERE key IN ({marks})", chunk
                ).fetchall()
                found.update((key, ModelOutput.model_validate_json(text)) for key, text in rows)
        return found

    def _store(self, entries: list[tuple[str, ModelOutput]]) -> None:
        if not entries:
            return
        now = time.time()
        rows = [(key, output.model_dump_json(), now) for key, output in entries]
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.executemany(
                    "INSERT OR REPLACE INTO responses (key, output, created) VALUES (?, ?, ?)",
                    rows,
                )
            except sqlite3.Error:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")
