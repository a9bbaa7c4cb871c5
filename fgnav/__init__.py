"""fgnav: spacecraft celestial navigation by factor-graph smoothing (GTSAM)."""

__version__ = "0.1.0"
