"""Simulated attitude-free angles: near body - star, near body's limb - star, body - body.

The instrument (a sextant: the INS/CNS lecture's "near body / spacecraft / far body" and "near
body / spacecraft / near body" angle measurements) measures the angle between two apparent
lines of sight; its readings are that angle from the truth plus Gaussian noise of 1σ
``spec.sigma_deg``: ``A = A_true + sigma n``. ``A_true`` is computed here on its own, not by
the model's kernel (``factors.celestial_angles``), the way an almanac computes an apparent
place (Urban & Seidelmann 2013, sec. 7.2): in the barycentric frame (the frame origin's
barycentric state from ERFA ``epv00``), each near body where it was when its light left it
(the light time iterated to convergence on the ephemeris), the star at its catalogue
direction, every line of sight then aberrated by the observer's barycentric velocity with
ERFA ``ab``; the limb form's near limb is the point of the aberrated limb circle nearest the
apparent star (searched on the circle). The ephemeris error of ``factors.planets`` is not
simulated.

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

from factors.aberration import SPEED_OF_LIGHT_MPS
from factors.constants import AU_M, DEG, R_EARTH_M, R_SUN_M
from factors.planets import origin_state_bcrs
from fgnav.errors import UserError
from fgnav.io.log_csv import BODIES
from fgnav.models.bodies import body_position_eci_m, body_velocity_mps, frame_velocity_bcrs_mps
from fgnav.simulate.body_directions import occulted_by_earth
from fgnav.time import j2000_seconds
from fgnav.vision.catalogue import decimal_year, load_catalogue

__all__ = ["R_MOON_M", "R_SUN_M", "body_position_eci_m", "body_velocity_mps",
           "frame_velocity_bcrs_mps", "apparent_angle", "limb_radius_m",
           "simulate_angle_rows", "MIN_ANGLE_RAD", "LIMB_MARGIN_RAD"]

R_MOON_M = 1737.4e3
"""Mean radius of the Moon, m (IAU WG on Cartographic Coordinates, Archinal et al. 2011)."""
MIN_ANGLE_RAD = 5.0 * DEG
"""Smallest angle (and pi minus the largest) a simulated reading makes."""
LIMB_MARGIN_RAD = 2.0 * DEG
"""A star closer than this to a body's disc is not measured (limb glare)."""
_LIGHT_TIME_ITERATIONS = 4


def _bcrs_body(name, t, centre):
    """Barycentric position (N, 3), m, of a near body at the epochs ``t`` (N,)."""
    return body_position_eci_m(name, t, centre) + origin_state_bcrs(t, centre)[0]


def _natural_direction(name, tj, o_bcrs_m, centre, r_limb_m=0.0):
    """Unit direction (N, 3) from the observer at ``o_bcrs_m`` (N, 3, barycentric, at ``tj``)
    to the body's centre where it was a light time earlier, and that distance (N,), m. The
    light time is the centre's, or with ``r_limb_m`` the limb's, ``sqrt(d^2 - R^2)/c`` (the
    tangent points, all at that distance, are what is seen: from LEO the Earth's limb is 14 ms
    nearer than its centre, 420 m of the Earth's orbital motion)."""
    w = _bcrs_body(name, tj, centre) - o_bcrs_m
    for _ in range(_LIGHT_TIME_ITERATIONS):
        d2 = np.sum(w * w, axis=1)
        tau = np.sqrt(d2 - r_limb_m ** 2 if r_limb_m else d2) / SPEED_OF_LIGHT_MPS
        w = _bcrs_body(name, tj - tau, centre) - o_bcrs_m
    d = np.linalg.norm(w, axis=1)
    return w / d[:, None], d


def _aberrated(n, beta, sun_distance_au):
    """ERFA ``ab``: the proper direction of the natural unit directions ``n`` (..., 3) for an
    observer moving at ``beta`` (..., 3, units of c)."""
    import erfa

    bm1 = np.sqrt(1.0 - np.sum(beta * beta, axis=-1))
    return erfa.ab(n, beta, sun_distance_au, bm1)


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _nearest_limb_angle(n_b, rho, beta, sun_au, s_app):
    """Angle (M,) from the apparent stars ``s_app`` (M, 3) to the nearest point of the
    aberrated limb circles (centres ``n_b`` (M, 3), radii ``rho`` (M,) rad): the circle's
    points ``cos(rho) n_b + sin(rho) (cos(phi) e1 + sin(phi) e2)`` aberrated and searched in
    ``phi`` on three nested grids (721, 201, 201 points: the last spacing 1e-6 rad)."""
    e1 = s_app - np.sum(s_app * n_b, axis=1)[:, None] * n_b
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(n_b, e1)
    centre, half = np.zeros(len(n_b)), np.full(len(n_b), np.pi)
    for n_grid in (721, 201, 201):
        phi = centre[:, None] + half[:, None] * np.linspace(-1.0, 1.0, n_grid)[None, :]
        pts = (np.cos(rho)[:, None, None] * n_b[:, None, :]
               + np.sin(rho)[:, None, None] * (np.cos(phi)[..., None] * e1[:, None, :]
                                               + np.sin(phi)[..., None] * e2[:, None, :]))
        app = _aberrated(pts, beta[:, None, :], sun_au[:, None])
        f = _angle(app, s_app[:, None, :])
        k = np.argmin(f, axis=1)
        centre = phi[np.arange(len(k)), k]
        best = f[np.arange(len(k)), k]
        half = 2.0 * half / (n_grid - 1)
    return best


def apparent_angle(tj, x_true, centre, body, *, stars=None, body2=None, r_limb_m=0.0):
    """The angle (M,), rad, between apparent lines of sight (module docstring) at the epochs
    ``tj`` (M,) (s after J2000 TT) from the true states ``x_true`` (M, 6) (the pass's frame):
    between ``body``'s centre (or, ``r_limb_m > 0``, its near limb) and the catalogue stars
    ``stars`` (M, 3), or between ``body`` and ``body2``."""
    tj = np.asarray(tj, dtype=float)
    x = np.asarray(x_true, dtype=float).reshape(-1, 6)
    o_p, o_v = origin_state_bcrs(tj, centre)
    o_p = o_p.reshape(-1, 3) + x[:, :3]
    beta = (o_v.reshape(-1, 3) + x[:, 3:]) / SPEED_OF_LIGHT_MPS
    sun_au = np.linalg.norm(_bcrs_body("sun", tj, centre) - o_p, axis=1) / AU_M
    n_b, d_b = _natural_direction(body, tj, o_p, centre, r_limb_m)
    a_b = _aberrated(n_b, beta, sun_au)
    if stars is None:
        n_2, _ = _natural_direction(body2, tj, o_p, centre)
        return _angle(a_b, _aberrated(n_2, beta, sun_au))
    s = np.asarray(stars, dtype=float).reshape(-1, 3)
    s_app = _aberrated(s / np.linalg.norm(s, axis=1)[:, None], beta, sun_au)
    if not r_limb_m:
        return _angle(a_b, s_app)
    a_c = _angle(a_b, s_app)
    rho = np.arcsin(r_limb_m / d_b)
    out = _nearest_limb_angle(n_b, rho, beta, sun_au, s_app)
    return np.where(a_c >= rho, out, -out)


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
        ok = seen & _seen(spec.body2, r, p2, e)
        i = np.flatnonzero(ok)
        a = apparent_angle(tj[i], np.asarray(x_true, dtype=float)[i], centre, spec.body,
                           body2=spec.body2)
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
    a = apparent_angle(tj[k_out], np.asarray(x_true, dtype=float)[k_out], centre, spec.body,
                       stars=s_out, r_limb_m=R_limb) + sig * rng.standard_normal(len(t_out))
    xyz = np.column_stack([a, np.full(len(t_out), R_limb if limb else np.nan),
                           np.full(len(t_out), np.nan)])
    extra = {"body": np.full(len(t_out), code), "star_x": s_out[:, 0], "star_y": s_out[:, 1],
             "star_z": s_out[:, 2]}
    return [(spec.kind, t_out, xyz, sig, extra)]
