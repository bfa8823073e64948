"""Where wcbench keeps generated and downloaded things (built-in scenes, embeddings...)."""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "WCBENCH_CACHE"


def cache_dir() -> Path:
    """``$WCBENCH_CACHE`` if set, else the user cache folder (``~/.cache/wcbench`` on Linux)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("wcbench"))
