"""Where fgnav finds its data (scenarios, studies, catalogue) and its caches."""

from __future__ import annotations

import os
from pathlib import Path


def data_dir() -> Path:
    """The project's ``data/`` directory (override with the FGNAV_DATA environment variable)."""
    env = os.environ.get("FGNAV_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1] / "data"


def cache_dir() -> Path:
    """A writable cache directory (FGNAV_CACHE, else ~/.cache/fgnav)."""
    path = Path(os.environ.get("FGNAV_CACHE", Path.home() / ".cache" / "fgnav"))
    path.mkdir(parents=True, exist_ok=True)
    return path
