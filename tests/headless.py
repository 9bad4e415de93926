"""Headless Chromium for the tests of static pages: Debian's /usr/bin/chromium driven by
Playwright (never `playwright install`), and pages opened with every console problem kept."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser"):
        if found := shutil.which(name):
            return found
    return None


def launch_chromium() -> Iterator[Any]:
    """A headless Chromium for a fixture to yield (skips when the system has none)."""
    executable = _chromium()
    if executable is None:
        pytest.skip("Chromium is not installed (scripts/setup_chromium.sh installs Debian's)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is missing: pip install -e '.[dev]'")
    with sync_playwright() as playwright:
        # --no-sandbox: the test may run as root (containers, CI), where the sandbox refuses.
        chromium = playwright.chromium.launch(executable_path=executable, args=["--no-sandbox"])
        yield chromium
        chromium.close()


def open_page(browser: Any, path: Path) -> tuple[Any, list[str]]:
    """`path` opened in a new page, and the list its console errors, warnings, page errors and
    failed requests are appended to."""
    page = browser.new_page(viewport={"width": 1280, "height": 1000})
    problems: list[str] = []
    page.on(
        "console", lambda m: problems.append(m.text) if m.type in ("error", "warning") else None
    )
    page.on("pageerror", lambda error: problems.append(str(error)))
    page.on("requestfailed", lambda request: problems.append(f"failed: {request.url}"))
    page.goto(path.as_uri())
    page.wait_for_load_state("load")
    return page, problems
