"""A balrog-protocol run as a submission folder of BALROG's leaderboard repository
(balrog-ai/experiments), and such a folder read back.

The folder holds what a BALROG submission holds for Crafter: a file per episode
(`crafter/default/default_run_NN.json`: task, steps, seed, return, score, progression and the
achievement dict, keys in Crafter's order), the environment summary
(`crafter/crafter_summary.json`), the top-level summary (`summary.json`) and the metadata
(`metadata.yaml`). The summaries are computed from the per-episode progressions as BALROG's
`collect_and_summarize_results` does (see `llm_agents.run_data.scores`). Our records keep when
an achievement was first unlocked, not how often: each count is 1 or 0, which is all
progression and the leaderboard read (count > 0).

Only a complete run of `--protocol balrog` with none of its settings overridden is a
submission; anything else is refused before anything is written.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from env.craftax_names import CLASSIC_ACHIEVEMENTS
from env.errors import UserError
from llm_agents.evaluation.run_view import read_run
from llm_agents.judging.rescoring import model_name_of
from llm_agents.run_data.records import EpisodeRecord
from llm_agents.run_data.scores import progression, score_episodes
from llm_agents.run_data.store import RunResults

__all__ = ["BalrogSubmission", "export_balrog", "read_balrog_submission", "submission_scores"]

ENV_NAME = "crafter"
TASK = "default"
#: Crafter's achievement names in the order BALROG's episode files store them (alphabetical).
BALROG_ACHIEVEMENTS: tuple[str, ...] = tuple(sorted(name.lower() for name in CLASSIC_ACHIEVEMENTS))


class BalrogSubmission(BaseModel):
    """A submission folder's Crafter numbers, as read back."""

    unlocked: list[list[str]]
    """Per episode file (in name order), the achievements with a count above 0."""
    progression_percentage: float
    """`crafter_summary.json`'s mean progression (x100)."""
    standard_error: float
    """`crafter_summary.json`'s standard error (x100)."""
    final_score: float
    """`summary.json`'s `Final score`."""
    episodes_played: int


def _refusal(results: RunResults, episodes: Sequence[EpisodeRecord]) -> str | None:
    config = results.config
    if config.get("protocol") != "balrog" or config.get("task") != "open_ended":
        return f"it was played under --protocol {config.get('protocol', 'default')}, not balrog"
    overrides = config.get("protocol_overrides") or []
    if overrides:
        return f"it overrode the balrog protocol's {', '.join(overrides)}"
    if results.status != "complete" or len(episodes) != results.scheduled:
        return f"it is {results.status} ({len(episodes)} of {results.scheduled} episodes)"
    return None


def _episode_file(episode: EpisodeRecord, results: RunResults) -> dict[str, Any]:
    unlocked = {name.lower() for name in episode.achievements}
    achievements = {name: int(name in unlocked) for name in BALROG_ACHIEVEMENTS}
    score = sum(1 for count in achievements.values() if count > 0)
    return {
        "task": TASK,
        "input_tokens": episode.prompt_tokens,
        "output_tokens": episode.completion_tokens,
        "done": True,
        "episode_return": episode.episode_return,
        "num_steps": episode.steps,
        "score": float(score),
        "progression": score / len(BALROG_ACHIEVEMENTS),
        "achievements": achievements,
        "seed": episode.seed,
        "craftext_llm": {
            "episode_id": episode.episode_id,
            "termination": episode.termination,
            "invalid_actions": episode.invalid_actions,
        },
    }


def _summaries(
    files: Sequence[dict[str, Any]], results: RunResults
) -> tuple[dict[str, Any], dict[str, Any]]:
    mean, error = progression([f["progression"] for f in files])
    n = len(files)
    inputs = sum(f["input_tokens"] for f in files)
    outputs = sum(f["output_tokens"] for f in files)
    crafter = {
        "progression_percentage": mean,
        "standard_error": error,
        "average_steps": sum(f["num_steps"] for f in files) / n,
        "episodes_played": n,
        "tasks": {
            TASK: {"progression_percentage": mean, "standard_error": error, "episodes_played": n}
        },
        "input_tokens": inputs,
        "output_tokens": outputs,
    }
    config = results.config
    generation = config.get("generation") or {}
    summary = {
        "Final score": mean,
        "standard_error": error,
        "environments": {
            ENV_NAME: {
                "progression_percentage": mean,
                "standard_error": error,
                "episodes_played": n,
            }
        },
        "total_input_tokens": inputs,
        "total_output_tokens": outputs,
        "client": {
            "client_name": "craftext-llm",
            # The expert calls no model: its config's model is only the unused default.
            "model_id": None if config.get("agent") == "expert" else config.get("model"),
            "generate_kwargs": {
                "temperature": generation.get("temperature"),
                "max_tokens": generation.get("max_tokens"),
            },
        },
        "agent": {"type": config.get("agent"), "max_history": config.get("history_length")},
    }
    return crafter, summary


def export_balrog(run_dir: str | Path, out: str | Path) -> Path:
    """Write the run in `run_dir` as a BALROG submission folder `out`; a `UserError` (nothing
    written) for a run that is not a complete balrog-protocol run or an `out` already used."""
    run_dir, out = Path(run_dir), Path(out)
    run = read_run(run_dir, require_episodes=False)
    results, episodes = run.results, list(run.episodes)
    why = _refusal(results, episodes)
    if why is not None:
        raise UserError(f"{run_dir} is not a complete balrog-protocol run: {why}")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"{out} already exists and is not an empty directory")
    episodes.sort(key=lambda e: e.episode_index)
    files = [_episode_file(e, results) for e in episodes]
    crafter, summary = _summaries(files, results)
    finished = results.finished_at or results.started_at
    metadata = {
        "name": model_name_of(results),
        "oss": None,
        "site": None,
        "verified": False,
        "org_logo": None,
        "trajs": False,
        "date": finished.date().isoformat(),
    }
    # Built aside and moved in whole, so a failure leaves no half-written submission.
    staging: Path | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}."))
        episode_dir = staging / ENV_NAME / TASK
        episode_dir.mkdir(parents=True)
        for index, data in enumerate(files):
            _write_json(episode_dir / f"{TASK}_run_{index:02d}.json", data)
        _write_json(staging / ENV_NAME / f"{ENV_NAME}_summary.json", crafter)
        _write_json(staging / "summary.json", summary)
        (staging / "metadata.yaml").write_text(yaml.safe_dump(metadata, sort_keys=False))
        if out.exists():
            out.rmdir()
        os.replace(staging, out)
    except OSError as err:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        raise UserError(f"cannot write {out}: {err.strerror}") from err
    return out


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=4) + "\n", encoding="utf-8")


def read_balrog_submission(folder: str | Path) -> BalrogSubmission:
    """The Crafter numbers of a BALROG submission folder: the episode files' unlocked
    achievements (files in name order) and the published summaries."""
    folder = Path(folder)
    try:
        names = sorted((folder / ENV_NAME).rglob("*.json"))
        files = [
            json.loads(p.read_text(encoding="utf-8"))
            for p in names
            if not p.name.endswith("_summary.json")
        ]
        crafter = json.loads((folder / ENV_NAME / f"{ENV_NAME}_summary.json").read_text())
        summary = json.loads((folder / "summary.json").read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise UserError(f"{folder} is not a readable BALROG submission: {err}") from err
    return BalrogSubmission(
        unlocked=[[k for k, v in f["achievements"].items() if v > 0] for f in files],
        progression_percentage=crafter["progression_percentage"],
        standard_error=crafter["standard_error"],
        final_score=summary["Final score"],
        episodes_played=crafter["episodes_played"],
    )


def submission_scores(submission: BalrogSubmission) -> tuple[float, float]:
    """(progression, standard error) recomputed from a submission's episode files."""
    scores = score_episodes(submission.unlocked)
    return scores.progression, scores.progression_stderr
