"""Sun/Earth/Moon scheme of the INS/CNS lecture: per-epoch attitude and geometric fixes, and the
preprocessing that turns body-frame directions into ECI Earth directions for the estimators.

The INS/CNS lecture ("基于日地月信息的航天器天文导航"), per epoch, with the body-frame unit vectors from
the spacecraft to the Sun ``L_ws``, the Moon ``L_wm`` and the Earth centre ``L_we`` and the
altimeter height ``H``:

1. Earth-relative vectors in the body frame (the lecture's triangle; removes the parallax,
   ~1 deg for the Moon in LEO): ``r_we = (R_e + H) L_we``, ``r_em = r_wm - r_we`` with
   ``|r_wm|`` from ``|r_em| = |r_em^i|`` (ephemeris): ``d_wm^2 - 2 d_wm d_we cos(alpha)
   + d_we^2 = D^2``, ``alpha = acos(L_wm . L_we)``, the root
   ``d_wm = d_we cos(alpha) + sqrt(D^2 - d_we^2 sin^2(alpha))`` (the lecture's law of sines,
   solved directly); the same for the Sun (:func:`earth_relative_body_vector`).
2. Two-vector attitude (TRIAD): ``C_b^i = P_N Q_M^T`` from (``r_em``, ``r_es``) in body and
   ECI (``factors.attitude.triad``). The lecture takes the Moon first; the first vector is
   matched exactly, so by default the more accurate sensor (the Sun: 1' 3σ vs 0.02° 3σ) is
   first (``first=``). Covariance ``factors.attitude.triad_covariance`` (Shuster & Oh).
3. Direct fix ``r = -(R_e + H) C_b^i L_we`` with covariance
   ``P_r = sigma_H^2 u u^T + (R_e + H)^2 R [ [L]x P_phi [L]x^T + sigma_e^2 (I - L L^T) ] R^T``
   (``u = R L``, ``phi`` the attitude error, right perturbation, body frame).

For the estimators (:func:`preprocess_log`), each epoch with an attitude gives an
``earth_direction`` row in ECI, ``u = C_b^i L_we``: its tangent-plane covariance is the
bracket above over ``(R_e + H)^2`` (Earth-sensor noise and attitude error; the two are
independent to ~2e-6 rad, the parallax correction's dependence on ``L_we``). The log format
carries one sigma per direction row, isotropic: the largest eigenvalue of that 2x2
covariance is used (conservative; the anisotropy is reported). Epochs without the Sun or
the Moon keep only the altimeter row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.attitude import triad, triad_covariance
from factors.constants import R_EARTH_M
from factors.planets import moon_position_geo_m, sun_position_geo_m
from factors.geometry import skew, so3_log, tangent_basis
from fgnav.errors import UserError
from fgnav.io.log_csv import log_from_arrays
from fgnav.models.registry import (ALTITUDE, ATTITUDE, EARTH_DIRECTION, EARTH_DIRECTION_BODY,
                                   MOON_DIRECTION_BODY, SUN_DIRECTION_BODY, prior_kinds)
from fgnav.time import j2000_seconds

__all__ = ["SemEpochs", "earth_relative_body_vector", "sem_epochs", "preprocess_log"]


@dataclass
class SemEpochs:
    """Per-epoch products of the INS/CNS lecture geometry (epochs with Sun, Moon, Earth and H).

    ``t_s`` (M,) s from the log's epoch0; ``R_eci_from_body`` (M,3,3) TRIAD attitude;
    ``P_att_rad2`` (M,3,3) its covariance (body frame, right perturbation);
    ``u_earth_eci`` (M,3) Earth direction in ECI; ``C_earth_rad2`` (M,2,2) its covariance in
    ``tangent_basis(u_earth_eci)``; ``sigma_earth_rad`` (M,) the isotropic 1σ used;
    ``h_m`` (M,) altimeter height; ``r_fix_eci_m`` (M,3) direct fix, ``P_fix_m2`` (M,3,3).
    """

    t_s: np.ndarray
    R_eci_from_body: np.ndarray
    P_att_rad2: np.ndarray
    u_earth_eci: np.ndarray
    C_earth_rad2: np.ndarray
    sigma_earth_rad: np.ndarray
    h_m: np.ndarray
    r_fix_eci_m: np.ndarray
    P_fix_m2: np.ndarray


def earth_relative_body_vector(L_w_target_body, L_we_body, d_we_m, d_target_m):
    """Body-frame vector Earth centre -> target from the spacecraft's two directions.

    ``L_w_target_body``, ``L_we_body`` (N,3) unit vectors spacecraft -> target and ->
    Earth centre (body); ``d_we_m`` (N,) spacecraft-Earth distance ``R_e + H``, m;
    ``d_target_m`` (N,) Earth-target distance from the ephemeris, m. Returns (N,3), m
    (the INS/CNS lecture triangle, module docstring step 1).
    """
    Lt = np.asarray(L_w_target_body, dtype=float)
    Le = np.asarray(L_we_body, dtype=float)
    d_we = np.asarray(d_we_m, dtype=float)
    D = np.asarray(d_target_m, dtype=float)
    cos_a = np.sum(Lt * Le, axis=1)
    disc = D ** 2 - d_we ** 2 * (1.0 - cos_a ** 2)
    if np.any(disc < 0):
        raise UserError("Sun/Moon triangle has no solution (target closer than the Earth?)")
    d_wt = d_we * cos_a + np.sqrt(disc)
    return d_wt[:, None] * Lt - d_we[:, None] * Le


def sem_epochs(t_s, t0_j2000_s, L_ws_body, L_wm_body, L_we_body, h_m, *, sigma_sun_rad,
               sigma_moon_rad, sigma_earth_rad, sigma_h_m, r_ref_m=R_EARTH_M, first="sun"):
    """The INS/CNS lecture geometry at epochs ``t_s`` (M,) (s from an epoch ``t0_j2000_s`` s after
    J2000): TRIAD attitude, ECI Earth direction with its covariance, direct fix.

    Directions (M,3) unit, body frame, spacecraft -> Sun / Moon / Earth centre; ``h_m`` (M,)
    altimeter height above ``r_ref_m``; sigmas 1σ (rad per tangent axis, m).
    """
    if first not in ("sun", "moon"):
        raise UserError(f"first must be 'sun' or 'moon', got {first!r}")
    t = np.asarray(t_s, dtype=float)
    tj = t0_j2000_s + t
    r_s, r_m = sun_position_geo_m(tj), moon_position_geo_m(tj)
    Le = np.asarray(L_we_body, dtype=float)
    h = np.asarray(h_m, dtype=float)
    d_we = r_ref_m + h
    es_b = earth_relative_body_vector(L_ws_body, Le, d_we, np.linalg.norm(r_s, axis=1))
    em_b = earth_relative_body_vector(L_wm_body, Le, d_we, np.linalg.norm(r_m, axis=1))
    if first == "sun":
        R = triad(es_b, em_b, r_s, r_m)
        P_att = triad_covariance(es_b, em_b, sigma_sun_rad, sigma_moon_rad)
    else:
        R = triad(em_b, es_b, r_m, r_s)
        P_att = triad_covariance(em_b, es_b, sigma_moon_rad, sigma_sun_rad)
    u = np.einsum("nij,nj->ni", R, Le)
    K = skew(Le)                                                 # phi x L = -[L]x phi
    C_body = K @ P_att @ np.swapaxes(K, -1, -2) + \
        sigma_earth_rad ** 2 * (np.eye(3) - Le[:, :, None] * Le[:, None, :])
    C3 = R @ C_body @ np.swapaxes(R, -1, -2)                     # ECI, tangent at u
    B = tangent_basis(u)
    C2 = B @ C3 @ np.swapaxes(B, -1, -2)
    sig_iso = np.sqrt(np.linalg.eigvalsh(C2)[:, -1])
    r_fix = -d_we[:, None] * u
    P_fix = sigma_h_m ** 2 * u[:, :, None] * u[:, None, :] + d_we[:, None, None] ** 2 * C3
    return SemEpochs(t, R, P_att, u, C2, sig_iso, h, r_fix, P_fix)


_SUN, _MOON, _EARTH, _ALT = (SUN_DIRECTION_BODY.kind, MOON_DIRECTION_BODY.kind,
                             EARTH_DIRECTION_BODY.kind, ALTITUDE.kind)


def uses_scheme(log) -> bool:
    """Whether a log holds body-frame Sun or Moon directions, which only this scheme's
    preprocessing (:func:`preprocess_log`) turns into rows the smoothers use."""
    return bool(len(log.select(_SUN)) or len(log.select(_MOON)))


def _rows(log, kind):
    i = log.select(kind)
    return i, np.asarray(log.t_s)[i]


def preprocess_log(log, *, first="sun"):
    """Preprocessing (the INS/CNS lecture's scheme) of a raw log (kinds ``sun_direction_body``,
    ``moon_direction_body``, ``earth_direction_body``, ``altitude``, priors).

    Returns ``(log_eci, epochs)``: a :class:`~fgnav.io.log_csv.MeasurementLog` with the
    priors, every ``altitude`` row, and per epoch with all four measurements an
    ``earth_direction`` row (ECI, isotropic 1σ of the module docstring) and an ``attitude``
    row (TRIAD, 1σ = sqrt of the largest eigenvalue of its covariance); and the
    :class:`SemEpochs`. Sigmas come from the log rows.
    """
    t_all = np.asarray(log.t_s, dtype=float)
    xyz = np.asarray(log.xyz, dtype=float)
    sig = np.asarray(log.sigma, dtype=float)
    found = {}
    for kind in (_SUN, _MOON, _EARTH, _ALT):
        i, t = _rows(log, kind)
        if not len(i):
            raise UserError(f"{log.path}: the Sun/Earth/Moon scheme needs '{kind}' rows")
        _, first_i = np.unique(t, return_index=True)
        found[kind] = dict(zip(t[first_i].tolist(), i[first_i].tolist()))
    common = sorted(set.intersection(*(set(d) for d in found.values())))
    if not common:
        raise UserError(f"{log.path}: no epoch has Sun, Moon, Earth directions and altitude together")
    ix = {k: np.array([found[k][t] for t in common]) for k in found}
    r_ref = xyz[ix[_ALT], 1]
    if np.ptp(r_ref) > 0:
        raise UserError(f"{log.path}: altitude rows must share one reference radius")
    ep = sem_epochs(np.array(common), float(j2000_seconds(log.epoch0)),
                    xyz[ix[_SUN]], xyz[ix[_MOON]], xyz[ix[_EARTH]], xyz[ix[_ALT], 0],
                    sigma_sun_rad=sig[ix[_SUN]], sigma_moon_rad=sig[ix[_MOON]],
                    sigma_earth_rad=sig[ix[_EARTH]][:, None, None],
                    sigma_h_m=sig[ix[_ALT]][:, None, None], r_ref_m=float(r_ref[0]),
                    first=first)
    keep = np.flatnonzero(np.isin(log.kind, prior_kinds() + (_ALT,)))
    n = len(common)
    att_sig = np.sqrt(np.linalg.eigvalsh(ep.P_att_rad2)[:, -1])
    kinds = np.concatenate([np.asarray(log.kind)[keep], [EARTH_DIRECTION.kind] * n,
                            [ATTITUDE.kind] * n])
    t = np.concatenate([t_all[keep], ep.t_s, ep.t_s])
    X = np.concatenate([xyz[keep], ep.u_earth_eci, so3_log(ep.R_eci_from_body)])
    S = np.concatenate([sig[keep], ep.sigma_earth_rad, att_sig])
    out = log_from_arrays(log.epoch0, t, kinds, X, S, path=f"{log.path} (Sun/Earth/Moon preprocessed)",
                          centre=log.centre, schema=log.schema)
    return out, ep
