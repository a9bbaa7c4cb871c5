"""Where the tests find ../shared (the real data beside the checkout; FGNAV_SHARED overrides)."""

import os
from pathlib import Path

SHARED = Path(os.environ.get("FGNAV_SHARED", Path(__file__).resolve().parents[1].parent / "shared"))
SHARED_DATA = SHARED / "data"
