"""Where fgnav finds its data (scenarios, studies, catalogue) and its caches."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path


def data_dir() -> Path:
    """The data the product needs at run time (scenarios, studies, star catalogue): the
    package's own ``fgnav/data`` (``data/`` at the top of a checkout links to it), found with
    ``importlib.resources`` so that an installed wheel finds it wherever it is; the
    FGNAV_DATA environment variable overrides it."""
    env = os.environ.get("FGNAV_DATA")
    if env:
        return Path(env)
    return Path(str(resources.files("fgnav") / "data"))


def cache_dir() -> Path:
    """A writable cache directory (FGNAV_CACHE, else ~/.cache/fgnav)."""
    path = Path(os.environ.get("FGNAV_CACHE", Path.home() / ".cache" / "fgnav"))
    path.mkdir(parents=True, exist_ok=True)
    return path
