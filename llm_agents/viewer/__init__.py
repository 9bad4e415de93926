"""The `view` command: a static HTML report of a run with frame-by-frame episode replays."""

from llm_agents.viewer.pages import (
    ReplayStatus,
    Selection,
    ViewOutcome,
    build_view,
    export_episode,
)

__all__ = ["ReplayStatus", "Selection", "ViewOutcome", "build_view", "export_episode"]
