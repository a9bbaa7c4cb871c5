"""Simulated passes for the tests of the attitude in the graph.

:func:`body_earth_scenario`: refraction-leo (its clear stars give an attitude row per epoch)
with an Earth sensor that reports the Earth's direction in the body frame. :func:`with_gyro`
adds rate-gyro rows to a log: the gyro reports, at every epoch of the log but the first, the true LVLH body rate over the
interval since the previous epoch (from the truth of the independent integrator) plus a bias
and white noise; the log's attitude rows are thinned to one epoch in ``attitude_every``.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_log
from fgnav.io.log_csv import log_from_arrays
from fgnav.models.registry import LOG_SCHEMA
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.body_directions import lvlh_R_eci_from_body


def body_earth_scenario(duration_h, sigma_deg=0.02):
    """refraction-leo with a body-frame Earth sensor of ``sigma_deg`` (1σ per axis)."""
    base = load_scenario("refraction-leo")
    return base.with_options(duration_h=duration_h, sensors=(
        base.sensors[0], SensorSpec("earth_direction_body", sigma_deg=sigma_deg)))


def with_gyro(log, t_truth, x_truth, bias_rad_s, sigma_rad_s, rng, attitude_every=6):
    """``(log with gyro rows, true R_eci_from_body at the log's epochs (N, 3, 3))``."""
    t_epochs = np.unique(log.t_s)
    keep = np.ones(len(log.t_s), bool)
    att = np.flatnonzero(log.kind == "attitude")
    k_att = np.searchsorted(t_epochs, log.t_s[att])
    keep[att[k_att % attitude_every != 0]] = False
    R = lvlh_R_eci_from_body(x_truth[np.searchsorted(t_truth, t_epochs)])
    dt = np.diff(t_epochs)
    omega = so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) / dt[:, None] + bias_rad_s + \
        rng.normal(0.0, sigma_rad_s, (len(dt), 3))
    t = np.concatenate([log.t_s[keep], t_epochs[1:]])
    order = np.argsort(t, kind="stable")
    extra = {c: np.concatenate([v[keep], np.full(len(dt), np.nan)])[order]
             for c, v in (log.extra or {}).items()} or None
    kinds = np.concatenate([np.asarray(log.kind)[keep], np.full(len(dt), "gyro", dtype=object)])
    merged = log_from_arrays(log.epoch0, t[order], kinds[order],
                             np.concatenate([log.xyz[keep], omega])[order],
                             np.concatenate([log.sigma[keep], np.full(len(dt), sigma_rad_s)])[order],
                             extra, schema=LOG_SCHEMA)
    return merged, R
