"""Starlight-refraction sensor simulation (Li et al. 2017 = CN104236546B, claim 1 steps 2-4).

Attitude plan (step 2): the body is Earth pointing (LVLH, ``fgnav.simulate.body_directions``); the
refraction sensor has one or more heads (``spec.azimuths_deg``, measured about nadir from
the body x axis ~ velocity towards body y), each a square field ``spec.fov_deg`` wide whose
centre ray grazes the Earth at tangent height ``spec.boresight_tangent_km``: the centre is
``asin((R_e + h_b)/|r|)`` from nadir, so the lower part of the field sees the Earth, the
upper part the sky (unrefracted stars, >= 50 deg^2 for fields >= 10 deg as Li et al. 2017 ask),
and the refraction band (20-50 km) crosses the field horizontally.

Stars (step 3): the project's BSC5 catalogue (``fgnav.vision.catalogue``, V <=
``spec.vmag_max``, proper motion to the pass epoch) rotated into each head. The ray crosses the
atmosphere, at rest in the geocentric frame, along the star's geocentric apparent direction
``s_g = ab(s, v_E/c)``: the catalogue direction ``s`` aberrated by the Earth's barycentric
velocity ``v_E`` (relativistic stellar aberration, Urban & Seidelmann 2013, *Explanatory
Supplement to the Astronomical Almanac*, eq. 7.40; ~20 arcsec; ``factors.aberration``); the
spacecraft's own velocity changes the direction its camera sees (the field test uses
``ab(s, (v_E + v)/c)``) but not the ray's path. For that direction ``s_g`` at the true
position ``r`` the refracted ray's tangent height ``h`` solves the factor's own geometry (``factors.refraction.apparent_tangent_height_m`` with
``R_e``, ``a = 0``):

    h = sqrt(|r|^2 - (r.s)^2) + |r.s| tan(gamma_real(h)) - R_e,

(a scalar root, Newton; ``h - q + R_e`` is increasing since gamma decreases with h), with
the real atmosphere ``gamma_real(h) = gamma_model(h + dh_model)``, ``dh_model = b(t) +
N(0, sigma_model_m^2)`` per star: the inverse model then returns ``h + dh_model``, which is
Li et al. 2017's "atmosphere-model error added to the tangent height" (step 4). Li et al.
draw it white per star (``b = 0``, the default); a real model's error is mostly a slowly
varying bias ``b(t)`` of the whole profile (:func:`refraction_bias_path_m`: the sensor keys
``model_bias_m``, ``model_bias_drift_m_per_h``, ``model_bias_random_walk_m_per_sqrt_h``),
the same for every star of an epoch; ``factors.refraction.refraction_residual(...,
bias_m=b)`` is zero at the truth for it. The measured angle
is ``gamma_real(h) + U(-D, D)``, ``D = gamma_halfwidth_arcsec`` (Li et al. 2017's uniform
refraction-angle error). Stars whose ray grazes in the valid band
(``factors.refraction.REFRACTION_VALID_BAND_M``) give ``refraction`` rows (catalogue
direction, ECI; ``sigma = D/sqrt(3)``; ``gamma``; ``sigma_model_m``); stars whose straight
ray passes > 100 km above the surface are unrefracted and give the attitude: one
``attitude`` row per epoch with >= 3 of them, its 1σ per axis
``star_sigma_arcsec / sqrt(n)``. The Earth is a sphere of radius ``R_e`` here, as in the
factor (``a = 0``).
"""

from __future__ import annotations

import numpy as np

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.constants import ARCSEC, DEG, R_EARTH_M
from factors.geometry import so3_exp, so3_log
from factors.refraction import REFRACTION_VALID_BAND_M, refraction_model
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.time import j2000_seconds
from fgnav.vision.catalogue import decimal_year, load_catalogue

__all__ = ["UNREFRACTED_MIN_HEIGHT_M", "head_frames_body", "true_tangent_height_m",
           "simulate_refraction_rows", "SIGMA_FLOOR_RAD", "has_model_bias",
           "refraction_bias_path_m", "MODEL_BIAS_KEYS"]

UNREFRACTED_MIN_HEIGHT_M = 100e3
"""A star whose straight ray passes higher than this above R_e counts as unrefracted, m."""

SIGMA_FLOOR_RAD = 1e-9
"""Logged angle 1σ when the angle error is switched off (D = 0), rad (the log needs > 0)."""


def head_frames_body(r_norm_m, azimuths_deg, boresight_tangent_m, r_earth_m=R_EARTH_M):
    """Head frames in the body (LVLH) frame: (H, 3, 3), columns (horizontal, up, boresight).

    Boresight ``b = (sin t cos a, sin t sin a, cos t)``, ``t = asin((R_e + h_b)/|r|)`` from
    nadir (body z); ``up`` points away from the Earth in the vertical plane of ``b``.
    """
    t = np.arcsin((r_earth_m + boresight_tangent_m) / r_norm_m)
    out = []
    for a in np.asarray(azimuths_deg, dtype=float) * DEG:
        b = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
        up = np.array([-np.cos(t) * np.cos(a), -np.cos(t) * np.sin(a), np.sin(t)])
        hz = np.cross(up, b)
        out.append(np.column_stack([hz, up, b]))
    return np.array(out)


def true_tangent_height_m(q_m, los_m, model, dh_model_m=0.0, r_earth_m=R_EARTH_M, iters=30):
    """Tangent height ``h`` (m) of the refracted ray: root of
    ``h = q + los tan(gamma_model(h + dh)) - R_e`` (``q = sqrt(|r|^2 - (r.s)^2)``,
    ``los = |r.s|``, arrays). Newton from ``h = q - R_e``; converged to < 1 mm."""
    q = np.asarray(q_m, dtype=float)
    los = np.asarray(los_m, dtype=float)
    dh = np.asarray(dh_model_m, dtype=float)
    m = refraction_model(model)
    h = q - r_earth_m
    for _ in range(iters):
        g = m.gamma_rad(h + dh)
        f = q + los * np.tan(g) - r_earth_m - h
        df = los / np.cos(g) ** 2 * (-g / m.scale_height_m) - 1.0
        step = f / df
        h = h - step
        if np.all(np.abs(step) < 1e-4):
            break
    return h


MODEL_BIAS_KEYS = ("model_bias_m", "model_bias_drift_m_per_h",
                   "model_bias_random_walk_m_per_sqrt_h")
"""The scenario keys of the atmosphere-model bias path (:func:`refraction_bias_path_m`): its
value at the pass start (m), its drift (m/h) and its random walk (m/sqrt(h))."""


def has_model_bias(spec):
    """True when the refraction sensor ``spec`` has a non-zero atmosphere-model bias."""
    return bool(spec.model_bias_m or spec.model_bias_drift_m_per_h
                or spec.model_bias_random_walk_m_per_sqrt_h)


def refraction_bias_path_m(spec, t_s, rng):
    """The real atmosphere's tangent-height shift against the model, ``b(t)`` (m), at the
    epochs ``t_s`` (s from the pass start, increasing, (N,)):

        b(t_k) = b0 + d t_k / 3600 + w(t_k),
        w(t_0) = 0,  w(t_k) = w(t_{k-1}) + q sqrt((t_k - t_{k-1}) / 3600) n_k,  n_k ~ N(0, 1),

    ``b0 = spec.model_bias_m`` (m), ``d = spec.model_bias_drift_m_per_h`` (m/h), ``q =
    spec.model_bias_random_walk_m_per_sqrt_h`` (m/sqrt(h)): a constant plus a linear drift
    plus a Wiener process sampled at ``t_s`` (1σ ``q sqrt(t_h)`` after ``t_h`` hours; the
    exact discrete form of a random walk with process noise ``q^2 dt``, Bar-Shalom, Li &
    Kirubarajan 2001, ch. 6, so a smoother that models ``b`` as that random walk has the
    truth's own process). ``rng`` (a numpy Generator) is drawn from only when ``q > 0``.
    """
    t = np.asarray(t_s, dtype=float)
    b = spec.model_bias_m + spec.model_bias_drift_m_per_h * t / 3600.0
    q = spec.model_bias_random_walk_m_per_sqrt_h
    if q > 0 and len(t) > 1:
        steps = q * np.sqrt(np.diff(t) / 3600.0) * rng.standard_normal(len(t) - 1)
        b = b + np.concatenate([[0.0], np.cumsum(steps)])
    return b


def simulate_refraction_rows(spec, t_s, x_true, epoch0, rng, model="exponential-seed004",
                             catalogue=None, bias_m=None):
    """Rows of the refraction sensor ``spec`` at epochs ``t_s`` (``pass_sim`` protocol):
    a list of ``(kind, t, xyz, sigma[, extra])`` chunks: the refracted stars under the
    sensor's kind (``spec.kind``, ``refraction``) and the attitude from the unrefracted ones
    (``attitude``). ``x_true`` (N, 6) truth at ``t_s``; ``rng`` a numpy Generator;
    ``bias_m`` the atmosphere-model bias ``b(t)`` at ``t_s`` ((N,) m, from
    :func:`refraction_bias_path_m`; None = 0), added to every star's model error."""
    if catalogue is None:
        catalogue = load_catalogue(epoch_year=decimal_year(epoch0),
                                   vmag_max=spec.vmag_max)
    S = catalogue.u_eci
    m = refraction_model(model)
    D = spec.gamma_halfwidth_arcsec * ARCSEC
    sig_g = max(D / np.sqrt(3.0), SIGMA_FLOOR_RAD)
    half = 0.5 * spec.fov_deg * DEG
    tan_half = np.tan(half)
    R_all = lvlh_R_eci_from_body(x_true)
    t_r, s_r, g_r, t_a, w_a, sig_a = [], [], [], [], [], []
    h_lo, h_hi = REFRACTION_VALID_BAND_M
    t_s = np.asarray(t_s, dtype=float)
    v_earth = earth_velocity_bcrs_mps(float(j2000_seconds(epoch0)) + t_s)
    for n, t in enumerate(t_s):
        r = x_true[n, :3]
        rn = float(np.linalg.norm(r))
        heads = head_frames_body(rn, spec.azimuths_deg, spec.boresight_tangent_km * 1e3)
        # the camera sees every star aberrated by the spacecraft's barycentric velocity
        s_seen, _ = apparent_direction(S, np.broadcast_to(v_earth[n] + x_true[n, 3:6], S.shape))
        s_body = s_seen @ R_all[n]                    # (M, 3): R^T s' for every star
        in_field = np.zeros(len(S), dtype=bool)
        for F in heads:
            c = s_body @ F                            # (M, 3): horizontal, up, boresight
            ok = c[:, 2] > 0
            in_field |= ok & (np.abs(c[:, 0]) <= tan_half * c[:, 2]) & \
                (np.abs(c[:, 1]) <= tan_half * c[:, 2])
        idx = np.flatnonzero(in_field)
        if not len(idx):
            continue
        s_cat = S[idx]
        s, _ = apparent_direction(s_cat, np.broadcast_to(v_earth[n], s_cat.shape))  # the ray
        p = s @ r
        q = np.sqrt(np.maximum(rn * rn - p * p, 0.0))
        ahead = p < 0                                  # closest approach in front
        clear = ~ahead | (q - R_EARTH_M > UNREFRACTED_MIN_HEIGHT_M)
        cand = np.flatnonzero(ahead & (q - R_EARTH_M > h_lo - 10e3) & (q - R_EARTH_M < h_hi + 10e3))
        dh = spec.sigma_model_m * rng.standard_normal(len(cand))
        if bias_m is not None:
            dh = dh + bias_m[n]
        h = true_tangent_height_m(q[cand], -p[cand], m, dh)
        keep = (h >= h_lo) & (h <= h_hi)
        g_true = m.gamma_rad(h[keep] + dh[keep])
        g_meas = g_true + (rng.uniform(-D, D, size=len(g_true)) if D > 0 else 0.0)
        t_r.append(np.full(int(keep.sum()), t))
        s_r.append(s_cat[cand[keep]])                 # rows carry the catalogue direction
        g_r.append(g_meas)
        n_clear = int(clear.sum())
        if n_clear >= 3:
            sa = spec.star_sigma_arcsec * ARCSEC / np.sqrt(n_clear)
            R_meas = R_all[n] @ so3_exp(sa * rng.standard_normal(3))
            t_a.append(t)
            w_a.append(so3_log(R_meas))
            sig_a.append(sa)
    chunks = []
    if t_r:
        tt = np.concatenate(t_r)
        g = np.concatenate(g_r)
        chunks.append((spec.kind, tt, np.concatenate(s_r), sig_g,
                       {"gamma": g, "sigma_model_m": np.full(len(tt), float(spec.sigma_model_m))}))
    if t_a:
        chunks.append(("attitude", np.array(t_a), np.array(w_a), np.array(sig_a)))
    return chunks
