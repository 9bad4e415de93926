"""Where a run's finished work goes: step and episode records appended to the run directory,
backend failures counted, `results.json` saved, progress shown."""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from llm_agents.agents.types import Decision
from llm_agents.backends.endpoints import EndpointStats
from llm_agents.evaluation.schedule import EpisodeQueue, ScheduledEpisode
from llm_agents.run_data.metrics import action_counts, action_histogram, summarize
from llm_agents.run_data.provenance import pooled_hardware
from llm_agents.run_data.records import EpisodeRecord, StepRecord
from llm_agents.run_data.scores import achievement_list_of, score_run
from llm_agents.run_data.store import (
    EPISODES_FILE,
    RESULTS_FILE,
    STEPS_FILE,
    RunResults,
    append_records,
    read_episodes,
    read_steps,
    rewrite_lines,
    write_results,
)

#: Seconds at least between the `results.json` rewrites of a run in progress. Each rewrite
#: summarises every finished episode: rewritten after each round that ends one, a fast agent's
#: run (several episodes a second) spent time quadratic in its episodes on it, and an fsync per
#: rewrite. The run's end, its stop on failures and Ctrl-C always write it; a resume rebuilds
#: it from `episodes.jsonl`, so a killed run loses nothing to the wait.
RESULTS_EVERY_S = 1.0
#: ...and at most this share of a run's time goes to them: on a Medium run one rewrite summarises
#: tens of thousands of episodes in seconds, and a fixed wait let the rewrites take all of the
#: driver's time (past 50,000 episodes a Medium run played at a quarter of its speed), so the
#: wait grows with the rewrite.
RESULTS_TIME_SHARE = 0.05


class RunSink:
    """The run's sink: hands out the episodes still to play, writes what comes back, stops the
    run when the backend fails too often in a row, and keeps `results.json` current (rewritten
    once an episode has ended, at the first round `RESULTS_EVERY_S` after the last rewrite, or
    later when rewrites would take more than `RESULTS_TIME_SHARE` of the time)."""

    def __init__(
        self,
        out: Path,
        results: RunResults,
        finished: list[EpisodeRecord],
        queue: EpisodeQueue,
        max_failures: int,
        endpoint_stats: Callable[[], list[EndpointStats]] = list,
        actions: dict[str, Counter[str]] | None = None,
        worker_hardware: Callable[[], list[dict[str, str]]] | None = None,
    ):
        self.out = out
        # Episode id -> action -> steps, from the step records (None: the run keeps no step log).
        self.actions = actions
        self.endpoint_stats = endpoint_stats
        # The machines of the workers that play the episodes elsewhere (Ray); None: this one.
        self.worker_hardware = worker_hardware
        self.results = results
        self.scheduled_ids = set(results.schedule)
        self.episodes = finished
        self.queue = queue
        self.max_failures = max_failures
        self.bar: Any = None
        self.stopped = False
        self.interrupted = threading.Event()
        self.failure: str | None = None
        self._failures_in_a_row = 0
        self._started = time.perf_counter()
        # This sitting's wall time is added to the earlier sittings' (None: not kept then).
        self._played_before = results.played_seconds
        self._saved_at = -RESULTS_EVERY_S
        self._save_s = 0.0
        self._unsaved = False
        self._successes = sum(e.success for e in finished)
        self._agent_steps = 0
        self._tokens = 0

    @property
    def counted(self) -> int:
        return sum(e.episode_id in self.scheduled_ids for e in self.episodes)

    def take(self, count: int) -> list[ScheduledEpisode]:
        """The next episodes to play; none once the run has stopped."""
        return [] if self.stopped else self.queue.take(count)

    def put_back(self, specs: Sequence[ScheduledEpisode]) -> None:
        """Episodes taken but lost unplayed (a Ray worker died): they are taken again first."""
        self.queue.put_back(specs)

    def record(
        self,
        decisions: list[Decision],
        steps: list[StepRecord],
        ended: list[EpisodeRecord],
        aborted: list[str],
    ) -> None:
        """Write a round's records, count its backend failures, and show progress."""
        if self.actions is not None:
            for episode_id, counts in action_counts(steps).items():
                self.actions.setdefault(episode_id, Counter()).update(counts)
            for episode_id in aborted:
                # Its steps are dropped on resume and it is played again from the start.
                self.actions.pop(episode_id, None)
        if steps:
            # Steps of unfinished episodes are dropped on resume, so only an episode's end needs
            # its steps on disk (before its line): an fsync per round would stall every round.
            append_records(self.out / STEPS_FILE, steps, durable=bool(ended))
        if ended:
            append_records(self.out / EPISODES_FILE, ended)
            self.episodes.extend(ended)
            self._successes += sum(e.success for e in ended)
        self._count_failures(decisions, aborted)
        self._unsaved = self._unsaved or bool(ended or aborted)
        if self._unsaved and self._save_due():
            self.save()
        self._agent_steps += len(decisions)
        self._tokens += sum(d.output.prompt_tokens + d.output.completion_tokens for d in decisions)
        if self.bar is not None:
            self._show_progress(len(ended))
        if self.interrupted.is_set():
            raise KeyboardInterrupt

    def _save_due(self) -> bool:
        wait = max(RESULTS_EVERY_S, self._save_s / RESULTS_TIME_SHARE)
        return time.monotonic() - self._saved_at >= wait

    def _show_progress(self, ended: int) -> None:
        elapsed = max(time.perf_counter() - self._started, 1e-9)
        self.bar.update(ended)
        self.bar.set_postfix(
            success=f"{self._successes}/{len(self.episodes)}",
            steps_s=f"{self._agent_steps / elapsed:.1f}",
            tok_s=f"{self._tokens / elapsed:.0f}",
            errors=self.results.backend_errors.failed_calls,
            refresh=False,
        )

    def _count_failures(self, decisions: list[Decision], aborted: list[str]) -> None:
        errors = self.results.backend_errors
        errors.aborted_episodes.extend(aborted)
        for decision in decisions:
            if decision.output.finish_reason != "error":
                self._failures_in_a_row = 0
                continue
            errors.failed_calls += 1
            errors.last_error = decision.output.error or "unknown backend error"
            self._failures_in_a_row += 1
            if self._failures_in_a_row >= self.max_failures and self.failure is None:
                self.failure = errors.last_error
                self.stopped = True

    def save(self, failure: str | None = None) -> None:
        """Write `results.json` for the episodes finished so far."""
        started = time.monotonic()
        results = self.results
        counted = [e for e in self.episodes if e.episode_id in self.scheduled_ids]
        results.finished = len(counted)
        results.endpoints = self.endpoint_stats()
        if self.worker_hardware is not None:
            results.worker_hardware = self.worker_hardware()
            results.hardware = pooled_hardware(results.worker_hardware)
        results.summary = summarize(counted, self.actions) if counted else None
        results.actions = (
            {}
            if self.actions is None
            else {
                e.episode_id: action_histogram(self.actions.get(e.episode_id, {})) for e in counted
            }
        )
        results.scores = (
            score_run(counted, achievement_list_of(results.config.get("variant")))
            if counted
            else None
        )
        results.groundings = {e.episode_id: e.grounding for e in counted if e.grounding}
        if failure is not None:
            results.status, results.failure = "failed", failure
        elif results.finished == results.scheduled:
            results.status, results.failure = "complete", None
        else:
            results.status, results.failure = "partial", None
        results.finished_at = datetime.now(UTC) if results.status == "complete" else None
        if self._played_before is not None:
            results.played_seconds = self._played_before + time.perf_counter() - self._started
        write_results(self.out / RESULTS_FILE, results)
        self._saved_at, self._unsaved = time.monotonic(), False
        self._save_s = self._saved_at - started


def finished_episodes(out: Path) -> list[EpisodeRecord]:
    """The episodes that finished in `out`, its episodes file rewritten without duplicates, so
    later appends extend a clean file."""
    path = out / EPISODES_FILE
    if not path.exists():
        return []
    episodes = read_episodes(path, repair=True)
    rewrite_lines(path, [e.model_dump_json() for e in episodes])
    return episodes


def recorded_actions(out: Path, finished_ids: set[str]) -> dict[str, Counter[str]]:
    """Episode id -> action -> steps of the finished episodes, from the step log (empty without
    one)."""
    path = out / STEPS_FILE
    return action_counts(read_steps(path, finished_ids)) if path.is_file() else {}
