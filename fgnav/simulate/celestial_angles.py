"""Simulated attitude-free angles: near body - star, near body's limb - star, body - body.

The instrument (a sextant: the INS/CNS lecture's "near body / spacecraft / far body" and "near
body / spacecraft / near body" angle measurements) measures the angle between two lines of
sight; its readings are the geometric angle from the truth plus Gaussian noise of 1σ
``spec.sigma_deg``: ``A = A_true + sigma n`` (the predicted angle of
``factors.celestial_angles``, so model and simulator share one definition of the geometry;
the ephemeris error of ``factors.ephemeris`` is not simulated, and neither is aberration:
the angle between two apparent directions differs from the geometric one by up to
~|v|/c ~ 20 arcsec).

Star choice at each epoch (``spec.stars_per_epoch`` stars from the BSC5 catalogue to
``spec.vmag_max``, proper motion applied): a star is usable when the Earth's disc does not
hide it, it is at least :data:`LIMB_MARGIN_RAD` outside the body's disc (``asin(R/d)``: the
Earth's limb sphere ``spec.r_limb_km`` for the Earth, :data:`R_MOON_M` for the Moon, the
photosphere for the Sun), at least ``spec.min_sun_elongation_deg`` from the Sun (stray
light) and its angle to the body's centre within [:data:`MIN_ANGLE_RAD`, pi -
:data:`MIN_ANGLE_RAD`] (the cone degenerates to a line at 0 and pi). Among the usable stars
the brightest is taken first, then greedily the star farthest (largest smallest angle) from
the ones taken: lines of sight spread over the sky give cones that cut at wide angles
(``spec.star_spread = "axes"``: spread as lines, a star and its antipode being one cone
axis, so that two cones through one body cut at right angles). An
epoch without enough usable stars gives the ones it has; the body itself must be seen (not
hidden by the Earth).
"""

from __future__ import annotations

import numpy as np

from factors.celestial_angles import BODY_BODY, BODY_STAR, predicted_angle
from factors.constants import DEG, R_EARTH_M
from factors.ephemeris import moon_position_eci_m, sun_position_eci_m
from factors.planets import earth_position_helio_m, moon_position_helio_m
from fgnav.errors import UserError
from fgnav.io.log_csv import BODIES
from fgnav.simulate.body_directions import occulted_by_earth
from fgnav.time import j2000_seconds
from fgnav.vision.catalogue import decimal_year, load_catalogue

__all__ = ["R_MOON_M", "R_SUN_M", "body_position_eci_m", "limb_radius_m",
           "simulate_angle_rows", "MIN_ANGLE_RAD", "LIMB_MARGIN_RAD"]

R_MOON_M = 1737.4e3
"""Mean radius of the Moon, m (IAU WG on Cartographic Coordinates, Archinal et al. 2011)."""
R_SUN_M = 6.957e8
"""Nominal solar radius, m (IAU 2015 Resolution B3)."""
MIN_ANGLE_RAD = 5.0 * DEG
"""Smallest angle (and pi minus the largest) a simulated reading makes."""
LIMB_MARGIN_RAD = 2.0 * DEG
"""A star closer than this to a body's disc is not measured (limb glare)."""


def body_position_eci_m(name: str, t_j2000_s, centre: str = "earth") -> np.ndarray:
    """Centre of a near body (one of ``fgnav.io.log_csv.BODIES``), m, (N, 3) at the epochs
    ``t_j2000_s`` (N,), relative to the pass's ``centre`` (EME2000 axes): geocentric, the
    Earth at the origin, the Sun and the Moon from ``factors.ephemeris``; heliocentric
    (``centre="sun"``), the Sun at the origin, the Earth and the Moon from pyerfa
    (``factors.planets``)."""
    t = np.atleast_1d(np.asarray(t_j2000_s, dtype=float))
    if centre == "sun":
        if name == "earth":
            return earth_position_helio_m(t)
        if name == "moon":
            return moon_position_helio_m(t)
        return np.zeros((len(t), 3))
    if name == "sun":
        return sun_position_eci_m(t)
    if name == "moon":
        return moon_position_eci_m(t)
    return np.zeros((len(t), 3))


def limb_radius_m(spec) -> float:
    """Radius of the limb sphere of the sensor's body, m: the Earth's ``spec.r_limb_km``,
    the Moon's mean radius."""
    return spec.r_limb_km * 1e3 if spec.body == "earth" else R_MOON_M


def _disc_radius_m(name, spec):
    return {"sun": R_SUN_M, "moon": R_MOON_M}.get(name, spec.r_limb_km * 1e3)


def _seen(name, r, p, e):
    """Whether the body at ``p`` is not hidden by the Earth (at ``e``) from ``r``."""
    return np.ones(len(r), bool) if name == "earth" else ~occulted_by_earth(r - e, p - e)


def _spread(cand_s, vmag, n, axes=False):
    """Indices of up to ``n`` candidate stars: the brightest, then greedily the farthest from
    the ones taken (module docstring); ``axes``: the farthest as lines (``|cos|``: a star
    and its antipode are the same cone axis, and two cones about one body cut best with
    axes at right angles)."""
    if not len(cand_s):
        return np.zeros(0, dtype=int)
    fold = np.abs if axes else (lambda c: c)
    take = [int(np.argmin(vmag))]
    best = fold(cand_s @ cand_s[take[0]])    # cosine to the nearest taken star
    for _ in range(min(n, len(cand_s)) - 1):
        j = int(np.argmin(best))
        take.append(j)
        best = np.maximum(best, fold(cand_s @ cand_s[j]))
    return np.array(take, dtype=int)


def simulate_angle_rows(spec, t_s, x_true, epoch0, rng, *, star, limb, centre="earth"):
    """Rows of one angle sensor (``fgnav.simulate.pass_sim`` protocol): one chunk
    ``(spec.kind, t, xyz, sigma_rad, extra)`` with x the measured angle (rad), y the limb
    radius (m, limb form) and the extra columns ``body`` (and ``body2``, or the star's
    ``star_x, star_y, star_z``) as codes of ``fgnav.io.log_csv.BODIES``.

    ``star``: body-star angles (else body-body); ``limb``: to the body's near limb.
    ``x_true`` (N, 6) truth at ``t_s`` (s from ``epoch0``), relative to ``centre``
    (:func:`body_position_eci_m`); ``rng`` a numpy Generator.
    """
    if limb and spec.body not in ("earth", "moon"):
        raise UserError(f"sensor {spec.kind}: body = {spec.body!r}: expected a body with a "
                        "limb, earth or moon")
    if not star and spec.body == spec.body2:
        raise UserError(f"sensor {spec.kind}: body and body2 are both {spec.body!r}: expected "
                        "two different bodies")
    t_s = np.asarray(t_s, dtype=float)
    r = np.asarray(x_true, dtype=float)[:, :3]
    tj = float(j2000_seconds(epoch0)) + t_s
    p = body_position_eci_m(spec.body, tj, centre)
    e = body_position_eci_m("earth", tj, centre)
    seen = _seen(spec.body, r, p, e)
    code = float(BODIES.index(spec.body))
    sig = spec.sigma_deg * DEG
    if not star:
        p2 = body_position_eci_m(spec.body2, tj, centre)
        data = np.zeros((len(t_s), 3))
        data[:, 2] = BODY_BODY
        B = np.stack([p, p2], axis=1)
        ok = seen & _seen(spec.body2, r, p2, e)
        i = np.flatnonzero(ok)
        a = predicted_angle(r[i], data[i], B[i])
        keep = (a >= MIN_ANGLE_RAD) & (a <= np.pi - MIN_ANGLE_RAD)
        i, a = i[keep], a[keep]
        a = a + sig * rng.standard_normal(len(i))
        xyz = np.column_stack([a, np.full((len(i), 2), np.nan)])
        extra = {"body": np.full(len(i), code),
                 "body2": np.full(len(i), float(BODIES.index(spec.body2)))}
        return [(spec.kind, t_s[i], xyz, sig, extra)]

    cat = load_catalogue(epoch_year=decimal_year(epoch0), vmag_max=spec.vmag_max)
    S, vmag = cat.u_eci, cat.vmag
    sun = body_position_eci_m("sun", tj, centre)
    R_limb = limb_radius_m(spec) if limb else 0.0
    rad_body = _disc_radius_m(spec.body, spec)
    n_want = int(spec.stars_per_epoch)
    rows_t, rows_s, rows_k = [], [], []
    for k in np.flatnonzero(seen):
        w = p[k] - r[k]
        d = np.linalg.norm(w)
        u = w / d
        c = S @ u
        a = np.arccos(np.clip(c, -1.0, 1.0))
        re_k = r[k] - e[k]   # from the Earth's centre
        rn = np.linalg.norm(re_k)
        earth_rho = np.arcsin(min(R_EARTH_M / rn, 1.0))
        s_sun = (sun[k] - r[k]) / np.linalg.norm(sun[k] - r[k])
        ok = ((np.arccos(np.clip(S @ (-re_k / rn), -1, 1)) > earth_rho + LIMB_MARGIN_RAD)
              & (a > np.arcsin(min(rad_body / d, 1.0)) + LIMB_MARGIN_RAD)
              & (a >= MIN_ANGLE_RAD) & (a <= np.pi - MIN_ANGLE_RAD)
              & (S @ s_sun < np.cos(spec.min_sun_elongation_deg * DEG)))
        cand = np.flatnonzero(ok)
        pick = cand[_spread(S[cand], vmag[cand], n_want, spec.star_spread == "axes")]
        rows_t.append(np.full(len(pick), t_s[k]))
        rows_s.append(S[pick])
        rows_k.append(np.full(len(pick), k))
    t_out = np.concatenate(rows_t) if rows_t else np.zeros(0)
    s_out = np.concatenate(rows_s).reshape(-1, 3) if rows_s else np.zeros((0, 3))
    k_out = np.concatenate(rows_k).astype(int) if rows_k else np.zeros(0, dtype=int)
    data = np.zeros((len(t_out), 3))
    data[:, 1] = R_limb
    data[:, 2] = BODY_STAR
    B = np.stack([p[k_out], s_out], axis=1)
    a = predicted_angle(r[k_out], data, B) + sig * rng.standard_normal(len(t_out))
    xyz = np.column_stack([a, np.full(len(t_out), R_limb if limb else np.nan),
                           np.full(len(t_out), np.nan)])
    extra = {"body": np.full(len(t_out), code), "star_x": s_out[:, 0], "star_y": s_out[:, 1],
             "star_z": s_out[:, 2]}
    return [(spec.kind, t_out, xyz, sig, extra)]
