"""A small two-spacecraft pass for the formation graph's tests: truth from the independent
integrator (fgnav.orbit.integrate_truth), Earth directions and priors per spacecraft, and
inter-satellite pseudoranges (and carrier phases) from the exact light time on that truth."""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_log
from fgnav.io.log_csv import log_from_arrays
from fgnav.orbit import integrate_truth
from fgnav.time import j2000_seconds, parse_utc

C = 299792458.0
EPOCH = "2025-03-01T00:00:00Z"
X0_A = np.array([6509244.371304875, 0.0, 3713244.835519765, -3737.397235776740, 0.0,
                 8790.602460568101])
OFFSET = np.array([600.0, -700.0, 300.0, 0.05, 0.02, -0.04])   # ~1 km, cm/s


def emission_states(x0, t_rx, p_rx, arm_eci, t0_j2000_s):
    """The transmitter's states (M, 6) at the emission times ``t_rx - tau`` of the exact
    light-time equation ``|p_rx - p_tx(t_rx - tau)| = c tau`` (fixed-point iteration, the
    truth re-integrated at each iterate's times: no interpolation)."""
    tau = np.zeros(len(t_rx))
    for _ in range(4):
        x = integrate_truth(x0, t_rx - tau, t0_j2000_s=t0_j2000_s)
        tau = np.linalg.norm(p_rx - (x[:, :3] + arm_eci), axis=1) / C
    return x, tau


def formation_log(seed=0, duration_s=1800.0, step_s=60.0, *, links=True, carrier=False,
                  lever_arms=False, sigma_dir_rad=1.745e-4, sigma_range_m=0.01,
                  prior_sigma_m=100.0, prior_sigma_mps=0.05,
                  clock_psd=1e-4, sigma_carrier_m=1e-5):
    """``(log, truth)`` with ``truth = {"A": (t, x), "B": (t, x)}`` and the clock's truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s + 1e-9, step_s)
    t0 = float(j2000_seconds(parse_utc(EPOCH)))
    xa = integrate_truth(X0_A, t, t0_j2000_s=t0)
    xb = integrate_truth(X0_A + OFFSET, t, t0_j2000_s=t0)
    rows = []   # (t, kind, xyz, sigma, sc, tx, rx_ant, tx_ant)
    for sc, x in (("A", xa), ("B", xb)):
        err = rng.standard_normal(6) * np.r_[[prior_sigma_m] * 3, [prior_sigma_mps] * 3]
        rows.append((0.0, "prior_position", x[0, :3] + err[:3], prior_sigma_m, sc))
        rows.append((0.0, "prior_velocity", x[0, 3:] + err[3:], prior_sigma_mps, sc))
        for k in range(len(t)):
            u = -x[k, :3] / np.linalg.norm(x[k, :3])
            e1, e2 = np.linalg.svd(u[None])[2][1:]
            u = u + sigma_dir_rad * (rng.standard_normal() * e1 + rng.standard_normal() * e2)
            rows.append((t[k], "earth_direction", u / np.linalg.norm(u), sigma_dir_rad, sc))
    clock = np.cumsum(np.r_[rng.standard_normal() * 3.0,
                            rng.standard_normal(len(t) - 1) * np.sqrt(clock_psd * step_s)])
    antennas, att = {}, {}
    if lever_arms:
        antennas = {("A", "a1"): np.array([0.5, 0.5, 0.5]), ("B", "b0"): np.array([0.5, -0.5, 0.5])}
    amb = {("A", "B"): 12.345, ("B", "A"): -3.21}
    if links:
        Rs = {"A": np.array([_lvlh_R(x) for x in xa]), "B": np.array([_lvlh_R(x) for x in xb])}
        arm = {sc: antennas.get((sc, "a1" if sc == "A" else "b0"), np.zeros(3)) for sc in "AB"}
        if lever_arms:
            for sc in "AB":
                for k in range(len(t)):
                    rows.append((t[k], "attitude", so3_log(Rs[sc][k][None])[0], 1e-6, sc))
        x_of = {"A": xa, "B": xb}
        x0_of = {"A": X0_A, "B": X0_A + OFFSET}
        for rx, tx in (("A", "B"), ("B", "A")):
            p_rx = x_of[rx][:, :3] + Rs[rx] @ arm[rx]
            # the transmitter's antenna turns with its LVLH attitude at the emission time: the
            # attitude at t_rx is used (the rotation over tau, ~3 us, moves it by ~1e-9 m)
            arm_tx = Rs[tx] @ arm[tx]
            _, tau = emission_states(x0_of[tx], t, p_rx, arm_tx, t0)
            rho = C * tau
            s = 1.0 if rx == "A" else -1.0
            ants = ("a1" if rx == "A" else "b0", "a1" if tx == "A" else "b0") if lever_arms \
                else ("", "")
            for k in range(len(t)):
                rows.append((t[k], "isl_pseudorange",
                             [rho[k] + s * clock[k] + sigma_range_m * rng.standard_normal(),
                              np.nan, np.nan], sigma_range_m, rx, tx, *ants))
                if carrier:
                    rows.append((t[k], "isl_carrier_phase",
                                 [rho[k] + s * clock[k] + amb[(rx, tx)]
                                  + sigma_carrier_m * rng.standard_normal(), np.nan, np.nan],
                                 sigma_carrier_m, rx, tx, *ants))
    n = len(rows)
    get = lambda j, d="": [r[j] if len(r) > j else d for r in rows]  # noqa: E731
    extra = {"spacecraft": get(4)}
    if links:
        extra["tx_spacecraft"] = get(5, None)
        if lever_arms:
            extra["rx_antenna"] = get(6, None)
            extra["tx_antenna"] = get(7, None)
    xyz = np.array([np.r_[r[2]].astype(float) for r in rows])
    log = log_from_arrays(EPOCH, get(0), get(1), xyz, get(3), extra, spacecraft=("A", "B"),
                          antennas=antennas)
    return log, {"A": (t, xa), "B": (t, xb), "clock": (t, clock)}


def _lvlh_R(x):
    """R_eci_from_body of a body aligned with the LVLH axes (radial, along-track, normal)."""
    r, v = x[:3], x[3:]
    ex = r / np.linalg.norm(r)
    ez = np.cross(r, v)
    ez /= np.linalg.norm(ez)
    return np.column_stack([ex, np.cross(ez, ex), ez])
