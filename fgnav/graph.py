"""Graph assembly: one small function per factor family.

Two routes share the residuals of ``factors/``:

* bulk (batch Gauss–Newton): ``linearize_<family>(family, X)`` evaluates the family's
  residual for all its rows at once and returns pre-whitened rows ``(k, A, b)`` with
  ``A`` of shape (M, m, 6) on the state of epoch ``k`` and ``b = -e/sigma``
  (so the linear problem is ``|| A dx - b ||^2``);
* incremental (iSAM2, fixed-lag): ``factors_<family>(family, rows, key)`` returns the
  ``gtsam.CustomFactor`` objects of the given rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.adapters import whiten
from factors.altimeter import altitude_residual, make_altitude_factor
from factors.direction import earth_direction_residual, make_earth_direction_factor
from factors.limb import limb_radius_residual, make_limb_radius_factor
from factors.refraction import make_refraction_factor, refraction_residual, refraction_sigma_m
from fgnav.constants import R_EARTH_M


def _pad6(H_r: np.ndarray) -> np.ndarray:
    """Jacobians with respect to position (M,m,3) -> with respect to the state (M,m,6)."""
    out = np.zeros(H_r.shape[:-1] + (6,))
    out[..., :3] = H_r
    return out


def _prior_rows(fam, X, sl):
    """Prior on position (sl = 0:3) or velocity (3:6): e = x - x_prior, H = [I 0] or [0 I]."""
    e = X[fam.k, sl] - fam.values["xyz"]
    H = np.zeros((len(fam), 3, 6))
    H[:, :, sl] = np.eye(3)
    A, b = whiten(e, H, fam.sigma)
    return fam.k, A, b, e


def linearize_prior_position(fam, X):
    return _prior_rows(fam, X, slice(0, 3))


def linearize_prior_velocity(fam, X):
    return _prior_rows(fam, X, slice(3, 6))


def linearize_earth_direction(fam, X):
    e, H_r = earth_direction_residual(X[fam.k, :3], fam.values["u_eci"])
    A, b = whiten(e, _pad6(H_r), fam.sigma)
    return fam.k, A, b, e


def linearize_limb_radius(fam, X):
    e, H_r = limb_radius_residual(X[fam.k, :3], fam.values["rho_rad"], fam.values["r_limb_m"])
    A, b = whiten(e, _pad6(H_r), fam.sigma)
    return fam.k, A, b, e


def linearize_altitude(fam, X):
    e, H_r = altitude_residual(X[fam.k, :3], fam.values["h_m"], fam.values["r_ref_m"])
    A, b = whiten(e, _pad6(H_r), fam.sigma)
    return fam.k, A, b, e


def refraction_sigma(fam, X=None) -> np.ndarray:
    """Tangent-height 1σ (m) of each refraction row: angle error and model error combined.

    The residual ``e = h_a(r; s, gamma) - h(gamma)`` depends on the measured gamma through
    both terms, ``de/dgamma = |r.s| sec^2(gamma) + H/gamma``: with the states ``X`` (N, 6)
    the line-of-sight range ``|r.s|`` is taken at ``X`` (the Monte Carlo of
    tests/test_factors_refraction.py matches only with it; +13 % on the angle term in LEO).
    Without ``X`` (single-factor route, no state at hand) Li et al. 2017's ``H/gamma`` alone is
    used.
    """
    los = 0.0
    if X is not None:
        los = np.abs(np.sum(np.asarray(X)[fam.k, :3] * fam.values["s_eci"], axis=1))
    return refraction_sigma_m(fam.values["gamma_rad"], fam.sigma, fam.values["sigma_model_m"],
                              los_range_m=los)


def linearize_refraction(fam, X):
    e, H_r = refraction_residual(X[fam.k, :3], fam.values["s_eci"], fam.values["gamma_rad"],
                                 np.full(len(fam), R_EARTH_M), np.zeros(len(fam)))
    A, b = whiten(e, _pad6(H_r), refraction_sigma(fam, X))
    return fam.k, A, b, e


LINEARIZERS = {
    "prior_position": linearize_prior_position,
    "prior_velocity": linearize_prior_velocity,
    "earth_direction": linearize_earth_direction,
    "limb_radius": linearize_limb_radius,
    "altitude": linearize_altitude,
    "refraction": linearize_refraction,
}
"""Families the smoothers use, by log kind ('attitude' rows are used by build_pass)."""


PRIOR_KINDS = ("prior_position", "prior_velocity")


@dataclass
class Rows:
    """All whitened measurement rows of a pass, as scalar rows sorted by epoch."""

    k: np.ndarray            # (R,) epoch index of each row
    A: np.ndarray            # (R, 6) whitened Jacobian rows (robust weights applied)
    b: np.ndarray            # (R,) whitened right-hand side, -e/sigma (weights applied)
    residuals: dict          # kind -> (M, m) whitened residuals e/sigma (no weights)
    row_kind: np.ndarray     # (R,) kind of each row
    weights: dict            # kind -> (M,) robust weight of each measurement (1 without)


def linearize_all(p, X, robust=None, rejected=None) -> Rows:
    """Linearize every measurement family of a pass at the states ``X`` (N, 6).

    ``robust``: a :class:`fgnav.robust.RobustKernel` applied to every measurement except
    the priors (IRLS: rows scaled by sqrt(w) of the measurement's whitened norm).
    ``rejected``: kind -> (M,) bool, measurements given zero weight (outliers).
    """
    ks, As, bs, res, tags, wts = [], [], [], {}, [], {}
    for kind, fam in p.families.items():
        fn = LINEARIZERS.get(kind)
        if fn is None:
            continue
        k, A, b, e = fn(fam, X)
        m = A.shape[1]
        res[kind] = -b.reshape(len(fam), m)  # whitened residual e/sigma
        if robust is not None and kind not in PRIOR_KINDS:
            w = robust.weights(np.linalg.norm(b.reshape(len(fam), m), axis=1))
            sw = np.sqrt(w)
            A = A * sw[:, None, None]
            b = b * sw[:, None]
        else:
            w = np.ones(len(fam))
        if rejected is not None and kind in rejected:
            w = np.where(rejected[kind], 0.0, w)
            keep = (~rejected[kind]).astype(float)
            A = A * keep[:, None, None]
            b = b * keep[:, None]
        wts[kind] = w
        ks.append(np.repeat(k, m))
        As.append(A.reshape(-1, 6))
        bs.append(b.reshape(-1))
        tags.append(np.full(len(fam) * m, kind, dtype=object))
    k = np.concatenate(ks)
    order = np.argsort(k, kind="stable")
    return Rows(k[order], np.concatenate(As)[order], np.concatenate(bs)[order], res,
                np.concatenate(tags)[order], wts)


# ---- incremental route ---------------------------------------------------------------

def make_state_prior_factor(key, sl, mean, sigma):
    """A prior on part of a Vector6 state (position: sl = 0:3, velocity: 3:6).

    Error e = x[sl] - mean (unwhitened, m or m/s); H = [I 0] or [0 I] (3x6).
    """
    import gtsam

    H = np.zeros((3, 6))
    H[:, sl] = np.eye(3)
    mean = np.array(mean, dtype=float)

    def error(this, values, jacobians):
        if jacobians is not None:
            jacobians[0] = H
        return values.atVector(this.keys()[0])[sl] - mean

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(3, float(sigma)), [key], error)


def factors_for_rows(kind, fam, rows, key, robust=None, x_guess=None):
    """CustomFactors (iSAM2 route) for the given rows of a family, all on state ``key``.

    ``robust``: a :class:`fgnav.robust.RobustKernel` wrapping the noise model of every
    measurement but the priors. ``x_guess`` (6,): the state's first guess, for noise that
    depends on geometry (the refraction line-of-sight term, as in the batch route).
    """
    import gtsam

    out = []
    dim = {"earth_direction": 2}.get(kind, 1)

    def noise(sigma):
        if robust is None or kind in PRIOR_KINDS:
            return sigma
        return robust.gtsam_noise(gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma)))

    for j in rows:
        if kind == "prior_position":
            out.append(make_state_prior_factor(key, slice(0, 3), fam.values["xyz"][j], fam.sigma[j]))
        elif kind == "prior_velocity":
            out.append(make_state_prior_factor(key, slice(3, 6), fam.values["xyz"][j], fam.sigma[j]))
        elif kind == "earth_direction":
            out.append(make_earth_direction_factor(key, fam.values["u_eci"][j], noise(fam.sigma[j])))
        elif kind == "limb_radius":
            out.append(make_limb_radius_factor(key, fam.values["rho_rad"][j],
                                               fam.values["r_limb_m"][j], noise(fam.sigma[j])))
        elif kind == "altitude":
            out.append(make_altitude_factor(key, fam.values["h_m"][j], fam.values["r_ref_m"][j],
                                            noise(fam.sigma[j])))
        elif kind == "refraction":
            sub = fam.subset(np.array([j]), 0)
            sig = refraction_sigma(sub, None if x_guess is None else np.asarray(x_guess)[None])[0]
            out.append(make_refraction_factor(key, fam.values["s_eci"][j], fam.values["gamma_rad"][j],
                                              noise(sig), R_EARTH_M, 0.0))
    return out
