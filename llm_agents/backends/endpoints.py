"""Many servers behind one model spec: least-outstanding choice, take-out and health checks.

An HTTP backend given several base URLs (`openai:MODEL@URL1,URL2`) asks an `EndpointPool` for
an endpoint before each attempt. The pool picks, among the endpoints in rotation, the one with
the fewest requests in flight. An attempt that fails in a way that says the server is gone or
sick (no connection, a timeout, a 5xx, a garbled body) takes its endpoint out of rotation; a
background thread then checks it every `health_interval_s` and puts it back once it answers
again. When every endpoint is out, attempts still go to them (the least loaded first): the
retry policy then decides, as for a single server, how long to keep trying before the answer
counts as failed, and the run's failure rules take over from there.

The pool is shared by the threads that call the backend (each with its own event loop), so its
state sits behind a lock; it never does I/O while holding it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from pydantic import BaseModel, computed_field

logger = logging.getLogger(__name__)

#: HTTP statuses that say "slow down", not "this server is broken": the endpoint stays in.
KEEP_IN_STATUSES = frozenset({408, 429})


def takes_out(status: int | None) -> bool:
    """Whether a transient failure with this HTTP status (None: no answer at all) takes its
    endpoint out of rotation."""
    return status not in KEEP_IN_STATUSES


class EndpointStats(BaseModel):
    """What one server endpoint did during a run (recorded in `results.json`)."""

    url: str
    """The endpoint's base URL, credentials removed."""
    requests: int = 0
    """Attempts sent to it (retries included)."""
    errors: int = 0
    """Attempts that failed (a retry elsewhere may still have answered)."""
    taken_out: int = 0
    """Times it was taken out of rotation after a failure."""
    latency_s_total: float = 0.0
    """Summed wall time of its successful attempts."""

    @computed_field  # type: ignore[prop-decorator]
    @property
    def mean_latency_s(self) -> float | None:
        """Mean wall time of a successful attempt; None before the first."""
        ok = self.requests - self.errors
        return self.latency_s_total / ok if ok > 0 else None


def merge_endpoint_stats(groups: Iterable[Iterable[EndpointStats]]) -> list[EndpointStats]:
    """Sum the stats of the same URLs seen by several processes (Ray workers), in first-seen order."""
    merged: dict[str, EndpointStats] = {}
    for group in groups:
        for stats in group:
            total = merged.setdefault(stats.url, EndpointStats(url=stats.url))
            total.requests += stats.requests
            total.errors += stats.errors
            total.taken_out += stats.taken_out
            total.latency_s_total += stats.latency_s_total
    return list(merged.values())


@dataclass(eq=False)
class Endpoint:
    """One server of the pool and its live state."""

    url: str
    """Base URL up to `/v1`, credentials removed."""
    in_rotation: bool = True
    outstanding: int = 0
    stats: EndpointStats = field(init=False)

    def __post_init__(self) -> None:
        self.stats = EndpointStats(url=self.url)


#: Checks one endpoint's health: True when the server answers.
HealthCheck = Callable[[Endpoint], bool]


class EndpointPool:
    """Endpoints of one backend: which to use next, and which are out of rotation."""

    def __init__(self, urls: list[str], health_check: HealthCheck, health_interval_s: float):
        self.endpoints = [Endpoint(url) for url in urls]
        self._health_check = health_check
        self._interval_s = health_interval_s
        self._lock = threading.Lock()
        self._checker: threading.Thread | None = None
        self._closed = threading.Event()
        self._next = 0

    def acquire(self) -> Endpoint:
        """The endpoint for the next attempt, counted as in flight until `release`.

        Ties between equally loaded endpoints rotate, so that a lightly loaded pool still
        spreads its requests.
        """
        with self._lock:
            candidates = [e for e in self.endpoints if e.in_rotation] or self.endpoints
            count = len(self.endpoints)
            start = self._next
            best = min(
                candidates,
                key=lambda e: (e.outstanding, (self.endpoints.index(e) - start) % count),
            )
            self._next = (self.endpoints.index(best) + 1) % count
            best.outstanding += 1
            best.stats.requests += 1
            return best

    def succeeded(self, endpoint: Endpoint, latency_s: float) -> None:
        """An attempt on `endpoint` got an answer (the server is alive, whatever it said)."""
        with self._lock:
            endpoint.outstanding -= 1
            endpoint.stats.latency_s_total += latency_s
            if not endpoint.in_rotation:
                endpoint.in_rotation = True
                logger.warning("endpoint %s answers again: back in rotation", endpoint.url)

    def failed(self, endpoint: Endpoint, *, take_out: bool) -> bool:
        """An attempt on `endpoint` failed; with `take_out` (the failure says the server is gone
        or sick) it leaves rotation. Returns whether it did and another endpoint in rotation can
        take the retry at once."""
        with self._lock:
            endpoint.outstanding -= 1
            endpoint.stats.errors += 1
            if len(self.endpoints) == 1 or not take_out:
                return False
            if endpoint.in_rotation:
                endpoint.in_rotation = False
                endpoint.stats.taken_out += 1
                logger.warning("endpoint %s failed: taken out of rotation", endpoint.url)
                self._start_checker()
            return any(e.in_rotation for e in self.endpoints)

    def released(self, endpoint: Endpoint) -> None:
        """An attempt ended without saying anything about the server (it was cancelled)."""
        with self._lock:
            endpoint.outstanding -= 1
            endpoint.stats.requests -= 1

    def stats(self) -> list[EndpointStats]:
        """A copy of every endpoint's counts."""
        with self._lock:
            return [e.stats.model_copy() for e in self.endpoints]

    def close(self) -> None:
        self._closed.set()

    def _start_checker(self) -> None:
        if self._checker is None:
            self._checker = threading.Thread(
                target=self._check_until_all_back, name="endpoint-health", daemon=True
            )
            self._checker.start()

    def _check_until_all_back(self) -> None:
        while not self._closed.wait(self._interval_s):
            with self._lock:
                out = [e for e in self.endpoints if not e.in_rotation]
                if not out:
                    # Decided under the lock, so that a failure right now starts a new checker.
                    self._checker = None
                    return
            for endpoint in out:
                started = time.perf_counter()
                if not self._health_check(endpoint):
                    continue
                with self._lock:
                    if not endpoint.in_rotation:
                        endpoint.in_rotation = True
                        logger.warning(
                            "endpoint %s passed a health check (%.2f s): back in rotation",
                            endpoint.url,
                            time.perf_counter() - started,
                        )
