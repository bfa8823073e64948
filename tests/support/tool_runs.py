"""Running a script of ``tools/`` as a user would: in a subprocess of this Python, its output kept."""

from __future__ import annotations

import subprocess
import sys

from paths import REPO

TOOLS = REPO / "tools"


def run_tool(script: str, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """``python tools/<script> <args>``: its exit code, stdout and stderr (text); ``timeout`` in s."""
    return subprocess.run([sys.executable, str(TOOLS / script), *args], capture_output=True, text=True,
                          timeout=timeout)
