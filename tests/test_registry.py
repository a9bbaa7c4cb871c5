"""The measurement-model registry is the one place that maps a log kind to its behaviour.

* no module outside the registry (and the log format's definition) names a kind to choose
  what to do (the kind strings are scanned in the sources);
* every kind the registry knows is a kind of the log format, and the other way round;
* every solved model's residual, Jacobians, dimension and GTSAM factor agree with each
  other on a simulated pass (Jacobians against central differences, the factor's
  linearization against the model's whitened rows);
* every model with a numba kernel is dispatched by the compiled EKF and gives there the
  whitened rows of the numpy route.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fgnav.io import log_csv, tdm
from fgnav.graph import initial_block
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.measurements import Pass, build_pass, with_estimates
from fgnav.models.registry import (ALTITUDE, ATTITUDE_VARIABLE, BODY_BODY_ANGLE, BODY_DIRECTION,
                                   BODY_DIRECTION_BODY,
                                   BODY_STAR_ANGLE, EARTH_DIRECTION, GYRO_BIAS, LIMB_STAR_ANGLE,
                                   EARTH_DIRECTION_BODY, LIMB_RADIUS, MODELS, REFRACTION,
                                   MOON_DIRECTION_BODY, STAR_DIRECTION_BODY,
                                   SUN_DIRECTION_BODY, solved_models)
from fgnav.iod import angles
from fgnav.models import isl, registry
from fgnav.models.variables import ORBIT, Layout
from fgnav.scenarios import SENSOR_KEYS, SENSOR_KIND_KEYS, SensorSpec, load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.simulate.simulators import SIMULATORS, simulated_kinds
from fgnav.solvers import ekf_numba
from attitude_passes import with_gyro

ROOT = Path(__file__).resolve().parents[1]
REGISTRY = "fgnav/models/registry.py"
# the modules that define the kinds (one module per family, assembled by the registry)
MODEL_FILES = {f"fgnav/models/{m.__name__.rsplit('.', 1)[1]}.py" for m in registry.FAMILY_MODULES}
LOG_FORMAT = "fgnav/io/log_csv.py"

# Double-quoted kind strings outside the registry and the log format that do not choose
# behaviour by a kind (file -> kinds, and why).
NOT_A_CHOICE = {
    # the refraction simulator labels the attitude rows it derives from the unrefracted
    # stars; it cannot import the registry (the registry imports it)
    "fgnav/simulate/refraction_sim.py": {"attitude"},
    # "refraction" is also the name of a scheme of `fgnav schemes` (a CLI choice)
    "fgnav/commands/schemes.py": {"refraction"},
    # the log format's module for several spacecraft names its inter-satellite kinds (the
    # format's definition, as log_csv.py; it cannot import the registry, which imports it)
    "fgnav/io/log_spacecraft.py": {"isl_pseudorange", "isl_carrier_phase"},
}


def _sources():
    for path in sorted((ROOT / "fgnav").rglob("*.py")) + sorted((ROOT / "factors").rglob("*.py")):
        yield path.relative_to(ROOT).as_posix(), path.read_text(encoding="utf-8")


def test_earth_direction_is_named_by_its_model_module_and_the_log_format_only():
    """The issue's acceptance check: ``git grep -l '"earth_direction"' -- fgnav``."""
    found = {name for name, text in _sources() if '"earth_direction"' in text}
    assert "fgnav/models/directions.py" in found
    assert found <= {"fgnav/models/directions.py", LOG_FORMAT}, sorted(found)


def test_no_kind_string_outside_the_registry_and_the_log_format():
    pattern = re.compile(r'"(' + "|".join(map(re.escape, MODELS)) + r')"')
    offenders = {}
    for name, text in _sources():
        if name in MODEL_FILES or name == LOG_FORMAT:
            continue
        kinds = set(pattern.findall(text)) - NOT_A_CHOICE.get(name, set())
        if kinds:
            offenders[name] = sorted(kinds)
    assert not offenders, ("kind strings outside the models' modules (use the model "
                           f"constants or flags): {offenders}")


def test_the_registry_and_the_log_format_know_the_same_kinds():
    # the format's own kinds, and those a family module adds (LOG_KINDS: the near bodies'),
    # each a measurement model or a kind that enters the motion (a declared manoeuvre)
    assert set(MODELS) | set(registry.MOTION_KINDS) == set(registry.LOG_SCHEMA)
    assert not set(MODELS) & set(registry.MOTION_KINDS) and registry.MOTION_KINDS
    assert set(log_csv.KINDS) <= set(MODELS)
    assert set(log_csv.SIGMA_RANGE) == set(log_csv.KINDS)
    # a kind drawn as a direction, or turned into one, is a unit vector in the log
    directions = {k for k, m in MODELS.items() if m.eci_ray or m.body_frame_of} | set(
        angles.DIRECTION_KINDS)
    assert directions and directions <= set(log_csv.DIRECTION_KINDS)
    assert MODELS[LIMB_RADIUS.kind].range_m is not None
    assert LIMB_RADIUS.kind not in log_csv.DIRECTION_KINDS


def test_isl_models_read_the_attitude_rows_of_the_registry_and_are_registered():
    assert isl.ATTITUDE_KIND == registry.ATTITUDE.kind
    assert tuple(m.kind for m in (isl.ISL_PSEUDORANGE, isl.ISL_CARRIER_PHASE)) == ISL_KINDS
    assert all(MODELS[k] is getattr(registry, k.upper()) for k in ISL_KINDS)


def test_the_tdm_reader_writes_the_kind_of_the_earth_direction_model():
    assert tdm.EARTH_DIRECTION_KIND == log_csv.EARTH_DIRECTION_KIND == EARTH_DIRECTION.kind


def test_every_scenario_key_of_a_simulator_is_validated_by_the_scenario_reader():
    assert set(SENSOR_KIND_KEYS) == set(simulated_kinds())
    assert set(SIMULATORS) <= set(MODELS), "a simulator of a kind no model reads"
    for kind, keys in SENSOR_KIND_KEYS.items():
        assert set(keys) <= set(SENSOR_KEYS), (kind, set(keys) - set(SENSOR_KEYS))
    assert "model_bias_drift_m_per_h" in SENSOR_KIND_KEYS[REFRACTION.kind]


# ---- one simulated pass with a family of every solved model -------------------------------

@pytest.fixture(scope="module")
def sim_pass():
    """Six minutes of LEO: priors, Earth direction (ECI and body frame), Sun and Moon
    directions (body frame), limb radius, altimeter, refraction and its attitude rows, a star
    camera's raw stars (the attitude estimated, so that the attitude, star and body-frame rows
    enter the graph), the attitude-free angles (Earth-limb - star, Moon - star, Earth - Moon),
    the Moon's direction (ECI and body frame) and limb radius."""
    base = load_scenario("refraction-leo")
    sensors = (SensorSpec(EARTH_DIRECTION.kind, sigma_deg=0.01, period_s=60.0),
               SensorSpec(LIMB_RADIUS.kind, sigma_deg=0.02, period_s=60.0),
               SensorSpec(ALTITUDE.kind, sigma_m=300.0, period_s=60.0),
               SensorSpec(EARTH_DIRECTION_BODY.kind, sigma_deg=0.02, period_s=60.0),
               SensorSpec(STAR_DIRECTION_BODY.kind, star_sigma_arcsec=5.0, fov_deg=12.85,
                          vmag_max=5.5, period_s=60.0),
               SensorSpec(SUN_DIRECTION_BODY.kind, sigma_deg=0.01, period_s=60.0),
               SensorSpec(MOON_DIRECTION_BODY.kind, sigma_deg=0.02, period_s=60.0,
                          min_sun_elongation_deg=30.0),
               SensorSpec(LIMB_STAR_ANGLE.kind, sigma_deg=0.005, body="earth", vmag_max=4.0,
                          period_s=60.0),
               SensorSpec(BODY_STAR_ANGLE.kind, sigma_deg=0.002, body="moon", vmag_max=4.0,
                          stars_per_epoch=2, period_s=60.0),
               SensorSpec(BODY_BODY_ANGLE.kind, sigma_deg=0.005, body="earth", body2="moon",
                          period_s=60.0),
               *base.sensors,
               # an optical navigation camera on the Moon (the limb with its body column)
               SensorSpec(BODY_DIRECTION.kind, sigma_deg=0.002, body="moon", period_s=60.0),
               SensorSpec(BODY_DIRECTION_BODY.kind, sigma_deg=0.002, body="moon",
                          period_s=60.0),
               SensorSpec(LIMB_RADIUS.kind, sigma_deg=0.002, body="moon", period_s=60.0))
    sim = simulate_pass(base.with_options(sensors=sensors, duration_h=0.1), seed=3)
    # and a rate gyro between consecutive epochs (attitude rows thinned to one epoch in six)
    log, _ = with_gyro(sim.log, sim.t_s, sim.x_true, np.array([1e-4, -5e-5, 8e-5]), 1e-6,
                       np.random.default_rng(5))
    p = with_estimates(build_pass(log), (ATTITUDE_VARIABLE.name, GYRO_BIAS.name))
    x_true = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    # a plausible state off the truth (residuals well away from zero)
    rng = np.random.default_rng(11)
    x = x_true + np.concatenate([rng.normal(0.0, 200.0, (len(x_true), 3)),
                                 rng.normal(0.0, 0.2, (len(x_true), 3))], axis=1)
    # the attitude at the measured attitude, 0.01 rad off (residuals away from zero, far from
    # the cut locus of the direction residuals)
    att = initial_block(p, x)[0][:, p.layout.slices[ATTITUDE_VARIABLE.name]]
    return p, x, att + rng.normal(0.0, 0.01, att.shape)


@pytest.fixture(scope="module")
def formation():
    """Two spacecraft half an hour apart by 1 km: priors and Earth directions each, one-way
    pseudoranges and carrier phases both ways between antennas off the centre of mass
    (turned by attitude rows), the pair's clock, the carrier links' ambiguities
    (tests/formation_data.py); the block off the truth by 200 m, 0.2 m/s, 2 m of clock."""
    from formation_data import formation_log

    log, truth = formation_log(1, carrier=True, lever_arms=True)
    p = build_pass(log)
    lay = p.layout
    X = lay.initial(truth["A"][1])
    X[:, lay.slices["orbit_B"]] = truth["B"][1]
    rng = np.random.default_rng(12)
    X += rng.normal(0.0, 1.0, X.shape) * np.r_[[200.0] * 3, [0.2] * 3, [200.0] * 3, [0.2] * 3,
                                               [2.0] * (lay.n - 12)]
    return p, X


def _per_row(mdl) -> bool:
    """Models whose rows bind their own variables (a formation's links)."""
    return mdl.kind in ("isl_pseudorange", "isl_carrier_phase")


def _case(request, kind):
    """``(family, layout, block values)`` of ``kind``: the formation's pass for a link, the
    one-spacecraft pass for the others."""
    mdl = MODELS[kind]
    if _per_row(mdl):
        p, X = request.getfixturevalue("formation")
        return p.families[kind], p.layout, X
    p, x, att = request.getfixturevalue("sim_pass")
    layout = _layout(mdl)
    return p.families[kind], layout, _block(layout, x, att)


def _layout(mdl):
    return Layout((ORBIT,) + tuple(mdl.optional_variables))


def _block(layout, x_orbit, att):
    X = layout.initial(x_orbit)
    for i, v in enumerate(layout.extra):
        # an attitude near the measured one; a bias at half its prior sigma (500 m of
        # refraction bias, 5e-4 rad/s of gyro bias)
        X[:, layout.slices[v.name]] = att if v.manifold == "rot3" else 0.5 * v.prior_sigma
    return X


def _insert(gtsam, values, key, v, w):
    values.insert(key, gtsam.Rot3.Expmap(w) if v.manifold == "rot3" else np.asarray(w, float))


def test_the_pass_has_a_family_of_every_solved_model(sim_pass, formation):
    p, _, _ = sim_pass
    missing = [m.kind for m in MODELS.values() if m.solved and m.kind not in p.families
               and not (_per_row(m) and m.kind in formation[0].families)]
    assert not missing, f"add a sensor of {missing} to the sim_pass fixture"


@pytest.mark.parametrize("kind", [m.kind for m in solved_models(MODELS) if not m.between])
def test_model_residual_jacobians_and_dim_agree(request, kind):
    mdl = MODELS[kind]
    fam, layout, X = _case(request, kind)
    if not _per_row(mdl):
        vals_all = layout.values_at(X, fam.k)
        e_raw, jac = mdl.residual(fam, {n: vals_all[n] for n in mdl.variables_in(layout)})
        assert set(jac) <= {"position"} | set(mdl.variables_in(layout))
        assert np.asarray(e_raw).size == len(fam) * mdl.dim
    e, H = mdl.evaluate(fam, X, layout)
    assert e.shape == (len(fam), mdl.dim) and H.shape == (len(fam), mdl.dim, layout.n)
    assert np.all(np.isfinite(e)) and np.all(np.isfinite(H)) and np.any(e != 0.0)
    # central differences in every column of the block (1 m, 1 m/s, 1 m, 1e-6 rad steps)
    steps = np.concatenate([np.full(v.dim, 1e-6 if v.manifold == "rot3" else 1.0)
                            for v in layout.variables])
    for c in range(layout.n):
        dX = np.zeros_like(X)
        dX[:, c] = steps[c]
        e_p, _ = mdl.evaluate(fam, layout.retract(X, dX), layout)
        e_m, _ = mdl.evaluate(fam, layout.retract(X, -dX), layout)
        fd = (e_p - e_m) / (2.0 * steps[c])
        np.testing.assert_allclose(fd, H[..., c], rtol=1e-5, atol=1e-7 * np.abs(H).max(),
                                   err_msg=f"{kind}: column {c}")


@pytest.mark.parametrize("kind", [m.kind for m in solved_models(MODELS) if not m.between])
def test_model_factor_linearizes_to_the_model_rows(request, kind):
    gtsam = pytest.importorskip("gtsam")
    mdl = MODELS[kind]
    fam, layout, X = _case(request, kind)
    A, b, _ = mdl.linearize(fam, X, layout)
    assert A.shape == (len(fam), mdl.dim, layout.n) and b.shape == (len(fam), mdl.dim)
    for j in sorted({0, len(fam) // 2, len(fam) - 1}):
        k = int(fam.k[j])
        keys = mdl.keys(layout, k, fam, j)
        by_key = {v.key(k): v for v in layout.variables}
        values = gtsam.Values()
        for name, key in keys.items():
            v = by_key[key]
            _insert(gtsam, values, key, v, X[k, layout.slices[v.name]])
        (factor,) = mdl.factors(fam, [j], k, layout, x_guess=X[k, :6])
        assert factor.dim() == mdl.dim
        assert factor.error(values) == pytest.approx(0.5 * float(b[j] @ b[j]), rel=1e-9)
        lin = factor.linearize(values)
        A_g, b_g = lin.jacobian()
        np.testing.assert_allclose(b_g, b[j], rtol=1e-9, atol=1e-12)
        col = 0
        for key in lin.keys():
            sl = layout.slices[by_key[key].name]
            width = sl.stop - sl.start
            np.testing.assert_allclose(A_g[:, col:col + width], A[j][:, sl], rtol=1e-7,
                                       atol=1e-9 * np.abs(A[j]).max(), err_msg=f"{kind} row {j}")
            col += width
        assert col == A_g.shape[1] == sum(by_key[key].dim for key in keys.values())


def test_star_model_without_and_with_the_camera_alignment(sim_pass):
    """The star rows are the plain attitude model unless the camera alignment is estimated:
    with the alignment at the identity both give the same residual and attitude Jacobian,
    and the alignment's Jacobian is the attitude's turned by the mounting (here the identity,
    so equal); with a mounting of 1 arcmin the residual moves by at most about that angle (residuals
    0.01 rad off: the log map bends the difference by ~1e-4 of it)."""
    from factors.constants import ARCSEC
    from fgnav.models.registry import CAMERA_ALIGNMENT

    p, x, att = sim_pass
    mdl = MODELS[STAR_DIRECTION_BODY.kind]
    fam = p.families[mdl.kind]
    plain = Layout((ORBIT, ATTITUDE_VARIABLE))
    aligned = Layout((ORBIT, ATTITUDE_VARIABLE, CAMERA_ALIGNMENT))
    assert set(mdl.variables_in(plain)) == {ORBIT.name, ATTITUDE_VARIABLE.name}  # aberration: v
    assert set(mdl.keys(aligned, 4)) == {ORBIT.name, ATTITUDE_VARIABLE.name,
                                         CAMERA_ALIGNMENT.name}
    X0 = _block(plain, x, att)
    X1 = aligned.initial(x)
    X1[:, aligned.slices[ATTITUDE_VARIABLE.name]] = att
    e0, H0 = mdl.evaluate(fam, X0, plain)
    e1, H1 = mdl.evaluate(fam, X1, aligned)
    np.testing.assert_allclose(e1, e0, atol=1e-15)
    sa, sm = aligned.slices[ATTITUDE_VARIABLE.name], aligned.slices[CAMERA_ALIGNMENT.name]
    np.testing.assert_allclose(H1[..., sa], H0[..., plain.slices[ATTITUDE_VARIABLE.name]],
                               atol=1e-15)
    np.testing.assert_allclose(H1[..., sm], H1[..., sa], atol=1e-15)
    X1[:, sm] = np.array([60.0, 0.0, 0.0]) * ARCSEC
    e2, _ = mdl.evaluate(fam, X1, aligned)
    shift = np.linalg.norm(e2 - e1, axis=1)
    assert np.all(shift <= 60.0 * ARCSEC * (1 + 1e-3)) and np.max(shift) > 30.0 * ARCSEC


def test_every_numba_kernel_is_dispatched_and_matches_the_numpy_rows(sim_pass):
    p, x, _ = sim_pass
    compiled = [m for m in MODELS.values() if m.numba_kernel is not None]
    assert len(compiled) >= 4
    for mdl in compiled:
        assert any(mdl.numba_kernel is kern for kern in ekf_numba.ROW_KERNELS), mdl.kind
    q = Pass(epoch0=p.epoch0, t_s=p.t_s,
             families={m.kind: p.families[m.kind] for m in compiled if m.kind in p.families})
    assert set(q.families) == {m.kind for m in compiled}
    assert ekf_numba.numba_supports(q)
    packed = ekf_numba.pack_pass(q)
    layout = Layout()
    for mdl in compiled:
        fam = q.families[mdl.kind]
        A_np, b_np, _ = mdl.linearize(fam, x, layout)
        row0, order = packed.spans[mdl.kind]
        code = next(i for i, kern in enumerate(ekf_numba.ROW_KERNELS) if kern is mdl.numba_kernel)
        for i in sorted({0, len(fam) - 1}):
            j = int(order[i])
            A = np.zeros((64, 6))
            b = np.zeros(64)
            n = ekf_numba._rows(code, np.ascontiguousarray(x[fam.k[j]]), packed.m_data[row0 + i],
                                packed.m_B[row0 + i], packed.m_sigma[row0 + i], A, b, 0)
            assert n == mdl.dim
            np.testing.assert_allclose(b[:n], b_np[j], rtol=1e-9, atol=1e-12, err_msg=mdl.kind)
            np.testing.assert_allclose(A[:n], A_np[j], rtol=1e-9,
                                       atol=1e-12 * np.abs(A_np[j]).max(), err_msg=mdl.kind)


@pytest.mark.parametrize("kind", [m.kind for m in solved_models(MODELS) if m.between])
def test_between_model_jacobians_and_factor(sim_pass, kind):
    """A model whose rows join two epochs (a gyro interval): central differences in every
    column of both blocks, and its GTSAM factor linearizes to the same rows."""
    gtsam = pytest.importorskip("gtsam")
    p, x, att = sim_pass
    mdl = MODELS[kind]
    # rows ending at odd epochs: their intervals share no epoch, so one perturbation of all
    # of them differentiates each row alone
    fam = p.families[kind].subset(np.flatnonzero(p.families[kind].k % 2 == 1))
    layout = _layout(mdl)
    X = _block(layout, x, att)
    e, H0, H1, dt = mdl.evaluate_between(fam, X, layout, p.t_s)
    assert e.shape == (len(fam), mdl.dim) and np.any(e != 0.0) and np.all(dt > 0)
    steps = np.concatenate([np.full(v.dim, 1e-6 if v.manifold == "rot3" else
                                    (1e-7 if v.unit == "rad/s" else 1.0)) for v in layout.variables])
    for H, shift in ((H0, -1), (H1, 0)):
        for c in range(layout.n):
            dX = np.zeros_like(X)
            dX[fam.k + shift, c] = steps[c]
            e_p = mdl.evaluate_between(fam, layout.retract(X, dX), layout, p.t_s)[0]
            e_m = mdl.evaluate_between(fam, layout.retract(X, -dX), layout, p.t_s)[0]
            np.testing.assert_allclose((e_p - e_m) / (2 * steps[c]), H[..., c], rtol=1e-5,
                                       atol=1e-7 * max(np.abs(H).max(), 1e-300),
                                       err_msg=f"{kind}: block {shift}, column {c}")
    A0, A1, b, _ = mdl.linearize_between(fam, X, layout, p.t_s)
    for j in sorted({0, len(fam) // 2, len(fam) - 1}):
        k = int(fam.k[j])
        values = gtsam.Values()
        for kk in (k - 1, k):
            for name, key in mdl.keys(layout, kk).items():
                _insert(gtsam, values, key, layout.variables[layout.names.index(name)],
                        X[kk, layout.slices[name]])
        (factor,) = mdl.factors(fam, [j], k, layout, t_s=p.t_s)
        lin = factor.linearize(values)
        A_g, b_g = lin.jacobian()
        np.testing.assert_allclose(b_g, b[j], rtol=1e-9, atol=1e-12)
        where = {}
        for kk, A in ((k - 1, A0), (k, A1)):
            for name, key in mdl.keys(layout, kk).items():
                where[key] = (A[j], layout.slices[name])
        col = 0
        for key in lin.keys():
            A, sl = where[key]
            width = sl.stop - sl.start
            np.testing.assert_allclose(A_g[:, col:col + width], A[:, sl], rtol=1e-7,
                                       atol=1e-9 * np.abs(A).max(), err_msg=f"{kind} row {j}")
            col += width
        assert col == A_g.shape[1]


def test_attitude_rate_process_rows_against_central_differences(sim_pass):
    """The attitude's body rate (``ATTITUDE_RATE``) is declared by no model: it is the
    variable of the attitude's constant-rate motion, whose rows the solvers take from
    ``fgnav.solvers.process.variable_step_rows`` (the attitude's and the rate's rows joined).
    Central differences in every column of both blocks, at a non-trivial point."""
    from fgnav.models.registry import ATTITUDE_RATE, VARIABLES
    from fgnav.solvers.process import variable_step_rows

    assert VARIABLES[ATTITUDE_RATE.name] is ATTITUDE_RATE
    p, x, att = sim_pass
    layout = Layout((ORBIT, ATTITUDE_VARIABLE, GYRO_BIAS, ATTITUDE_RATE))
    X = _block(layout, x, att)
    rng = np.random.default_rng(4)
    X[:, layout.slices[ATTITUDE_RATE.name]] = rng.normal(0.0, 0.01, (len(X), 3))
    dt = np.diff(p.t_s)
    A0, A1, b = variable_step_rows(layout, X[:-1], X[1:], dt)
    sa, sw = layout.slices[ATTITUDE_VARIABLE.name], layout.slices[ATTITUDE_RATE.name]
    assert np.any(A0[:, sa, sw]) and np.all(A1[:, :6] == 0) and np.any(b[:, sa] != 0)
    X0, X1 = X[:-1], X[1:]
    for A, which in ((A0, 0), (A1, 1)):
        for c in list(range(sa.start, sa.stop)) + list(range(sw.start, sw.stop)):
            step = 1e-6 if c < sa.stop else 1e-7
            dX = np.zeros_like(X0)
            dX[:, c] = step
            bp, bm = (variable_step_rows(
                layout, layout.retract(X0, d) if which == 0 else X0,
                layout.retract(X1, d) if which == 1 else X1, dt)[2] for d in (dX, -dX))
            num = -(bp - bm) / (2 * step)            # b = -W e
            np.testing.assert_allclose(num, A[..., c], rtol=1e-5,
                                       atol=1e-6 * np.abs(A[..., c]).max(),
                                       err_msg=f"block {which}, column {c}")
