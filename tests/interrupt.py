"""Starting a CLI run that Ctrl-C can interrupt, as it can from a terminal."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path


def interruptible_run(command: list[str], cwd: Path) -> subprocess.Popen[bytes]:
    """`command` started with its output captured and SIGINT at its default.

    A shell's background job (CI scripts, nohup) starts with SIGINT ignored, and Python keeps an
    ignored SIGINT ignored: the run gets the default, as a terminal's Ctrl-C finds it.
    """
    return subprocess.Popen(
        command,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
