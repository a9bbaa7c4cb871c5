"""Formation relative navigation over time: simulation, factor graph, batch GN and iSAM2.

Variables per epoch k (GTSAM keys through ``gtsam.symbol``):
- ``P(k)`` Vector3: position of sat 2 in sat-1 body frame, Cartesian ``(x, y, z)`` m or
  spherical ``(R m, az rad, el rad)`` (the parameterization under study);
- ``V(k)`` Vector3: relative velocity in the chief's LVLH frame, m/s (Cartesian in both);
- ``C(k)`` Vector1: relative clock bias c dt, m;
- ``N(0)`` Vector6 (with carrier phase): float ambiguities of the six links, m.

Factors: six pseudoranges per epoch (``factors.pseudorange``), optional carrier phases,
the Clohessy–Wiltshire motion factor between consecutive epochs with the known attitude
``R_body_from_lvlh`` (residual ``[C_{k+1}^T r_{k+1}; v_{k+1}] - Phi [C_k^T r_k; v_k]`` in
LVLH, Van Loan covariance), a clock random walk ``c_{k+1} - c_k`` (variance ``q_clock dt``),
and priors from the formation design at epoch 0.

Solvers: batch Gauss–Newton with ``eliminateSequential(ordering, EliminateQR)``
(GTSAM's Cholesky elimination throws on these ill-conditioned problems) and iSAM2 with QR
factorization. Covariances of the batch solution come from a dense QR of the whitened
Jacobian at the solution (the problem is small), iSAM2's from ``marginalCovariance``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import gtsam
import numpy as np

from factors.adapters import custom_factor
from factors.geometry import so3_exp
from factors.pseudorange import (
    N_LINKS, make_carrier_factor, make_pseudorange_factor, predict_ranges, spherical_to_cartesian,
)
from fgnav.errors import UserError
from fgnav.formation.relative_motion import (
    chief_circular_state, circular_relative_orbit, cw_matrices, mean_motion,
    two_body_relative_truth,
)
from fgnav.iod.single_epoch import PARAMS, from_param, solve_single_epoch_many, to_param

__all__ = ["FormationScenario", "simulate_formation", "attitude_track", "FormationGraph",
           "solve_batch", "solve_isam2", "TrackResult", "nees_of", "cw_motion_residual"]

M21_FACING = np.diag([-1.0, -1.0, 1.0])
"""Sat-2 body -> sat-1 body when sat 2 is turned 180 deg about z: antenna faces face each other."""


@dataclass
class FormationScenario:
    """Time-series formation case (SI inside; km/deg only where named)."""

    alt_km: float = 500.0               # circular chief altitude
    radius_m: float = 1000.0            # closed CW relative orbit radius (= separation)
    phase_rad: float = 0.3              # relative-orbit phase at t = 0
    duration_s: float = 600.0
    step_s: float = 10.0
    sigma_code_m: float = 0.01          # pseudorange noise (Xing et al.)
    sigma_carrier_m: float = 1e-5       # carrier-phase noise (Xing et al. ref. [1]: 10 um)
    carrier: bool = False
    q_m2_s3: float = 1e-11              # white relative-acceleration PSD of the CW factor
    #                                     (covers CW's linearization error, ~2e-7 m/s^2 at 1 km)
    q_clock_m2_s: float = 1e-4          # clock random-walk PSD (c dt in m)
    wobble_rad: float = 0.05            # known attitude wobble amplitude about body y/z
    wobble_period_s: float = 300.0
    roll_period_s: float = 600.0        # known roll of both satellites about the line of sight
    sigma_init_pos_m: float = 1.0       # design-vs-truth spread at epoch 0 (prior)
    sigma_init_vel_mps: float = 1e-3
    sigma_init_clock_m: float = 1.0
    sigma_ambiguity_m: float = 1.0
    m21: list = field(default_factory=lambda: M21_FACING.tolist())

    def validate(self):
        if not (self.step_s > 0 and self.duration_s >= 2 * self.step_s):
            raise UserError("need step_s > 0 and duration_s >= 2 step_s")
        for name in ("sigma_code_m", "sigma_carrier_m", "q_m2_s3", "q_clock_m2_s", "radius_m"):
            if not getattr(self, name) > 0:
                raise UserError(f"{name} must be positive, got {getattr(self, name)}")


def attitude_track(t_s, n_rad_s, sc: FormationScenario):
    """Known sat-1 attitude ``R_body_from_lvlh`` (N, 3, 3).

    Body +x points at the *nominal* (design) deputy position on the circular relative orbit,
    body +z along that orbit plane's normal ``(sqrt(3)/2, 0, -1/2)``; then a known wobble
    ``Exp(w [0, cos(2 pi t/P), sin(2 pi t/P)])^T`` so that the line of sight moves in the body
    frame, and a known roll ``2 pi t / roll_period_s`` about body +x (the line of sight) that
    turns the antenna baselines about it. Both satellites share the roll, so ``M21`` stays
    constant. The roll is what separates the direction from the float carrier ambiguities:
    without it an angle offset is first-order indistinguishable from an ambiguity.

    ``R_body_from_lvlh = (Exp([psi, 0, 0]) Exp(w [0, cos, sin]))^T R_track``.
    """
    nom = circular_relative_orbit(sc.radius_m, n_rad_s, t_s, sc.phase_rad)
    zb = np.array([0.5 * np.sqrt(3.0), 0.0, -0.5])
    out = np.empty((len(t_s), 3, 3))
    for k, t in enumerate(np.asarray(t_s, dtype=float)):
        xb = nom[k, :3] / np.linalg.norm(nom[k, :3])
        yb = np.cross(zb, xb)
        Rt = np.stack([xb, yb, zb])
        ph = 2 * np.pi * t / sc.wobble_period_s
        W = so3_exp(np.array([2 * np.pi * t / sc.roll_period_s, 0.0, 0.0])) @ so3_exp(
            sc.wobble_rad * np.array([0.0, np.cos(ph), np.sin(ph)]))
        out[k] = W.T @ Rt
    return out


def simulate_formation(sc: FormationScenario, rng):
    """Simulate truth and measurements. ``rng``: numpy Generator. Returns a dict of arrays.

    Truth: the design orbit perturbed at t = 0 (``sigma_init_*``), propagated as two
    absolute two-body orbits (``two_body_relative_truth``, independent of the CW model);
    clock: random walk; code noise ``sigma_code_m``; carrier with float ambiguities drawn
    ``N(0, sigma_ambiguity_m^2)`` and noise ``sigma_carrier_m``.
    """
    sc.validate()
    t = np.arange(0.0, sc.duration_s + 0.5 * sc.step_s, sc.step_s)
    n = mean_motion(sc.alt_km)
    nominal = circular_relative_orbit(sc.radius_m, n, t, sc.phase_rad)
    x0 = nominal[0].copy()
    x0[:3] += sc.sigma_init_pos_m * rng.standard_normal(3)
    x0[3:] += sc.sigma_init_vel_mps * rng.standard_normal(3)
    truth = two_body_relative_truth(chief_circular_state(sc.alt_km), x0, t)
    C = attitude_track(t, n, sc)
    r_body = np.einsum("kab,kb->ka", C, truth[:, :3])
    cdt = sc.sigma_init_clock_m * rng.standard_normal() + np.concatenate(
        [[0.0], np.cumsum(np.sqrt(sc.q_clock_m2_s * sc.step_s) * rng.standard_normal(t.size - 1))])
    M21 = np.broadcast_to(np.asarray(sc.m21, dtype=float), (t.size, 3, 3)).copy()
    clean = predict_ranges(r_body, cdt, M21)
    rho = clean + sc.sigma_code_m * rng.standard_normal(clean.shape)
    amb = sc.sigma_ambiguity_m * rng.standard_normal(N_LINKS)
    phi = clean + amb + sc.sigma_carrier_m * rng.standard_normal(clean.shape)
    return {"t_s": t, "n_rad_s": n, "nominal_lvlh": nominal, "truth_lvlh": truth,
            "R_body_from_lvlh": C, "r_body_m": r_body, "cdt_m": cdt, "M21": M21,
            "rho_m": rho, "phi_m": phi, "ambiguity_m": amb}


def cw_motion_residual(p_k, v_k, p_k1, v_k1, C_k, C_k1, Phi, param):
    """CW motion residual between epochs k, k+1 and its Jacobians.

    ``e = [C_{k+1}^T r(p_{k+1}); v_{k+1}] - Phi [C_k^T r(p_k); v_k]`` (LVLH, m and m/s),
    with ``r(p)`` the sat-1-body Cartesian position of the parameterization ``param`` and
    ``C = R_body_from_lvlh``. Returns ``e (6,)`` and ``[H_pk, H_vk, H_pk1, H_vk1]`` (6, 3) each
    (chain rule through ``dr/dp``: identity or ``factors.pseudorange.spherical_to_cartesian``).
    """
    r_k, G_k = _position_and_jacobian(p_k, param)
    r_k1, G_k1 = _position_and_jacobian(p_k1, param)
    x_k = np.concatenate([C_k.T @ r_k, v_k])
    e = np.concatenate([C_k1.T @ r_k1, v_k1]) - Phi @ x_k
    H_pk = -Phi[:, :3] @ C_k.T @ G_k
    H_vk = -Phi[:, 3:].copy()
    H_pk1 = np.vstack([C_k1.T @ G_k1, np.zeros((3, 3))])
    H_vk1 = np.vstack([np.zeros((3, 3)), np.eye(3)])
    return e, [H_pk, H_vk, H_pk1, H_vk1]


def _position_and_jacobian(p, param):
    if param == "cartesian":
        return np.asarray(p, dtype=float), np.eye(3)
    return spherical_to_cartesian(np.asarray(p, dtype=float))


def _keys():
    return (lambda k: gtsam.symbol("p", k), lambda k: gtsam.symbol("v", k),
            lambda k: gtsam.symbol("c", k), gtsam.symbol("n", 0))


class FormationGraph:
    """Builds the factors of the formation problem for one parameterization."""

    def __init__(self, sim, sc: FormationScenario, param: str):
        if param not in PARAMS:
            raise UserError(f"param must be one of {PARAMS}, got {param!r}")
        self.sim, self.sc, self.param = sim, sc, param
        self.Phi, self.Q = cw_matrices(sim["n_rad_s"], sc.step_s, sc.q_m2_s3)
        self.P, self.V, self.C, self.N = _keys()

    def prior_factors(self):
        """Priors at epoch 0 from the formation design (nominal orbit), clock 0, ambiguities 0."""
        sc, sim = self.sc, self.sim
        nom = sim["nominal_lvlh"][0]
        r_b = sim["R_body_from_lvlh"][0] @ nom[:3]
        p_mean = to_param(r_b, self.param)
        if self.param == "cartesian":
            p_sig = np.full(3, sc.sigma_init_pos_m)
        else:
            R = np.linalg.norm(r_b)
            p_sig = np.array([sc.sigma_init_pos_m, sc.sigma_init_pos_m / R,
                              sc.sigma_init_pos_m / (R * np.cos(p_mean[2]))])
        out = []
        keyp = self.P(0)

        def prior_p(values):
            p = np.asarray(values.atVector(keyp), dtype=float)
            e = p - p_mean
            if self.param == "spherical":
                e[1] = np.angle(np.exp(1j * e[1]))
            return e, [np.eye(3)]

        out.append(custom_factor([keyp], p_sig, prior_p))
        out.append(gtsam.PriorFactorVector(self.V(0), nom[3:].copy(),
                                           gtsam.noiseModel.Isotropic.Sigma(3, sc.sigma_init_vel_mps)))
        out.append(gtsam.PriorFactorVector(self.C(0), np.zeros(1),
                                           gtsam.noiseModel.Isotropic.Sigma(1, sc.sigma_init_clock_m)))
        if sc.carrier:
            out.append(gtsam.PriorFactorVector(self.N, np.zeros(N_LINKS),
                                               gtsam.noiseModel.Isotropic.Sigma(N_LINKS, sc.sigma_ambiguity_m)))
        return out

    def epoch_factors(self, k):
        """Measurement factors of epoch k and (for k > 0) the motion/clock factors k-1 -> k."""
        sim, sc, param = self.sim, self.sc, self.param
        out = [make_pseudorange_factor(self.P(k), self.C(k), sim["rho_m"][k], sim["M21"][k],
                                       sc.sigma_code_m, param)]
        if sc.carrier:
            out.append(make_carrier_factor(self.P(k), self.C(k), self.N, sim["phi_m"][k],
                                           sim["M21"][k], sc.sigma_carrier_m, param))
        if k > 0:
            Ck, Ck1, Phi = sim["R_body_from_lvlh"][k - 1], sim["R_body_from_lvlh"][k], self.Phi
            keys = [self.P(k - 1), self.V(k - 1), self.P(k), self.V(k)]

            def motion(values, keys=keys, Ck=Ck, Ck1=Ck1):
                a = [np.asarray(values.atVector(kk), dtype=float) for kk in keys]
                return cw_motion_residual(a[0], a[1], a[2], a[3], Ck, Ck1, Phi, param)

            out.append(custom_factor(keys, self.Q, motion, dim=6))
            kc0, kc1 = self.C(k - 1), self.C(k)

            def clock(values, kc0=kc0, kc1=kc1):
                e = values.atVector(kc1) - values.atVector(kc0)
                return np.asarray(e, dtype=float), [-np.eye(1), np.eye(1)]

            out.append(custom_factor([kc0, kc1], np.sqrt(sc.q_clock_m2_s * sc.step_s), clock, dim=1))
        return out

    def graph(self):
        g = gtsam.NonlinearFactorGraph()
        for f in self.prior_factors():
            g.add(f)
        for k in range(self.sim["t_s"].size):
            for f in self.epoch_factors(k):
                g.add(f)
        return g

    def initial_values(self):
        """Initial guess: single-epoch code solutions (position, clock), design velocity,
        ambiguities from carrier minus code at epoch 0."""
        sim, sc = self.sim, self.sc
        K = sim["t_s"].size
        x0 = np.tile([sc.radius_m, 0.0, 0.0, 0.0], (K, 1))
        xs, _, _ = solve_single_epoch_many(sim["rho_m"], sim["M21"], "spherical", x0)
        r0 = from_param(xs[:, :3], "spherical")
        vals = gtsam.Values()
        for k in range(K):
            vals.insert(self.P(k), to_param(r0[k], self.param))
            vals.insert(self.V(k), sim["nominal_lvlh"][k, 3:].copy())
            vals.insert(self.C(k), np.array([xs[k, 3]]))
        if sc.carrier:
            vals.insert(self.N, sim["phi_m"][0] - predict_ranges(r0[0], xs[0, 3], sim["M21"][0]))
        return vals, r0, xs[:, 3]

    def ordering_keys(self):
        K = self.sim["t_s"].size
        keys = []
        for k in range(K):
            keys += [self.P(k), self.V(k), self.C(k)]
        if self.sc.carrier:
            keys.append(self.N)
        return keys


@dataclass
class TrackResult:
    """Estimated relative trajectory and its per-epoch covariance blocks."""

    param: str
    solver: str
    t_s: np.ndarray
    p: np.ndarray            # (K, 3) position coordinates of `param`
    v_lvlh_mps: np.ndarray   # (K, 3)
    cdt_m: np.ndarray        # (K,)
    cov: np.ndarray          # (K, 7, 7) covariance of [p, v, cdt] per epoch (param coords)
    iterations: int = 0
    ambiguity_m: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def r_body_m(self):
        return from_param(self.p, self.param)

    def spherical(self):
        """(K, 3) (R, az, el) and their 1-sigma (K, 3), mapped to/from the parameterization."""
        return _both_coords(self)[0:2]

    def cartesian(self):
        """(K, 3) Cartesian sat-1-body position and its 1-sigma (K, 3)."""
        return _both_coords(self)[2:4]


def _both_coords(res: TrackResult):
    r = res.r_body_m
    s = to_param(r, "spherical")
    _, J = spherical_to_cartesian(s)                  # dr/ds
    Pp = res.cov[:, :3, :3]
    if res.param == "cartesian":
        Jinv = np.linalg.inv(J)
        Ps = Jinv @ Pp @ np.swapaxes(Jinv, 1, 2)
        Pc = Pp
    else:
        Ps = Pp
        Pc = J @ Pp @ np.swapaxes(J, 1, 2)
    sd = lambda P: np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 0.0))  # noqa: E731
    return s, sd(Ps), r, sd(Pc)


def _dense_covariances(graph, values, keys):
    """Per-epoch 7x7 covariance blocks from a dense QR of the whitened Jacobian."""
    from scipy.linalg import solve_triangular

    order = gtsam.Ordering()
    for k in keys:
        order.push_back(k)
    A, _ = graph.linearize(values).jacobian(order)
    R = np.linalg.qr(A, mode="r")
    Rinv = solve_triangular(R, np.eye(R.shape[0]), lower=False)
    cov = Rinv @ Rinv.T
    return cov, A


def _extract(values, fg: FormationGraph):
    K = fg.sim["t_s"].size
    p = np.array([values.atVector(fg.P(k)) for k in range(K)])
    v = np.array([values.atVector(fg.V(k)) for k in range(K)])
    c = np.array([values.atVector(fg.C(k))[0] for k in range(K)])
    amb = np.asarray(values.atVector(fg.N)) if fg.sc.carrier else None
    return p, v, c, amb


def solve_batch(sim, sc: FormationScenario, param="spherical", max_iter=20, tol=1e-9):
    """Batch Gauss–Newton with QR elimination (own loop). Returns :class:`TrackResult`."""
    fg = FormationGraph(sim, sc, param)
    graph = fg.graph()
    values, _, _ = fg.initial_values()
    keys = fg.ordering_keys()
    order = gtsam.Ordering()
    for k in keys:
        order.push_back(k)
    it = 0
    err0 = graph.error(values)
    for it in range(1, max_iter + 1):
        gfg = graph.linearize(values)
        delta = gfg.eliminateSequential(order, gtsam.EliminateQR).optimize()
        values = values.retract(delta)
        err = graph.error(values)
        if abs(err0 - err) <= tol * max(err, 1.0):
            break
        err0 = err
    cov, A = _dense_covariances(graph, values, keys)
    K = sim["t_s"].size
    blocks = np.array([cov[7 * k:7 * k + 7, 7 * k:7 * k + 7] for k in range(K)])
    p, v, c, amb = _extract(values, fg)
    sv = np.linalg.svd(A, compute_uv=False)
    info = {"final_error": float(graph.error(values)), "jacobian_cond": float(sv[0] / sv[-1]),
            "n_factors": int(graph.size())}
    if amb is not None:
        info["ambiguity_sigma_m"] = np.sqrt(np.diag(cov[7 * K:, 7 * K:])).tolist()
    return TrackResult(param, "batch", sim["t_s"], p, v, c, blocks, it, amb, info)


def default_relinearize_thresholds(param, sc: FormationScenario):
    """Per-variable iSAM2 relinearization thresholds in each variable's own unit.

    Position: 0.01 mm (Cartesian), or 0.01 mm in R and 0.01 mm / radius in az, el (rad),
    i.e. ~1 % of the smallest sigmas; velocity 1e-7 m/s; clock 0.01 mm; ambiguities 0.1 um.
    A single float threshold (GTSAM's default 0.1) would never relinearize the angles
    (0.1 rad = 100 m at 1 km).
    """
    tm = gtsam.ISAM2ThresholdMap()
    ang = 1e-5 / sc.radius_m
    tm.insert(("p", np.array([1e-5, 1e-5, 1e-5]) if param == "cartesian"
               else np.array([1e-5, ang, ang])))
    tm.insert(("v", np.full(3, 1e-7)))
    tm.insert(("c", np.array([1e-5])))
    tm.insert(("n", np.full(N_LINKS, 1e-7)))
    return tm


def solve_isam2(sim, sc: FormationScenario, param="spherical", factorization="QR",
                relinearize_threshold=None, extra_updates=None):
    """iSAM2, one epoch at a time (QR factorization by default; ``factorization="CHOLESKY"``
    to compare). New keys are initialized by CW prediction from the previous estimate.

    Returns :class:`TrackResult` (smoothed estimate after the last epoch; covariance blocks
    from ``jointMarginalCovariance``).

    Measured (tests/test_formation_track.py): Cholesky throws "Indeterminant linear system"
    in both parameterizations; with QR both reach the batch optimum. iSAM2 is easier in
    Cartesian coordinates: one threshold in metres suits all position components and 2
    updates per epoch suffice, while the spherical state needs per-variable thresholds in
    rad (:func:`default_relinearize_thresholds`; GTSAM's single 0.1 leaves the estimate
    several sigma off the optimum) and more relinearization per epoch (the CW factor is
    nonlinear in az, el): on the 600 s case 3 extra updates left it 0.36 sigma off the batch
    optimum, 6 reach it (1e-7 sigma). ``extra_updates=None``: 6 spherical, 3 Cartesian.
    """
    fg = FormationGraph(sim, sc, param)
    if extra_updates is None:   # measured: enough to reach the batch optimum (see above)
        extra_updates = 6 if param == "spherical" else 3
    init, _, _ = fg.initial_values()
    params = gtsam.ISAM2Params()
    params.setFactorization(factorization)
    params.setRelinearizeThreshold(
        default_relinearize_thresholds(param, sc) if relinearize_threshold is None
        else relinearize_threshold)
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    K = sim["t_s"].size
    est = None
    for k in range(K):
        g = gtsam.NonlinearFactorGraph()
        if k == 0:
            for f in fg.prior_factors():
                g.add(f)
        for f in fg.epoch_factors(k):
            g.add(f)
        new = gtsam.Values()
        if k == 0:
            new.insert(fg.P(0), init.atVector(fg.P(0)))
            new.insert(fg.V(0), init.atVector(fg.V(0)))
            new.insert(fg.C(0), init.atVector(fg.C(0)))
            if sc.carrier:
                new.insert(fg.N, init.atVector(fg.N))
        else:
            Ck0, Ck1 = sim["R_body_from_lvlh"][k - 1], sim["R_body_from_lvlh"][k]
            r_prev = from_param(np.asarray(est.atVector(fg.P(k - 1))), param)
            x_prev = np.concatenate([Ck0.T @ r_prev, est.atVector(fg.V(k - 1))])
            x_pred = fg.Phi @ x_prev
            p_pred = to_param(Ck1 @ x_pred[:3], param)
            if param == "spherical":   # keep azimuth continuous with the previous epoch
                az0 = float(est.atVector(fg.P(k - 1))[1])
                p_pred[1] = az0 + np.angle(np.exp(1j * (p_pred[1] - az0)))
            new.insert(fg.P(k), p_pred)
            new.insert(fg.V(k), x_pred[3:])
            new.insert(fg.C(k), est.atVector(fg.C(k - 1)))
        isam.update(g, new)
        for _ in range(extra_updates):
            isam.update()
        est = isam.calculateEstimate()
    p, v, c, amb = _extract(est, fg)
    blocks = np.empty((K, 7, 7))
    for k in range(K):
        keys = gtsam.KeyVector([fg.P(k), fg.V(k), fg.C(k)])
        blocks[k] = isam.jointMarginalCovariance(keys).fullMatrix()
    info = {"factorization": factorization}
    return TrackResult(param, "isam2", sim["t_s"], p, v, c, blocks, K, amb, info)


def nees_of(res: TrackResult, sim, which="position"):
    """Normalized estimation error squared per epoch, in the result's own coordinates.

    ``which``: "position" (3 dof) or "state" (7 dof: position, LVLH velocity, clock).
    """
    truth_p = to_param(sim["r_body_m"], res.param)
    e = np.concatenate([res.p - truth_p, res.v_lvlh_mps - sim["truth_lvlh"][:, 3:],
                        (res.cdt_m - sim["cdt_m"])[:, None]], axis=1)
    if res.param == "spherical":
        e[:, 1] = np.angle(np.exp(1j * e[:, 1]))
    d = 3 if which == "position" else 7
    e = e[:, :d]
    P = res.cov[:, :d, :d]
    return np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])


def scenario_dict(sc: FormationScenario):
    """JSON-able scenario."""
    return asdict(sc)
