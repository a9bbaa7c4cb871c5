"""Declared manoeuvres (``manoeuvre`` rows): an impulsive delta-v planned at an epoch, with
its 1-sigma execution error per axis.

A row is no measurement: it changes the motion of the step that ends at its epoch,
``x_k = f(x_{k-1}) + [0; dv]``, ``dv ~ N(planned, sigma^2 I)`` (an impulsive burn in the
state's process, Tapley, Schutz & Born 2004, sec. 4.9), so it has no residual and no
``MeasurementModel``; the pass keeps its rows as ``Pass.manoeuvres`` (:func:`manoeuvre_family`)
and :func:`fgnav.graph.impulses` turns them into the steps' mean and covariance for every
method. Its epoch is an epoch of the pass (the state there is the state just after the burn).
"""

from __future__ import annotations

import math

import numpy as np

from fgnav.io.log_csv import KindSpec, RowError

__all__ = ["MEASUREMENT_MODELS", "LOG_KINDS", "MOTION_KINDS", "MANOEUVRE_KIND",
           "MAX_DELTA_V_MPS", "manoeuvre_values"]

MANOEUVRE_KIND = "manoeuvre"
MAX_DELTA_V_MPS = 1e4
"""Largest planned delta-v a row may give (m/s): beyond it a value is a unit error."""


def _check_delta_v(x, y, z, sigma_model):
    if not math.hypot(x, y, z) <= MAX_DELTA_V_MPS:
        raise RowError("out_of_range", "x,y,z", f"a planned delta-v within {MAX_DELTA_V_MPS:g} "
                       "m/s", f"|dv| = {math.hypot(x, y, z)!r} m/s")


LOG_KINDS = {MANOEUVRE_KIND: KindSpec(
    ("r", "r", "r"), "planned impulsive delta-v at the row's epoch, m/s, EME2000 "
    "(sigma: its 1-sigma execution error per axis, m/s)", 1e-6, 1e3, "m/s",
    check=_check_delta_v)}
"""The ``manoeuvre`` kind's log schema row: x, y, z the planned delta-v (m/s), sigma its
execution error per axis (m/s)."""

MEASUREMENT_MODELS = ()
"""No measurement model: a manoeuvre enters the motion (module docstring)."""
MOTION_KINDS = (MANOEUVRE_KIND,)
"""This module's log kinds that enter the motion instead of the measurements (assembled as
:data:`fgnav.models.registry.MOTION_KINDS`)."""


def manoeuvre_values(log, i) -> dict:
    """The rows ``i`` of a log as the manoeuvre family's values: ``dv_mps`` (M, 3)."""
    return {"dv_mps": np.asarray(log.xyz, dtype=float)[i].reshape(-1, 3)}
