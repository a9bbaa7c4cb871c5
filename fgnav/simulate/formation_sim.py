"""Simulate a formation: several spacecraft, each with its celestial sensors, and the
inter-satellite pseudoranges (and carrier phases) between them, in one measurement log.

Truth: every spacecraft's orbit from the independent integrator
(:func:`fgnav.orbit.integrate_truth`, scipy DOP853), never from the estimator's propagator
or its link model. A link row at receive time ``t`` (receiver R, transmitter T) is::

    rho = |p_R(t) - p_T(t - tau)| + (C_R - C_T)(t) + noise,   |p_R(t) - p_T(t - tau)| = c tau

with the antenna positions ``p = r_eci + R_eci_from_body a_body`` (lever arm ``a_body`` of
the declared antenna; none = the centre of mass) and the exact light time ``tau``, found by
fixed-point iteration on the truth: the transmitter's orbit is integrated again to the
emission epochs ``t - tau`` each iteration (the map contracts by |v|/c ~ 3e-5, so three
iterations leave < 1e-7 m; Montenbruck & Gill, "Satellite Orbits", 2000, section 6.2.2).
``C_A - C_B = clock_m`` is the relative clock ``c (dt_A - dt_B)`` of a linked pair (A, B), A
the one declared first: a random walk per pair (:class:`fgnav.scenarios.RangingSpec`; the
estimator's ``clock_<A>_<B>``, :func:`fgnav.models.isl.clock_pair`), so a row carries
``+clock_m`` when A receives and ``-clock_m`` when B receives (Xing et al., eq. (1), the sign
of c dt on the links received by satellite 1 and 2). Carrier phase: the same plus a constant
float ambiguity per link, m. Any number of spacecraft (two or more) fly, each pair linked
only where a ``[[link]]`` says so.

Attitude: each spacecraft's body frame is the Earth-pointing LVLH frame of its own orbit
turned by its ``yaw_deg`` about the body z axis (nadir); when a link uses an antenna, the
attitude at every link epoch is written as ``attitude`` rows (rotation vector of
``R_eci_from_body``, perturbed in the body frame by ``attitude_sigma_rad``). With
``body_frame`` the direction sensors with a body-frame kind (``earth_direction`` ->
``earth_direction_body``, ...) measure in each spacecraft's own body frame: the noisy ECI
direction turned by the true attitude, ``u_body = R_eci_from_body^T u_eci`` (an isotropic
angular noise stays isotropic under a rotation, so the draws are those of the ECI rows), and
the attitude rows are written whether or not a link uses an antenna.

Random streams (one seed, independent draws): the first spacecraft's celestial rows draw
from ``default_rng(seed)`` exactly as a one-spacecraft pass of the same scenario would (so its
rows equal that pass's), spacecraft k >= 1 from ``default_rng([seed, FORMATION_STREAM, k])``,
the links (the first pair's clock, noise, ambiguities, attitude noise) from
``[seed, FORMATION_STREAM, 0]``, the clock of each further pair q >= 1 (in the order of
:func:`linked_pairs`) from ``[seed, FORMATION_STREAM, 0, q]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.constants import C_LIGHT_M_S
from factors.geometry import so3_exp, so3_log
from fgnav.errors import UserError
from fgnav.io.log_csv import MeasurementLog, write_log
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.io.oem import oem_frame, write_oem
from fgnav.io.truth_params import TRUTH_ATTITUDE_COLUMNS, write_truth_params_csv
from fgnav.models.registry import ATTITUDE, MODELS
from fgnav.scenarios import MAX_DURATION_H, MAX_EPOCHS, Scenario, check_size
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.pass_sim import (chunks_to_log, check_seed, integrate_scenario_truth,
                                     sensor_chunks, sensor_epochs, truth_epochs)
from fgnav.simulate.refraction_sim import has_model_bias
from fgnav.time import parse_utc

__all__ = ["FORMATION_STREAM", "FormationPass", "initial_states", "attitude_law",
           "light_time_range", "simulate_formation_pass", "write_formation_files",
           "TRUTH_CLOCK_CSV", "linked_pairs"]

FORMATION_STREAM = 3
"""Second entropy word of a formation's streams (module docstring)."""
TRUTH_CLOCK_CSV = "truth_clock.csv"
"""The relative clock ``clock_m`` = c (dt_A - dt_B) at the link epochs, m."""
LIGHT_TIME_TOL_M = 1e-7
"""The light-time iteration stops when c |tau_(k+1) - tau_k| < this (m) on every row."""


@dataclass
class FormationPass:
    """A simulated formation pass (SI). ``x_true[id]`` (N, 6) at ``t_s``; ``t_link`` (K,)
    the link epochs with the relative clock ``clock_m`` (K,) of the first pair of
    :func:`linked_pairs` and ``clocks[(a, b)]`` (K,) of every linked pair; ``R_eci_from_body[id]`` (N, 3, 3)
    the true attitudes at ``t_s``; ``ambiguity_m`` one float per ``[[link]]`` (carrier);
    ``light_time_s`` (rows,) per link row of ``log`` in ``isl_rows``."""

    scenario: Scenario
    seed: int
    epoch0: np.datetime64
    ids: tuple
    t_s: np.ndarray
    x_true: dict
    R_eci_from_body: dict
    t_link: np.ndarray
    clock_m: np.ndarray
    log: MeasurementLog
    ambiguity_m: np.ndarray
    attitude_rows: bool
    light_time_s: dict = field(default_factory=dict)
    """Link index -> (K,) light times, s."""
    clocks: dict = field(default_factory=dict)
    """(id a, id b) -> (K,) relative clock c (dt_a - dt_b), m, per linked pair."""


def linked_pairs(scn: Scenario) -> list:
    """The spacecraft pairs (a, b) its ``[[link]]`` tables link, ``a`` declared before ``b``
    (the estimator's clock pairs), the pair of the first two spacecraft first, then in
    declaration order."""
    order = {sc.id: i for i, sc in enumerate(scn.formation.spacecraft)}
    got = {tuple(sorted((ln.rx, ln.tx), key=order.get)) for ln in scn.formation.links}
    return sorted(got, key=lambda ab: (order[ab[0]], order[ab[1]]))


def _rz(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def attitude_law(x_eci, yaw_deg: float) -> np.ndarray:
    """``R_eci_from_body`` (N, 3, 3) of states ``x_eci`` (N, 6): the Earth-pointing LVLH frame
    (:func:`~fgnav.simulate.body_directions.lvlh_R_eci_from_body`: x ahead, y = -orbit
    normal, z nadir) turned by ``yaw_deg`` about its z axis (body vectors rotate by +yaw)."""
    return lvlh_R_eci_from_body(x_eci) @ _rz(np.deg2rad(yaw_deg))


def initial_states(scn: Scenario) -> dict:
    """Each spacecraft's truth state (6,) at t = 0: its own orbit, or the scenario's
    ``[orbit]`` truth ``lead_s`` later (:class:`fgnav.scenarios.SpacecraftSpec`)."""
    out = {}
    for sc in scn.formation.spacecraft:
        if sc.x0_eci is not None:
            out[sc.id] = np.array(sc.x0_eci)
        elif sc.lead_s == 0.0:
            out[sc.id] = np.array(scn.x0_eci)
        else:
            out[sc.id] = integrate_scenario_truth(scn, scn.x0_eci, np.array([sc.lead_s]))[0]
    return out


def light_time_range(scn: Scenario, p_rx_eci_m, t_rx_s, x0_tx, yaw_tx_deg, arm_tx_m,
                     max_iter: int = 8):
    """The geometric range ``|p_R(t) - p_T(t - tau)| = c tau`` (K,) m and ``tau`` (K,) s.

    ``p_rx_eci_m`` (K, 3): the receiving antenna at the receive epochs ``t_rx_s`` (K,);
    the transmitter: truth from ``x0_tx`` at t = 0 (re-integrated to ``t - tau`` each
    iteration), attitude law ``yaw_tx_deg``, lever arm ``arm_tx_m`` (3,) body m. Fixed-point
    iteration ``tau <- |p_R(t) - p_T(t - tau)| / c`` from the instantaneous range."""
    p_rx = np.asarray(p_rx_eci_m, dtype=float)
    t = np.asarray(t_rx_s, dtype=float)
    arm = np.asarray(arm_tx_m, dtype=float)

    def tx_antenna(t_emit):
        x = integrate_scenario_truth(scn, x0_tx, t_emit)
        return x[:, :3] + attitude_law(x, yaw_tx_deg) @ arm

    tau = np.linalg.norm(p_rx - tx_antenna(t), axis=1) / C_LIGHT_M_S
    for _ in range(max_iter):
        rng = np.linalg.norm(p_rx - tx_antenna(t - tau), axis=1)
        step = np.max(np.abs(rng - C_LIGHT_M_S * tau))
        tau = rng / C_LIGHT_M_S
        if step < LIGHT_TIME_TOL_M:
            return rng, tau
    raise RuntimeError(f"light-time iteration did not converge ({step:.3g} m)")


def _check_formation_sensors(scn: Scenario) -> None:
    f = scn.formation
    for i, s in enumerate(scn.sensors):
        if has_model_bias(s) or (s.mounting_sigma_arcsec or 0.0) > 0.0:
            raise UserError(f"scenario {scn.name}: sensor[{i + 1}] ({s.kind}): an atmosphere-"
                            "model bias or a camera mounting error is simulated for one "
                            "spacecraft only; remove it from a formation scenario")
        if s.kind.endswith("_body") and any(sc.yaw_deg != 0.0 for sc in f.spacecraft):
            raise UserError(f"scenario {scn.name}: sensor[{i + 1}] ({s.kind}) measures in the "
                            "body frame, which its simulator takes as the LVLH plan; use it "
                            "only with yaw_deg = 0 on every [[spacecraft]]")


def simulate_formation_pass(scn: Scenario, seed: int = 0, *, max_epochs: int = MAX_EPOCHS,
                            max_duration_h: float = MAX_DURATION_H,
                            body_frame: bool = False) -> FormationPass:
    """Truth and one measurement log for a formation scenario; the same seed gives the same
    numbers (module docstring: the link model, the attitude law, ``body_frame`` and the random
    streams)."""
    check_seed(seed)
    if scn.formation is None:
        raise UserError(f"scenario {scn.name}: one spacecraft (no [[spacecraft]] tables)")
    if scn.manoeuvres:
        raise UserError(f"scenario {scn.name}: manoeuvres are not yet simulated for several "
                        "spacecraft (a formation's graph does not yet take a burn of one "
                        "spacecraft); simulate a one-spacecraft scenario")
    _check_formation_sensors(scn)
    check_size(scn, max_epochs, max_duration_h)
    f, rs = scn.formation, scn.formation.ranging
    ids = f.ids
    epoch0 = parse_utc(scn.epoch)
    t_link = sensor_epochs(scn, rs.period_s)
    t_all = truth_epochs(scn, t_link)
    x0 = initial_states(scn)
    x_true = {i: integrate_scenario_truth(scn, x0[i], t_all) for i in ids}
    yaw = {sc.id: sc.yaw_deg for sc in f.spacecraft}
    R = {i: attitude_law(x_true[i], yaw[i]) for i in ids}
    chunks = []
    for k, i in enumerate(ids):   # each spacecraft's prior and celestial rows, own draws
        words = (seed,) if k == 0 else (seed, FORMATION_STREAM, k)
        got, _ = sensor_chunks(scn, t_all, x_true[i], epoch0, words)
        if body_frame:
            got = [_in_body_frame(c, R[i], t_all) for c in got]
        chunks += [(c[0], c[1], c[2], c[3], {**(c[4] if len(c) > 4 and c[4] else {}),
                                              "spacecraft": np.full(len(c[1]), i, dtype=object)})
                   for c in got]
    rng = np.random.default_rng([seed, FORMATION_STREAM, 0])
    K = len(t_link)
    idx = np.searchsorted(t_all, t_link)

    def random_walk(g):
        return rs.clock_sigma0_m * g.standard_normal() + np.concatenate(
            [[0.0], np.cumsum(rs.clock_random_walk_m_per_sqrt_s * np.sqrt(np.diff(t_link))
                              * g.standard_normal(K - 1))])

    linked = linked_pairs(scn)
    clocks = {ab: random_walk(rng if q == 0 else
                              np.random.default_rng([seed, FORMATION_STREAM, 0, q]))
              for q, ab in enumerate(linked)}
    clock = clocks[linked[0]]
    order = {i: k for k, i in enumerate(ids)}
    arms = {(a, n): np.array(arm) for a, n, arm in f.antennas}
    zero = np.zeros(3)
    attitude_rows = body_frame or any(ln.rx_antenna or ln.tx_antenna for ln in f.links)
    if attitude_rows:
        for i in ids:
            noise = rs.attitude_sigma_rad * rng.standard_normal((K, 3))
            w = so3_log(R[i][idx] @ so3_exp(noise))
            chunks.append((ATTITUDE.kind, t_link, w, rs.attitude_sigma_rad,
                           {"spacecraft": np.full(K, i, dtype=object)}))
    amb = rs.ambiguity_sigma_m * rng.standard_normal(len(f.links))
    code_noise = rs.sigma_m * rng.standard_normal((len(f.links), K))
    light, clean, extras = {}, [], []
    for j, ln in enumerate(f.links):
        p_rx = x_true[ln.rx][idx, :3] + R[ln.rx][idx] @ arms.get((ln.rx, ln.rx_antenna), zero)
        geo, light[j] = light_time_range(scn, p_rx, t_link, x0[ln.tx], yaw[ln.tx],
                                         arms.get((ln.tx, ln.tx_antenna), zero))
        first = order[ln.rx] < order[ln.tx]   # the pair (a, b) in the declared order
        pair = (ln.rx, ln.tx) if first else (ln.tx, ln.rx)
        clean.append(geo + (1.0 if first else -1.0) * clocks[pair])
        extras.append({"spacecraft": np.full(K, ln.rx, dtype=object),
                       "tx_spacecraft": np.full(K, ln.tx, dtype=object),
                       "rx_antenna": np.full(K, ln.rx_antenna or None, dtype=object),
                       "tx_antenna": np.full(K, ln.tx_antenna or None, dtype=object)})
        rho = clean[j] + code_noise[j]
        chunks.append((ISL_KINDS[0], t_link, np.column_stack([rho, np.full((K, 2), np.nan)]),
                       rs.sigma_m, extras[j]))
    if rs.carrier_sigma_m > 0.0:   # drawn after the code: switching it on keeps the code rows
        for j in range(len(f.links)):
            phi = clean[j] + amb[j] + rs.carrier_sigma_m * rng.standard_normal(K)
            chunks.append((ISL_KINDS[1], t_link, np.column_stack([phi, np.full((K, 2), np.nan)]),
                           rs.carrier_sigma_m, extras[j]))
    log = chunks_to_log(epoch0, chunks, spacecraft=ids,
                        antennas={(a, n): arm for (a, n), arm in arms.items()},
                        centre=scn.centre)
    return FormationPass(scenario=scn, seed=seed, epoch0=epoch0, ids=ids, t_s=t_all,
                         x_true=x_true, R_eci_from_body=R, t_link=t_link, clock_m=clock, log=log,
                         ambiguity_m=amb, attitude_rows=attitude_rows, light_time_s=light,
                         clocks=clocks)


BODY_KIND_OF = {m.body_frame_of: kind for kind, m in MODELS.items() if m.body_frame_of}
"""The body-frame kind of each ECI direction kind that has one (``earth_direction`` ->
``earth_direction_body``)."""


def _in_body_frame(chunk, R_eci_from_body, t_all):
    """A chunk ``(kind, t_s, values, sigma, extra)`` of an ECI direction kind with a body-frame
    kind as that kind's rows, ``u_body = R^T u_eci`` with the attitude at the chunk's epochs
    (module docstring); other chunks unchanged."""
    kind = chunk[0]
    if kind not in BODY_KIND_OF:
        return chunk
    R = R_eci_from_body[np.searchsorted(t_all, chunk[1])]
    u_body = np.einsum("mji,mj->mi", R, np.asarray(chunk[2], dtype=float))
    return (BODY_KIND_OF[kind], chunk[1], u_body, *chunk[3:])


def write_formation_files(out_dir, sim: FormationPass) -> list:
    """Write a formation pass as ``fgnav simulate`` does: ``measurements.csv`` (all
    spacecraft, ``spacecraft`` column and declarations), ``truth-<id>.oem`` per spacecraft,
    ``truth_clock.csv`` (epoch, clock_m: the first pair's; with more than one linked pair
    also ``clock_<a>_<b>_m`` per pair) and, when attitude rows are written (or body-frame
    rows exist), ``truth_attitude-<id>.csv`` (the true ``R_eci_from_body`` as a rotation
    vector). Returns the paths written; an unwritable directory is a :class:`UserError`."""
    out, scn = Path(out_dir), sim.scenario
    written = [out / "measurements.csv"]
    try:
        write_log(written[0], sim.log, comments=(
            f"scenario {scn.name}, seed {sim.seed}: {len(sim.ids)} spacecraft",))
        for i in sim.ids:
            written.append(out / f"truth-{i}.oem")
            write_oem(written[-1], sim.epoch0, sim.t_s, sim.x_true[i], None,
                      object_name=i.upper(), **oem_frame(scn.centre),
                      comments=(f"fgnav truth of spacecraft {i}, scenario {scn.name}, "
                                f"seed {sim.seed}",
                                "scipy DOP853 rtol 1e-12 (independent of the estimator's "
                                "propagator)"))
        written.append(out / TRUTH_CLOCK_CSV)
        (a, b), more = next(iter(sim.clocks)), len(sim.clocks) > 1
        cols = {"clock_m": sim.clock_m}
        if more:
            cols.update({f"clock_{x}_{y}_m": c for (x, y), c in sim.clocks.items()})
        write_truth_params_csv(
            written[-1], sim.epoch0, sim.t_link, cols,
            comments=(f"scenario {scn.name}, seed {sim.seed}: relative clock c (dt_{a}"
                      f" - dt_{b}), m, at the link epochs (a row received by "
                      f"{a} carries +clock_m, by {b} -clock_m)"
                      + ("; clock_<a>_<b>_m the same of every linked pair" if more else ""),))
        body_rows = any(str(k).endswith("_body") and MODELS.get(str(k)) is not None
                        for k in set(sim.log.kind))
        if sim.attitude_rows or body_rows:
            for i in sim.ids:
                written.append(out / f"truth_attitude-{i}.csv")
                write_truth_params_csv(
                    written[-1], sim.epoch0, sim.t_s,
                    dict(zip(TRUTH_ATTITUDE_COLUMNS, so3_log(sim.R_eci_from_body[i]).T)),
                    comments=(f"scenario {scn.name}, seed {sim.seed}: spacecraft {i}'s true "
                              "R_eci_from_body as a rotation vector, rad",))
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    return written
