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
"""

from __future__ import annotations

import functools

import numpy as np

from fgnav.constants import AU_M, C_LIGHT_M_S

__all__ = ["NEAR_BODIES", "barycentric_state", "apparent_body"]

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
