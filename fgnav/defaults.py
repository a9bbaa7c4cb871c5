"""Defaults shared by the library and the CLI; a light module (no numpy/GTSAM), so that
``fgnav --help`` can quote them without importing the solvers."""

DEFAULT_Q_M2_S3 = 1e-12
"""Default white-acceleration PSD of the motion prior (m^2/s^3): 1e-12 lets the velocity
wander by sqrt(q t) = 0.12 mm/s over 4 h, far below what direction measurements resolve
when the dynamics are modelled (two-body + J2); raise it (e.g. 1e-9 ... 1e-7) when forces are
missing from the model (drag, third body at GEO, manoeuvres)."""
