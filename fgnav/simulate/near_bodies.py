"""The simulator's near bodies: what an optical navigation camera sees of the Earth, the
Moon and the Sun, computed independently of the models of ``factors.near_body``.

In the barycentric frame (BCRS, ICRF axes), from DE421 as ``jplephem``'s own reader gives it
(the Earth = EMB - Moon/(1 + EMRAT), the Sun's barycentric series): the observer at
``O(t) = E(t) + r(t)`` (``r`` from the pass's centre, the Earth or the Moon), the body's
centre at its retarded time, ``d = P(t - tau) - O(t)``, ``tau = |d|/c`` iterated to a
fixed point (three passes: the Moon's 1.3 s to 1e-15 s); the apparent direction is
``ab(d/|d|, V_O/c)`` by ERFA's ``ab`` (SOFA ``iauAb``: Urban & Seidelmann 2013, eq. 7.40,
rigorous normalization and the Sun's potential term), with the observer's barycentric
velocity ``V_O = E'(t) + v(t)`` (plus the Moon's velocity about a Moon-centred pass). The
apparent angular radius: in the body's rest frame (its motion uniform over the light time)
the sphere is static and its cone from the observer exact, ``asin(R/|P(t) - O(t)|)``;
eight points of that limb circle and its centre are aberrated by the relative velocity
``V_O - V_B`` (ERFA's ``ab``), the radius the mean angle between them. The models use the first-order planetary
aberration instead; the difference is the models' error (tests/test_near_body.py).

:func:`simulate_near_body_rows` makes the log's rows of an optical navigation camera from
these (``body_direction``, ``body_direction_body``, ``limb_radius`` with a ``body``), the
simulators of :mod:`fgnav.simulate.simulators`.
"""

from __future__ import annotations

import functools

import numpy as np

from fgnav.constants import AU_M, C_LIGHT_M_S, DEG, R_MOON_M, R_SUN_M
from fgnav.errors import UserError
from fgnav.io.log_csv import BODIES
from fgnav.models.registry import BODY_DIRECTION, BODY_DIRECTION_BODY, LIMB_RADIUS
from fgnav.simulate.body_directions import lvlh_R_eci_from_body, occulted_by_earth
from fgnav.simulate.noise import perturb_directions
from fgnav.time import j2000_seconds

__all__ = ["NEAR_BODIES", "barycentric_state", "apparent_body", "limb_sphere_radius_m",
           "simulate_near_body_rows", "NEAR_BODY_FORMS"]

NEAR_BODIES = ("earth", "moon", "sun")
"""The bodies a camera can image in the near-body kinds (the log's ``body`` column)."""


@functools.lru_cache(maxsize=1)
def _jpl():
    import de421
    from jplephem.ephem import Ephemeris

    return Ephemeris(de421)


def barycentric_state(body: str, t_j2000_s) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric position (m) and velocity (m/s) of ``"earth"``, ``"moon"`` or ``"sun"``
    at ``t_j2000_s`` (N,) s after J2000 TDB, from DE421 by jplephem: (N, 3) each."""
    eph = _jpl()
    d = np.atleast_1d(np.asarray(t_j2000_s, dtype=float)) / 86400.0

    def pv(name):
        p, v = eph.position_and_velocity(name, 2451545.0, d)
        return p.T * 1e3, v.T * (1e3 / 86400.0)

    if body == "sun":
        return pv("sun")
    (pb, vb), (pm, vm) = pv("earthmoon"), pv("moon")
    k = 1.0 / (1.0 + eph.EMRAT)
    pe, ve = pb - k * pm, vb - k * vm
    if body == "earth":
        return pe, ve
    if body == "moon":
        return pe + pm, ve + vm
    raise ValueError(f"near body: expected one of {', '.join(NEAR_BODIES)}, found {body!r}")


def apparent_body(body: str, t_j2000_s, x_sc, radius_m: float, centre: str = "earth",
                  aberration: bool = True, light_time: bool = True):
    """What the camera sees of ``body`` from the states ``x_sc`` (N, 6) about ``centre``
    (``"earth"`` or ``"moon"``) at ``t_j2000_s`` (N,): ``(u_apparent (N, 3) unit, ICRF;
    angular radius (N,) rad; light time (N,) s)``. ``aberration``/``light_time`` False give
    the geometric quantities (for measuring what each is worth)."""
    import erfa

    t = np.atleast_1d(np.asarray(t_j2000_s, dtype=float))
    x = np.asarray(x_sc, dtype=float).reshape(-1, 6)
    pc, vc = barycentric_state(centre, t)
    obs, v_obs = pc + x[:, :3], vc + x[:, 3:]
    tau = np.zeros(len(t))
    for _ in range(3 if light_time else 1):
        d = barycentric_state(body, t - tau)[0] - obs
        if light_time:
            tau = np.linalg.norm(d, axis=1) / C_LIGHT_M_S
    d = barycentric_state(body, t - tau)[0] - obs
    dn = np.linalg.norm(d, axis=1)
    u = d / dn[:, None]
    if aberration:
        beta = v_obs / C_LIGHT_M_S
        s_au = np.linalg.norm(obs - barycentric_state("sun", t)[0], axis=1) / AU_M
        u = erfa.ab(u, beta, s_au, np.sqrt(1.0 - np.sum(beta * beta, axis=1)))
    # the limb in the body's rest frame (uniform motion over the light time): a static
    # sphere, whose cone from the observer is exact, then aberrated by the relative velocity
    pb, vb = barycentric_state(body, t)
    g = pb - obs
    gn = np.linalg.norm(g, axis=1)
    ug = g / gn[:, None]
    rho = np.arcsin(radius_m / gn)
    rel = (v_obs if aberration else 0.0 * v_obs) - (vb if light_time else 0.0 * vb)
    if aberration or light_time:
        beta = rel / C_LIGHT_M_S
        bm1 = np.sqrt(1.0 - np.sum(beta * beta, axis=1))
        s_au = np.linalg.norm(obs - barycentric_state("sun", t)[0], axis=1) / AU_M
        uc = erfa.ab(ug, beta, s_au, bm1)
        e1 = np.cross(ug, np.where(np.abs(ug[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        e1 /= np.linalg.norm(e1, axis=1)[:, None]
        e2 = np.cross(ug, e1)
        ang = []
        for phi in np.arange(8) * np.pi / 4:   # 8 limb points, their mean angle from the centre
            limb = (np.cos(rho)[:, None] * ug + np.sin(rho)[:, None]
                    * (np.cos(phi) * e1 + np.sin(phi) * e2))
            la = erfa.ab(limb, beta, s_au, bm1)
            ang.append(np.arctan2(np.linalg.norm(np.cross(uc, la), axis=1), np.sum(uc * la, axis=1)))
        rho = np.mean(ang, axis=0)
    return u, rho, tau


NEAR_BODY_FORMS = {"direction": BODY_DIRECTION.kind, "direction_body": BODY_DIRECTION_BODY.kind,
                   "limb": LIMB_RADIUS.kind}
"""The row forms of :func:`simulate_near_body_rows` and the log kinds they give."""


def limb_sphere_radius_m(body: str, spec=None) -> float:
    """The limb sphere of a body, m: the Moon's mean radius, the Sun's photosphere (IAU 2015
    B3), the Earth's ``spec.r_limb_km`` (the limb sensor's sphere, default 6375 km)."""
    if body == "moon":
        return R_MOON_M
    if body == "sun":
        return R_SUN_M
    return 1e3 * (getattr(spec, "r_limb_km", None) or 6375.0)


def simulate_near_body_rows(spec, t_s, x_true, epoch0, rng, *, form, centre="earth"):
    """Rows ``(kind, t, xyz, sigma, {"body": code})`` of an optical navigation camera
    imaging ``spec.body`` (``pass_sim`` protocol): ``form`` ``"direction"`` (the apparent
    unit vector, EME2000), ``"direction_body"`` (the same in the LVLH body frame of
    ``fgnav.simulate.body_directions.lvlh_R_eci_from_body``) or ``"limb"`` (x = apparent
    angular radius, y = the limb sphere's radius), from :func:`apparent_body`; 1-sigma
    ``spec.sigma_deg`` per tangent axis (deg); no row while the Earth hides the body's centre
    (``occulted_by_earth``) or the camera is inside the limb sphere."""
    if spec.body not in NEAR_BODIES:
        raise UserError(f"sensor {spec.kind}: body = {spec.body!r}: expected one of "
                        f"{', '.join(NEAR_BODIES)}")
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_true, dtype=float).reshape(-1, 6)
    tj = float(j2000_seconds(epoch0)) + t
    radius = limb_sphere_radius_m(spec.body, spec)
    pc = barycentric_state(centre, tj)[0]
    p_geo = barycentric_state(spec.body, tj)[0] - barycentric_state("earth", tj)[0]
    r_geo = x[:, :3] + pc - barycentric_state("earth", tj)[0]
    d = np.linalg.norm(p_geo - r_geo, axis=1)
    seen = d > radius
    if spec.body != "earth":
        seen &= ~occulted_by_earth(r_geo, p_geo)
    i = np.flatnonzero(seen)
    if not len(i):
        return []
    u, rho, _ = apparent_body(spec.body, tj[i], x[i], radius, centre)
    sig = spec.sigma_deg * DEG
    if form == "limb":
        xyz = np.column_stack([rho + sig * rng.standard_normal(len(i)), np.full(len(i), radius),
                               np.full(len(i), np.nan)])
    elif form == "direction":
        xyz = perturb_directions(u, np.full(len(i), sig), rng)
    elif form == "direction_body":
        R = lvlh_R_eci_from_body(x[i]) if centre == "earth" else lvlh_R_eci_from_body(
            np.column_stack([r_geo[i], x[i, 3:]]))
        xyz = perturb_directions(np.einsum("nji,nj->ni", R, u), np.full(len(i), sig), rng)
    else:
        raise ValueError(f"near-body rows: form {form!r}, expected one of {', '.join(NEAR_BODY_FORMS)}")
    return [(NEAR_BODY_FORMS[form], t[i], xyz, sig,
             {"body": np.full(len(i), float(BODIES.index(spec.body)))})]
