"""Faulty logs made from simulated passes with independent truth (DOP853): outliers, mirrored
directions, a wrong or missing prior, gaps, an unmodelled manoeuvre. For integrity tests and
studies (scripts/study_integrity.py).

Each builder returns ``(log, t_truth_s, x_truth)``: a :class:`fgnav.io.log_csv.MeasurementLog`
with the fault in it and the true states at ``t_truth_s`` (seconds from the log's epoch0).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fgnav.io.log_csv import log_from_arrays
from fgnav.models.registry import EARTH_DIRECTION, PRIOR_POSITION, prior_kinds
from fgnav.orbit import integrate_truth
from fgnav.scenarios import load_scenario
from fgnav.simulate.noise import perturb_directions
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.time import j2000_seconds


def clean(scenario="gto-transfer", seed=0, **opts):
    """A simulated pass as it is: ``(log, t_truth_s, x_truth)``."""
    sim = simulate_pass(load_scenario(scenario).with_options(**opts), seed=seed)
    return sim.log, sim.t_s, sim.x_true


def with_rows(log, *, xyz=None, sigma=None, keep=None, t_s=None):
    """A copy of ``log`` with some arrays replaced and only the rows ``keep`` (bool mask)."""
    t = log.t_s if t_s is None else t_s
    xyz = log.xyz if xyz is None else xyz
    sigma = log.sigma if sigma is None else sigma
    keep = np.ones(len(t), bool) if keep is None else keep
    extra = None if log.extra is None else {k: v[keep] for k, v in log.extra.items()} or None
    return log_from_arrays(log.epoch0, t[keep], np.asarray(log.kind)[keep], xyz[keep],
                           sigma[keep], extra, centre=log.centre, schema=log.schema)


def _direction_rows(fraction, seed, salt, opts):
    """A clean pass, a copy of its xyz, and ``fraction`` of its Earth-direction rows drawn
    at random (the draw seeded by ``salt + seed``)."""
    log, t, x = clean(seed=seed, **opts)
    rng = np.random.default_rng(salt + seed)
    rows = np.flatnonzero(log.kind == EARTH_DIRECTION.kind)
    bad = rng.choice(rows, int(round(fraction * len(rows))), replace=False)
    return log, t, x, log.xyz.copy(), bad, rng


def outliers(fraction=0.05, seed=0, **opts):
    """``fraction`` of the Earth directions replaced by random unit vectors."""
    log, t, x, xyz, bad, rng = _direction_rows(fraction, seed, 1000, opts)
    v = rng.standard_normal((len(bad), 3))
    xyz[bad] = v / np.linalg.norm(v, axis=1, keepdims=True)
    return with_rows(log, xyz=xyz), t, x


def mirrored(fraction=0.3, seed=0, **opts):
    """``fraction`` of the Earth directions replaced by their opposite (u -> -u)."""
    log, t, x, xyz, bad, _ = _direction_rows(fraction, seed, 2000, opts)
    xyz[bad] = -xyz[bad]
    return with_rows(log, xyz=xyz), t, x


def wrong_prior(offset_m=1e8, sigma_m=1e4, seed=0, **opts):
    """The prior position moved by ``offset_m`` along the radial direction, 1-sigma ``sigma_m``."""
    log, t, x = clean(seed=seed, **opts)
    xyz, sigma = log.xyz.copy(), log.sigma.copy()
    i = np.flatnonzero(log.kind == PRIOR_POSITION.kind)
    r = xyz[i]
    xyz[i] = r + offset_m * r / np.linalg.norm(r, axis=1, keepdims=True)
    sigma[i] = sigma_m
    return with_rows(log, xyz=xyz, sigma=sigma), t, x


def without_prior(seed=0, **opts):
    log, t, x = clean(seed=seed, **opts)
    keep = ~np.isin(log.kind, prior_kinds())
    return with_rows(log, keep=keep), t, x


def gap(start_s, length_s, seed=0, **opts):
    """No rows with ``start_s <= t < start_s + length_s`` (the priors at t = 0 stay)."""
    log, t, x = clean(seed=seed, **opts)
    keep = ~((log.t_s >= start_s) & (log.t_s < start_s + length_s))
    return with_rows(log, keep=keep), t, x


def manoeuvre(dv_mps=0.5, at_fraction=0.5, seed=0, scenario="gto-transfer", **opts):
    """An unmodelled impulsive manoeuvre of ``dv_mps`` along the velocity half way through:
    truth integrated in two arcs, the Earth directions after it re-drawn from the new truth
    with the same noise statistics."""
    scn = load_scenario(scenario).with_options(**opts)
    sim = simulate_pass(scn, seed=seed)
    log, t, x = sim.log, sim.t_s.copy(), sim.x_true.copy()
    j = int(at_fraction * (len(t) - 1))
    x_after = x[j].copy()
    x_after[3:] += dv_mps * x_after[3:] / np.linalg.norm(x_after[3:])
    t0 = float(j2000_seconds(log.epoch0))
    x[j:] = integrate_truth(x_after, t[j:] - t[j], j2=scn.truth_j2,
                            third_body=scn.truth_third_body, t0_j2000_s=t0 + t[j],
                            drag=scn.truth_drag or None, srp=scn.truth_srp or None)
    rng = np.random.default_rng(3000 + seed)
    xyz = log.xyz.copy()
    rows = np.flatnonzero((log.kind == EARTH_DIRECTION.kind) & (log.t_s >= t[j]))
    r = x[np.searchsorted(t, log.t_s[rows]), :3]
    xyz[rows] = perturb_directions(-r / np.linalg.norm(r, axis=1, keepdims=True),
                                   log.sigma[rows], rng)
    return with_rows(log, xyz=xyz), t, x


def shifted(log, dt_s):
    """The same rows ``dt_s`` later (for multi-session logs)."""
    return dataclasses.replace(log, t_s=log.t_s + dt_s)
