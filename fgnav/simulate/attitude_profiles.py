"""Attitude truths other than the Earth-pointing plan, and a log's attitude rows under them.

The scenarios fly the Earth-pointing (LVLH) attitude (``body_directions.lvlh_R_eci_from_body``).
For studies of the attitude's motion model the true attitude is given instead:

* :func:`spinning` -- a constant body rate, ``R(t) = R_0 Exp(w t)`` (torque-free spin about a
  principal axis, or any body-fixed rate held by the attitude control);
* :func:`random_walk` -- the attitude's own random-walk process on SO(3),
  ``R_{k+1} = R_k Exp(n_k)``, ``n_k ~ N(0, psd dt I)`` (the estimator's model, for consistency
  checks of the estimator rather than of the model).

:func:`with_attitude_truth` rewrites a log's attitude-dependent rows under such a truth.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_exp, so3_log
from fgnav.io.log_csv import log_from_arrays
from fgnav.models.registry import ATTITUDE, EARTH_DIRECTION_BODY
from fgnav.simulate.noise import perturb_directions

__all__ = ["spinning", "random_walk", "with_attitude_truth"]


def spinning(t_s, omega_body_rad_s, R0=np.eye(3)):
    """``R_eci_from_body`` (N, 3, 3) at ``t_s`` (s) of a body turning at the constant body
    rate ``omega_body_rad_s`` (3,), rad/s, from ``R0`` at t = 0."""
    t = np.asarray(t_s, dtype=float)
    return np.asarray(R0, dtype=float) @ so3_exp(t[:, None] * np.asarray(omega_body_rad_s, float))


def random_walk(t_s, psd_rad2_s, rng, R0=np.eye(3)):
    """``R_eci_from_body`` (N, 3, 3) at ``t_s`` (s) of a random walk on SO(3) of spectral
    density ``psd_rad2_s`` (rad^2/s) from ``R0`` at the first epoch (right increments)."""
    t = np.asarray(t_s, dtype=float)
    steps = so3_exp(rng.normal(0.0, 1.0, (len(t) - 1, 3))
                    * np.sqrt(psd_rad2_s * np.diff(t))[:, None])
    R = np.empty((len(t), 3, 3))
    R[0] = R0
    for k in range(1, len(t)):
        R[k] = R[k - 1] @ steps[k - 1]
    return R


def with_attitude_truth(log, t_truth, x_truth, R_true, rng, *, attitude_every=1,
                        sigma_attitude_rad=1e-4, earth_body_sigma_rad=None):
    """The log with its ``attitude`` and ``earth_direction_body`` rows replaced by rows of the
    true attitude ``R_true`` (N, 3, 3) at the log's unique epochs.

    ``attitude`` rows at one epoch in ``attitude_every`` (the first included): the rotation
    vector of ``R_true Exp(n)``, ``n ~ N(0, sigma_attitude_rad^2 I)`` (a right perturbation,
    as the attitude factor models it); ``earth_direction_body`` rows at every epoch when
    ``earth_body_sigma_rad`` is given: ``R_true^T (-r/|r|)`` rotated by tangent noise of that
    1-sigma per axis, ``r`` from the truth ``x_truth`` (states at ``t_truth``). Other rows
    are kept.
    """
    t_ep = np.unique(np.asarray(log.t_s, dtype=float))
    R_true = np.asarray(R_true, dtype=float)
    keep = ~np.isin(np.asarray(log.kind), [ATTITUDE.kind, EARTH_DIRECTION_BODY.kind])
    k_att = np.arange(0, len(t_ep), attitude_every)
    att = so3_log(R_true[k_att] @ so3_exp(rng.normal(0.0, sigma_attitude_rad, (len(k_att), 3))))
    t = [np.asarray(log.t_s, float)[keep], t_ep[k_att]]
    kinds = [np.asarray(log.kind, dtype=object)[keep], np.full(len(k_att), ATTITUDE.kind, dtype=object)]
    xyz = [np.asarray(log.xyz, float)[keep], att]
    sig = [np.asarray(log.sigma, float)[keep], np.full(len(k_att), sigma_attitude_rad)]
    if earth_body_sigma_rad is not None:
        r = x_truth[np.searchsorted(t_truth, t_ep), :3]
        u = np.einsum("nji,nj->ni", R_true, -r / np.linalg.norm(r, axis=1, keepdims=True))
        t.append(t_ep)
        kinds.append(np.full(len(t_ep), EARTH_DIRECTION_BODY.kind, dtype=object))
        xyz.append(perturb_directions(u, np.full(len(t_ep), earth_body_sigma_rad), rng))
        sig.append(np.full(len(t_ep), earth_body_sigma_rad))
    n_new = sum(len(a) for a in t[1:])
    extra = {c: np.concatenate([np.asarray(v)[keep], np.full(n_new, np.nan)])
             for c, v in (log.extra or {}).items()} or None
    return log_from_arrays(log.epoch0, np.concatenate(t), np.concatenate(kinds),
                           np.concatenate(xyz), np.concatenate(sig), extra,
                           centre=log.centre, schema=log.schema)
