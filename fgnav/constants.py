"""Physical constants in SI units (one source: ``factors.constants``, re-exported here)."""

from factors.constants import *  # noqa: F401,F403
from factors.constants import __all__  # noqa: F401
