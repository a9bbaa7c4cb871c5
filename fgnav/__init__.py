"""fgnav: spacecraft celestial navigation by factor-graph smoothing (GTSAM).

The version is written once, here; pyproject.toml reads it (``[tool.setuptools.dynamic]``).
"""

__version__ = "0.2.0"
