"""The batch route and the iSAM2 route linearize every registered measurement model the same way.

Batch hands GTSAM pre-whitened rows built in bulk (``fgnav.graph.linearize_all`` over the
models' vectorized residuals); iSAM2 and the fixed-lag smoother linearize one GTSAM factor per
row (``fgnav.graph.factors_for_rows``, the models' ``factors/`` adapters). Both must give the
same whitened Jacobian and right-hand side for every model that enters the graphs, on every
variable it touches (the refraction bias too), at a state off the truth, or the online and
batch answers drift apart.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from fgnav.graph import factors_for_rows, initial_block, linearize_all, linearize_family
from fgnav.io.log_csv import ATT_COV_COLUMNS, log_from_arrays
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import MODELS
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate import faults as F
from fgnav.simulate.pass_sim import raw_star_scenario, simulate_pass
from fgnav.sun_earth_moon import preprocess_log

_REFRACTION = load_scenario("refraction-leo").sensors[0]
_GTO = load_scenario("gto-transfer").sensors
_GEO = load_scenario("geo-limb").sensors
# an optical navigation camera imaging the Moon and the Earth (issue 31 item 1)
_NEAR = (SensorSpec("body_direction", body="moon", sigma_deg=2e-3, period_s=300.0),
         SensorSpec("limb_radius", body="moon", sigma_deg=2e-3, period_s=300.0),
         SensorSpec("body_direction", body="earth", sigma_deg=2e-3, period_s=300.0))
CASES = {  # id: (scenario, options, families checked, graph variables beyond the orbit)
    "gto": ("gto-transfer", {}, ("prior_position", "prior_velocity", "earth_direction"), ()),
    "geo-limb": ("geo-limb", {}, ("limb_radius",), ()),
    "leo-sun-earth-moon": ("leo-sun-earth-moon", {}, ("altitude", "earth_direction"), ()),
    # the same log with the attitude estimated: raw Sun, Moon and Earth directions in the
    # body frame as factors on (orbit, attitude), no TRIAD preprocessing
    "sun-earth-moon-raw": ("leo-sun-earth-moon", {},
                           ("sun_direction_body", "moon_direction_body", "earth_direction_body",
                            "altitude"), ("attitude",)),
    "refraction": ("refraction-leo", {}, ("refraction",), ()),
    # near bodies: the Moon's and the Earth's apparent directions and the Moon's limb (with
    # the body column) beside the Earth's limb rows of geo-limb; in the body frame with the
    # attitude from raw stars
    "near-body": ("gto-transfer", {"sensors": _GTO + _NEAR}, ("body_direction", "limb_radius"),
                  ()),
    "near-body-limb": ("geo-limb", {"sensors": _GEO + _NEAR[1:2]}, ("limb_radius",), ()),
    "near-body-attitude": ("geo-limb", {"raw_stars": True, "sensors": _GEO + (
        SensorSpec("body_direction_body", body="moon", sigma_deg=2e-3),)},
        ("body_direction_body",), ("attitude",)),
    "refraction-bias": ("refraction-leo", {}, ("refraction",), ("refraction-bias",)),
    # attitude rows (from the refraction heads' clear stars) + Earth directions in the body
    # frame, with the attitude a Rot3 variable per epoch
    "attitude": ("refraction-leo",
                 {"sensors": (_REFRACTION, SensorSpec("earth_direction_body", sigma_deg=0.02))},
                 ("attitude", "earth_direction_body", "refraction"), ("attitude",)),
    # the same with each attitude row's full 3x3 covariance (att_c11..att_c33: a roll
    # sigma 10x the cross-boresight ones about a random axis): whitened by W, W^T W = C^-1
    "attitude-full-cov": ("refraction-leo",
                          {"sensors": (_REFRACTION, SensorSpec("earth_direction_body",
                                                               sigma_deg=0.02)),
                           "attitude_cov": True},
                          ("attitude", "earth_direction_body"), ("attitude",)),
    # raw stars of a zenith star camera + Earth directions in the body frame (--raw-stars)
    # the sextant: attitude-free angles, star - Earth limb, star - Moon centre, Earth - Moon
    "sextant": ("sextant-leo", {}, ("limb_star_angle", "body_star_angle", "body_body_angle"), ()),
    "raw-stars": ("geo-limb", {"raw_stars": True},
                  ("star_direction_body", "earth_direction_body", "limb_radius"), ("attitude",)),
    # the same with the star camera on its own mount: star rows through the estimated
    # camera alignment (a constant Rot3 beside the attitude)
    "raw-stars-aligned": ("geo-limb", {"raw_stars": True},
                          ("star_direction_body", "earth_direction_body"),
                          ("attitude", "camera-alignment")),
}


def with_attitude_covariance(log, seed=3):
    """``log`` with a full covariance on every ``attitude`` row: per row a random rotation
    ``Q`` and ``C = Q diag(s^2, s^2, (10 s)^2) Q^T`` with ``s`` the row's sigma."""
    rng = np.random.default_rng(seed)
    extra = {c: np.array(v, dtype=float) for c, v in log.extra.items()}
    for i in log.select("attitude"):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        C = Q @ np.diag(np.array([1.0, 1.0, 100.0]) * log.sigma[i] ** 2) @ Q.T
        for c, (a, b) in zip(ATT_COV_COLUMNS, zip(*np.triu_indices(3))):
            extra[c][i] = C[a, b]
    return log_from_arrays(log.epoch0, log.t_s, log.kind, log.xyz, log.sigma, extra)


def _raw_stars(scenario, **opts):
    sim = simulate_pass(raw_star_scenario(load_scenario(scenario).with_options(**opts)))
    return sim.log, sim.t_s, sim.x_true


def test_every_model_that_enters_the_graphs_is_covered():
    covered = {k for _, _, kinds, _ in CASES.values() for k in kinds} | {"gyro"} | set(LINKS)
    solved = {k for k, m in MODELS.items() if m.solved}
    assert solved <= covered, f"add a case carrying {sorted(solved - covered)} to CASES"


def test_every_declared_variable_is_covered():
    """Every graph variable a model declares is estimated in some case (the gyro bias in
    the between-epochs test below)."""
    declared = {v.cli_name for m in MODELS.values() if m.solved for v in m.optional_variables}
    covered = {name for _, _, _, est in CASES.values() for name in est} | {"gyro-bias"}
    assert declared <= covered, f"add a case estimating {sorted(declared - covered)} to CASES"


def _cases():
    """The (case, kind) parameters as a list (pytest >= 9.1 refuses a generator)."""
    return [pytest.param(case, kind, id=f"{case}-{kind}")
            for case, (_, _, kinds, _) in CASES.items() for kind in kinds]


@pytest.mark.parametrize("case, kind", _cases())
def test_batch_and_isam2_routes_give_the_same_whitened_rows(case, kind):
    scenario, opts, _, estimate = CASES[case]
    opts = dict(opts)
    attitude_cov = opts.pop("attitude_cov", False)
    if opts.pop("raw_stars", False):
        log, t, x = _raw_stars(scenario, duration_h=0.5, **opts)
    else:
        log, t, x = F.clean(scenario, duration_h=0.5, **opts)
    if attitude_cov:
        log = with_attitude_covariance(log)
    if len(log.select("sun_direction_body")) and "attitude" not in estimate:
        # body-frame rows: to ECI by TRIAD attitude (the attitude not estimated)
        log = preprocess_log(log)[0]
    p = with_estimates(build_pass(log), estimate)
    lay = p.layout
    fam = p.families[kind]
    rng = np.random.default_rng(7)
    # a state off the truth: 2 km and 1 m/s per axis (and 50 units on any further variable),
    # so the Jacobians are not evaluated at the zero-residual point
    X_eval = initial_block(p, x[np.searchsorted(t, p.t_s)])[0]
    scale = np.concatenate([[2e3] * 3, [1.0] * 3] + [np.full(v.dim, 0.01 if v.manifold == "rot3"
                                                             else 50.0) for v in lay.extra])
    X_eval += rng.normal(0, 1, X_eval.shape) * scale   # 0.01 rad on an attitude
    k_b, A_b, b_b, _ = linearize_family(p, kind, fam, X_eval)
    rows = np.unique(np.linspace(0, len(fam) - 1, 6).astype(int))
    for j in rows:
        k = int(fam.k[j])
        factor, = factors_for_rows(p, kind, np.array([j]), k, None, X_eval[k, :6])
        values = gtsam.Values()
        for v in lay.variables:
            w = X_eval[k, lay.slices[v.name]]
            values.insert(v.key(k), gtsam.Rot3.Expmap(w) if v.manifold == "rot3" else w)
        lin = factor.linearize(values)
        A_i, b_i = lin.jacobian()
        # the factor's columns in the layout's order (GTSAM orders them by key)
        cols = {int(key): i for i, key in enumerate(lin.keys())}
        dims = {v.key(k): v.dim for v in lay.variables}
        A_layout = np.zeros((A_i.shape[0], lay.n))
        off = np.cumsum([0] + [dims[int(key)] for key in lin.keys()])
        for v in lay.variables:
            if v.key(k) in cols:
                i = cols[v.key(k)]
                A_layout[:, lay.slices[v.name]] = A_i[:, off[i]:off[i + 1]]
        assert int(k_b[j]) == k
        scale = max(1.0, np.abs(A_b[j]).max())
        np.testing.assert_allclose(A_layout, A_b[j], rtol=1e-9, atol=1e-12 * scale,
                                   err_msg=f"{kind} row {j}: whitened Jacobian")
        np.testing.assert_allclose(b_i, b_b[j], rtol=1e-9, atol=1e-9,
                                   err_msg=f"{kind} row {j}: whitened right-hand side")


def _two_epoch_blocks(lin, lay, k):
    """A linearized factor on the variables of epochs ``k - 1`` and ``k`` as the batch
    route's rows: ``(A0, A1)`` (rows, n) in the layout's columns of each epoch, and ``b``."""
    A_i, b_i = lin.jacobian()
    A0 = np.zeros((len(b_i), lay.n))
    A1 = np.zeros((len(b_i), lay.n))
    col = 0
    for key in lin.keys():
        for kk, A in ((k - 1, A0), (k, A1)):
            for v in lay.variables:
                if v.key(kk) == key:
                    A[:, lay.slices[v.name]] = A_i[:, col:col + v.dim]
                    col += v.dim
    assert col == A_i.shape[1]
    return A0, A1, b_i


def test_batch_and_isam2_routes_agree_between_epochs():
    """Rows that join two epochs (a gyro interval): the batch route's step rows
    (``Rows.steps``, stacked under the motion rows) and the iSAM2 factor on the keys of both
    epochs give the same whitened blocks."""
    from attitude_passes import with_gyro

    log, t, x = F.clean("refraction-leo", duration_h=0.2, **CASES["attitude"][1])
    log, _ = with_gyro(log, t, x, np.array([1e-4, -5e-5, 8e-5]), 1e-6, np.random.default_rng(3))
    p = with_estimates(build_pass(log), ("attitude", "gyro-bias"))
    lay = p.layout
    rng = np.random.default_rng(8)
    X_eval = initial_block(p, x[np.searchsorted(t, p.t_s)])[0]
    scale = np.concatenate([[2e3] * 3, [1.0] * 3] + [np.full(v.dim, 0.01 if v.manifold == "rot3"
                                                             else 1e-4) for v in lay.extra])
    X_eval += rng.normal(0, 1, X_eval.shape) * scale
    rows = linearize_all(p, X_eval)
    s_k, s_A0, s_A1, s_b = rows.steps
    fam = p.families["gyro"]
    order = np.argsort(fam.k, kind="stable")
    for j in (int(order[0]), int(order[len(order) // 2]), int(order[-1])):
        k = int(fam.k[j])
        r = np.flatnonzero(s_k == k - 1)            # this epoch's gyro row (one per epoch)
        factor, = factors_for_rows(p, "gyro", np.array([j]), k, None, X_eval[k, :6])
        values = gtsam.Values()
        for kk in (k - 1, k):
            for v in lay.variables:
                w = X_eval[kk, lay.slices[v.name]]
                values.insert(v.key(kk), gtsam.Rot3.Expmap(w) if v.manifold == "rot3" else w)
        A0, A1, b_i = _two_epoch_blocks(factor.linearize(values), lay, k)
        np.testing.assert_allclose(A0, s_A0[r], rtol=1e-9, atol=1e-9 * np.abs(s_A0[r]).max())
        np.testing.assert_allclose(A1, s_A1[r], rtol=1e-9, atol=1e-9 * np.abs(s_A1[r]).max())
        np.testing.assert_allclose(b_i, s_b[r], rtol=1e-9, atol=1e-9)


def test_batch_and_isam2_routes_agree_on_the_constant_rate_motion():
    """The attitude's constant-rate motion (``--attitude-motion constant-rate``): the batch
    route's process rows (``fgnav.solvers.batch.process_blocks``) and the iSAM2 factors of
    the step (``fgnav.solvers.incremental._process_factors``) give the same whitened blocks
    on the attitude and its rate, at a block off the truth."""
    from fgnav.models.registry import ATTITUDE_RATE, ATTITUDE_VARIABLE
    from fgnav.solvers.batch import process_blocks
    from fgnav.solvers.incremental import _insert_block, _process_factors
    from fgnav.solvers.options import SmootherOptions

    log, t, x = F.clean("refraction-leo", duration_h=0.1, **CASES["attitude"][1])
    p = with_estimates(build_pass(log), ("attitude", "attitude-rate"))
    lay = p.layout
    assert lay.has(ATTITUDE_RATE.name)
    rng = np.random.default_rng(8)
    X_eval = initial_block(p, x[np.searchsorted(t, p.t_s)])[0]
    X_eval[:, lay.slices[ATTITUDE_VARIABLE.name]] += rng.normal(0, 0.01, (p.n_epochs, 3))
    X_eval[:, lay.slices[ATTITUDE_RATE.name]] = rng.normal(0, 0.01, (p.n_epochs, 3))
    opts = SmootherOptions()
    model = opts.motion_model()
    A0_b, A1_b, b_b = process_blocks(p, X_eval, opts.q_m2_s3, model, 0.0)
    sa, sw = lay.slices[ATTITUDE_VARIABLE.name], lay.slices[ATTITUDE_RATE.name]
    rows = np.r_[sa, sw]
    for k in (1, p.n_epochs // 2, p.n_epochs - 1):
        values = gtsam.Values()
        for kk in (k - 1, k):
            _insert_block(values, lay, kk, X_eval[kk])
        dt = p.t_s[k] - p.t_s[k - 1]
        facs = [f for f in _process_factors(lay, k, dt, opts.q_m2_s3, model, 0.0)
                if ATTITUDE_RATE.key(k) in f.keys()]
        assert len(facs) == 1                        # one factor joins attitude and rate
        A0, A1, b_i = _two_epoch_blocks(facs[0].linearize(values), lay, k)
        np.testing.assert_allclose(A0, A0_b[k - 1][rows], rtol=1e-9,
                                   atol=1e-9 * np.abs(A0_b[k - 1][rows]).max())
        np.testing.assert_allclose(A1, A1_b[k - 1][rows], rtol=1e-9,
                                   atol=1e-9 * np.abs(A1_b[k - 1][rows]).max())
        np.testing.assert_allclose(b_i, b_b[k - 1][rows], rtol=1e-9, atol=1e-9)


LINKS = ("isl_pseudorange", "isl_carrier_phase")
"""The formation's links, covered below on a two-spacecraft pass."""


@pytest.mark.parametrize("kind", LINKS)
def test_batch_and_isam2_routes_agree_on_a_formations_links(kind):
    """A link's rows bind the orbits of its two spacecraft, the pair's clock and (carrier) the
    link's ambiguity row by row: the batch rows and the factor on those keys agree."""
    from formation_data import formation_log

    log, truth = formation_log(2, carrier=True, lever_arms=True)
    p = build_pass(log)
    lay = p.layout
    X_eval = lay.initial(truth["A"][1])
    X_eval[:, lay.slices["orbit_B"]] = truth["B"][1]
    X_eval += np.random.default_rng(9).normal(0, 1, X_eval.shape) * np.r_[
        [2e3] * 3, [1.0] * 3, [2e3] * 3, [1.0] * 3, [50.0] * (lay.n - 12)]
    fam = p.families[kind]
    k_b, A_b, b_b, _ = linearize_family(p, kind, fam, X_eval)
    for j in np.unique(np.linspace(0, len(fam) - 1, 6).astype(int)):
        k = int(fam.k[j])
        factor, = factors_for_rows(p, kind, np.array([j]), k, None, X_eval[k, :6])
        values = gtsam.Values()
        for v in lay.variables:
            values.insert(v.key(k), X_eval[k, lay.slices[v.name]])
        lin = factor.linearize(values)
        A_i, b_i = lin.jacobian()
        A_layout = np.zeros((A_i.shape[0], lay.n))
        col = 0
        for key in lin.keys():
            v = next(v for v in lay.variables if v.key(k) == key)
            A_layout[:, lay.slices[v.name]] = A_i[:, col:col + v.dim]
            col += v.dim
        assert col == A_i.shape[1]
        np.testing.assert_allclose(A_layout, A_b[j], rtol=1e-9, atol=1e-12 * np.abs(A_b[j]).max())
        np.testing.assert_allclose(b_i, b_b[j], rtol=1e-9, atol=1e-9)


# -- the other factor families: orbit motion, the further variables' process, their priors --

def _values(lay, X, epochs):
    """A ``gtsam.Values`` of the block values ``X`` (N, n) at ``epochs`` (each variable's
    manifold turns its stored numbers into its GTSAM value)."""
    values = gtsam.Values()
    for kk in epochs:
        for v in lay.variables:
            values.insert(v.key(kk), v.manifold.to_gtsam(X[kk, lay.slices[v.name]]))
    return values


def _assert_rows(A0, A1, b, A0_b, A1_b, b_b, what):
    for got, want, name in ((A0, A0_b, "A0"), (A1, A1_b, "A1")):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * max(np.abs(want).max(), 1.0),
                                   err_msg=f"{what}: {name}")
    np.testing.assert_allclose(b, b_b, rtol=1e-9, atol=1e-9, err_msg=f"{what}: b")


def _family_pass(case):
    """``(pass, block values off the truth)`` of a pass whose graph holds the variables of
    ``case``: a formation's two orbits with clock and ambiguities (vector random walks),
    the refraction bias (a scalar random walk), the attitude and the gyro bias (a random
    walk on SO(3) beside a vector one), the attitude with its rate (the constant-rate
    motion, one joint process) and the attitude with the camera alignment (two rotations)."""
    from attitude_passes import with_gyro
    from formation_data import formation_log

    rng = np.random.default_rng(11)
    if case == "formation":
        log, truth = formation_log(2, carrier=True, lever_arms=True)
        p = build_pass(log)
        X = p.layout.initial(truth["A"][1])
        X[:, p.layout.slices["orbit_B"]] = truth["B"][1]
    else:
        if case == "refraction-bias":
            log, t, x = F.clean("refraction-leo", duration_h=0.1)
            estimate = ("refraction-bias",)
        elif case == "camera-alignment":
            log, t, x = _raw_stars("geo-limb", duration_h=0.2)
            estimate = ("attitude", "camera-alignment")
        else:
            log, t, x = F.clean("refraction-leo", duration_h=0.1, **CASES["attitude"][1])
            if case == "gyro-bias":
                log, _ = with_gyro(log, t, x, np.array([1e-4, -5e-5, 8e-5]), 1e-6,
                                   np.random.default_rng(3))
            estimate = ("attitude", case)
        p = with_estimates(build_pass(log), estimate)
        X = initial_block(p, x[np.searchsorted(t, p.t_s)])[0]
    lay = p.layout
    scale = np.concatenate([[2e3] * 3, [1.0] * 3] + [
        np.r_[[2e3] * 3, [1.0] * 3] if v.orbit else np.full(v.dim, 50.0 if v.manifold.additive
                                                          else 0.01) for v in lay.extra])
    if lay.has("gyro_bias"):
        scale[lay.slices["gyro_bias"]] = 1e-4
    if lay.has("attitude_rate"):
        scale[lay.slices["attitude_rate"]] = 0.01
    return p, X + rng.normal(0, 1, X.shape) * scale


FAMILY_CASES = ("formation", "refraction-bias", "gyro-bias", "attitude-rate", "camera-alignment")


@pytest.mark.parametrize("case", FAMILY_CASES)
def test_motion_and_process_rows_and_factors_agree(case):
    """Every step's rows of the orbit motion (``graph.motion_rows``) and of the further
    variables' processes (``graph.process_rows``) are those of the GTSAM factors of the same
    step (``graph.motion_factors``, ``graph.process_factors``), variable by variable, at a
    block off the truth; and the two families together cover every row of the step."""
    from fgnav.graph import motion_factors, motion_rows, process_factors, process_rows, step_rows
    from fgnav.solvers.options import SmootherOptions

    p, X = _family_pass(case)
    lay = p.layout
    opts = SmootherOptions()
    model = opts.motion_model()
    t0 = 123.0
    M0, M1, mb = motion_rows(p, X, opts.q_m2_s3, model, t0)
    V0, V1, vb = process_rows(lay, X[:-1], X[1:], np.diff(p.t_s))
    A0, A1, b = step_rows(p, X, opts.q_m2_s3, model, t0)
    np.testing.assert_array_equal(A0, M0 + V0)       # disjoint rows: the sum is the stack
    np.testing.assert_array_equal(A1, M1 + V1)
    np.testing.assert_array_equal(b, mb + vb)
    covered = np.zeros(lay.n, bool)
    for k in (1, p.n_epochs // 2, p.n_epochs - 1):
        values = _values(lay, X, (k - 1, k))
        dt = p.t_s[k] - p.t_s[k - 1]
        facs = motion_factors(lay, k, dt, opts.q_m2_s3, model, t0 + p.t_s[k - 1])
        assert len(facs) == len(lay.orbits)
        for v, f in zip(lay.orbits, facs):
            F0, F1, fb = _two_epoch_blocks(f.linearize(values), lay, k)
            rows = lay.slices[v.name]
            _assert_rows(F0, F1, fb, M0[k - 1][rows], M1[k - 1][rows], mb[k - 1][rows],
                         f"motion of {v.name}, step {k}")
            covered[rows] = True
        facs = process_factors(lay, k, dt)
        assert len(facs) == len(lay.groups)
        for (owner, names), f in zip(lay.groups, facs):
            F0, F1, fb = _two_epoch_blocks(f.linearize(values), lay, k)
            rows = np.concatenate([np.arange(lay.n)[lay.slices[m]] for m in names])
            _assert_rows(F0, F1, fb, V0[k - 1][rows], V1[k - 1][rows], vb[k - 1][rows],
                         f"process of {names}, step {k}")
            assert not np.any(V0[k - 1][np.setdiff1d(np.arange(lay.n), rows)][:, rows])
            covered[rows] = True
    assert covered.all(), "a variable has no process"
    if case == "attitude-rate":   # one joint 6-row process (attitude and rate)
        assert [names for _, names in lay.groups] == [("attitude", "attitude_rate")]


@pytest.mark.parametrize("case", FAMILY_CASES)
def test_prior_rows_and_factors_agree(case):
    """The further variables' priors at the first epoch: the bulk rows (``graph.prior_rows``,
    in ``linearize_all``) and the GTSAM prior factors (``graph.prior_factors``) give the same
    whitened rows at a block off the prior mean; the filter's first covariance
    (``graph.prior_block_covariance``) is the inverse of their information at the mean."""
    from fgnav.graph import prior_block_covariance, prior_factors, prior_rows

    p, X = _family_pass(case)
    lay = p.layout
    k, A, b, tags = prior_rows(p, X)
    assert np.all(k == 0)
    facs = prior_factors(lay)
    assert len(facs) == len(lay.parameters) > 0
    values = _values(lay, X, (0,))
    for v, f in zip(lay.parameters, facs):
        lin = f.linearize(values)
        A_i, b_i = lin.jacobian()
        assert list(lin.keys()) == [v.key(0)]
        mine = tags == f"prior_{v.name}"
        assert mine.sum() == v.dim
        A_layout = np.zeros((v.dim, lay.n))
        A_layout[:, lay.slices[v.name]] = A_i
        np.testing.assert_allclose(A_layout, A[mine], rtol=1e-9, atol=1e-12 * np.abs(A[mine]).max())
        np.testing.assert_allclose(b_i, b[mine], rtol=1e-9, atol=1e-9)
        assert np.abs(b[mine]).max() > 1e-6          # off the mean: a residual to compare
    # at the prior mean the rows' information is the covariance's inverse
    X_mean = lay.initial(X[:, :6])
    _, A_m, _, tags_m = prior_rows(p, X_mean)
    P0 = prior_block_covariance(lay, [np.eye(6) * 4.0] * len(lay.orbits))
    for v in lay.parameters:
        sl = lay.slices[v.name]
        rows = A_m[tags_m == f"prior_{v.name}"][:, sl]
        np.testing.assert_allclose(np.linalg.inv(rows.T @ rows), P0[sl, sl], rtol=1e-12)
    for v in lay.orbits:
        np.testing.assert_array_equal(P0[lay.slices[v.name], lay.slices[v.name]], np.eye(6) * 4.0)


def _manoeuvre_pass():
    """A gto-transfer pass (0.5 h) with two declared burns: one on a sensor epoch, one between
    two (the row makes an epoch of its own), and the block values off the truth."""
    from fgnav.scenarios import ManoeuvreSpec

    scn = load_scenario("gto-transfer").with_options(duration_h=0.5, manoeuvres=(
        ManoeuvreSpec(600.0, (0.3, 0.4, 0.0), 0.05), ManoeuvreSpec(1205.0, (0.0, -0.2, 0.1), 0.02)))
    sim = simulate_pass(scn, seed=4)
    p = build_pass(sim.log)
    rng = np.random.default_rng(12)
    X = sim.x_true[np.searchsorted(sim.t_s, p.t_s)] + rng.normal(0, 1, (p.n_epochs, 6)) * np.r_[
        [2e3] * 3, [1.0] * 3]
    return p, X


def test_motion_rows_and_factors_agree_with_a_declared_manoeuvre():
    """A step that ends with a declared burn (``graph.impulses``): its bulk rows
    (``graph.motion_rows``, chunked or not) are those of its GTSAM motion factor
    (``graph.motion_factors`` with the impulse), mean ``[0; dv]`` and noise ``Q + [0; S]``;
    the other steps keep the plain motion rows."""
    from fgnav.graph import impulses, motion_factors, motion_rows
    from fgnav.solvers.options import SmootherOptions

    p, X = _manoeuvre_pass()
    imp = impulses(p)
    assert sorted(imp) == [int(np.searchsorted(p.t_s, 600.0)), int(np.searchsorted(p.t_s, 1205.0))]
    assert 1205.0 in p.t_s   # between two sensor epochs (10 s apart): an epoch of its own
    opts = SmootherOptions()
    model = opts.motion_model()
    t0 = 123.0
    M0, M1, mb = motion_rows(p, X, opts.q_m2_s3, model, t0)
    C0, C1, cb = motion_rows(p, X, opts.q_m2_s3, model, t0, chunked=True)
    np.testing.assert_array_equal(np.concatenate(C0), M0)
    np.testing.assert_array_equal(C1, M1)
    np.testing.assert_array_equal(cb, mb)
    lay = p.layout
    for k in sorted(imp) + [1, min(imp) + 1]:
        values = _values(lay, X, (k - 1, k))
        dt = p.t_s[k] - p.t_s[k - 1]
        (f,) = motion_factors(lay, k, dt, opts.q_m2_s3, model, t0 + p.t_s[k - 1], imp.get(k))
        F0, F1, fb = _two_epoch_blocks(f.linearize(values), lay, k)
        _assert_rows(F0, F1, fb, M0[k - 1], M1[k - 1], mb[k - 1], f"motion, step {k}")
    # the burn's rows differ from the plain motion's: the mean shifts, the noise widens
    k = min(imp)
    plain = motion_rows(type(p)(p.epoch0, p.t_s, p.families), X, opts.q_m2_s3, model, t0)
    assert not np.allclose(plain[2][k - 1], mb[k - 1])
    np.testing.assert_array_equal(plain[2][k], mb[k])
