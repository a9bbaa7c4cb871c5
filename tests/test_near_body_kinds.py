"""The near-body log kinds (issue 31 item 1): ``body_direction``, ``body_direction_body`` and
``limb_radius`` with a ``body`` column, read, simulated and smoothed.

Model against simulator from log rows (the rows written and read back, the models'
``factors.near_body`` against ``fgnav.simulate.near_bodies``' barycentric light time and
ERFA aberration); the reader's errors; and a GTO pass with an optical camera imaging the
Moon and the Earth smoothed by every method, against the truth of the independent
integrator (scipy DOP853), with its NEES over seeds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgnav import api
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import BODIES, read_log, write_log
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import LOG_SCHEMA, MODELS
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.faults import with_rows
from fgnav.simulate.near_bodies import simulate_near_body_rows
from fgnav.simulate.pass_sim import chunks_to_log, simulate_pass
from fgnav.solvers import ekf_numba
from fgnav.solvers.ekf import run_ekf

MAS = np.pi / 180.0 / 3.6e6


class _NoNoise:
    """An rng whose draws are zero: the simulator's noise-free rows."""

    def standard_normal(self, shape):
        return np.zeros(shape)


def _gto(hours=3.0):
    return load_scenario("gto-transfer").with_options(duration_h=hours, step_s=60.0)


def _camera(sigma_deg=2e-3, period_s=300.0):
    return (SensorSpec("body_direction", body="moon", sigma_deg=sigma_deg, period_s=period_s),
            SensorSpec("limb_radius", body="moon", sigma_deg=sigma_deg, period_s=period_s),
            SensorSpec("body_direction", body="earth", sigma_deg=sigma_deg, period_s=period_s))


@pytest.mark.parametrize("body", ["moon", "earth", "sun"])
def test_models_match_the_simulator_from_log_rows(body, tmp_path):
    """Noise-free rows of every form, written to a CSV and read back: the models' residual at
    the truth is within 3 mas (the first-order planetary aberration against ERFA's rigorous
    ab and the iterated light time: tests/test_near_body.py), while the light time and the
    aberration each are worth far more (docs/cislunar.md). The Earth's limb near the GTO's
    perigee (a 70 deg disc) is within 1 microradian: the first-order ``rho (1 - beta . u)``
    against the aberrated limb circle of a large disc (1 % of a limb sensor's 0.005 deg)."""
    sim = simulate_pass(_gto(), seed=1)
    t, x = sim.t_s[::30], sim.x_true[::30]
    chunks = []
    for form in ("direction", "direction_body", "limb"):
        spec = SensorSpec("x", body=body, sigma_deg=1e-4)
        chunks += simulate_near_body_rows(spec, t, x, sim.epoch0, _NoNoise(), form=form)
    log = chunks_to_log(sim.epoch0, chunks)
    path = tmp_path / "near.csv"
    write_log(path, log, schema=LOG_SCHEMA)
    log = read_log(path, schema=LOG_SCHEMA)
    assert set(np.unique(log.kind)) == {"body_direction", "body_direction_body", "limb_radius"}
    assert np.all(np.asarray(log.extra["body"]) == BODIES.index(body))
    p = build_pass(log)
    xt = x[np.searchsorted(t, p.t_s)]
    for kind in ("body_direction", "limb_radius"):
        fam = p.families[kind]
        e, _ = MODELS[kind].residual(fam, {"orbit": xt[fam.k]})
        tol = 3 * MAS if (kind, body) != ("limb_radius", "earth") else 1e-6
        assert np.max(np.abs(e)) < tol, (kind, np.max(np.abs(e)) / MAS)
        # without the corrections the model misses by more than 10x that
        off = replace(fam, values={**fam.values, "light_time": np.zeros(len(fam), bool),
                                   "aberration": np.zeros(len(fam), bool)})
        e0, _ = MODELS[kind].residual(off, {"orbit": xt[fam.k]})
        assert np.max(np.abs(e0)) > (30 if kind != "limb_radius" else 1e-3) * MAS
    # the body frame: on the attitude the simulator used (LVLH)
    fam = build_pass(log).deferred["body_direction_body"]
    R = lvlh_R_eci_from_body(xt[fam.k])
    e, jac = MODELS["body_direction_body"].residual(fam, {"orbit": xt[fam.k], "attitude": R})
    assert np.max(np.abs(e)) < 3 * MAS and set(jac) == {"orbit", "attitude"}


def _csv(tmp_path, rows):
    path = tmp_path / "m.csv"
    path.write_text("epoch,kind,x,y,z,sigma,body\n" + "".join(r + "\n" for r in rows))
    return path


def test_the_reader_names_file_line_and_column(tmp_path):
    ok = "2025-03-01T00:00:00Z,body_direction,1,0,0,1e-5,moon"
    log = read_log(_csv(tmp_path, [ok, "2025-03-01T00:00:00Z,limb_radius,0.01,1737400,,1e-5,"]),
                   schema=LOG_SCHEMA)
    assert len(log.kind) == 2 and np.isnan(log.extra["body"][1])      # empty body: the Earth
    with pytest.raises(InputFormatError, match=r"m\.csv.*line 3.*body"):
        read_log(_csv(tmp_path, [ok, "2025-03-01T00:00:00Z,body_direction,1,0,0,1e-5,"]),
                 schema=LOG_SCHEMA)
    with pytest.raises(InputFormatError, match=r"m\.csv.*line 2.*body.*mars"):
        read_log(_csv(tmp_path, ["2025-03-01T00:00:00Z,limb_radius,0.01,1737400,,1e-5,mars"]),
                 schema=LOG_SCHEMA)
    with pytest.raises(InputFormatError, match=r"m\.csv.*line 2.*kind"):   # the format alone
        read_log(_csv(tmp_path, [ok]))


def test_earth_limb_rows_without_a_body_keep_their_numbers():
    """A ``limb_radius`` family without a ``body`` has the values and the packed rows it had
    before the column (the Earth's limb at the origin, ``factors.limb``)."""
    sim = simulate_pass(load_scenario("geo-limb").with_options(duration_h=0.5), seed=2)
    fam = build_pass(sim.log).families["limb_radius"]
    assert set(fam.values) == {"rho_rad", "r_limb_m"}
    d, B = MODELS["limb_radius"].numba_data(fam)
    assert B is None and d.shape == (len(fam), 3)


def _smoothed(seed, method="batch", hours=3.0):
    scn = _gto(hours)
    sim = simulate_pass(replace(scn, sensors=scn.sensors + _camera()), seed=seed)
    return sim, api.smooth(sim.log, method, truth=sim)


def test_a_pass_imaging_the_moon_and_the_earth_is_smoothed_within_its_bound():
    """Batch over 8 seeds: position error against the truth within 2x the batch's own
    sigma, and the mean 6-dof NEES over the seeds' epochs inside the 99 % band of its
    chi-square (8 independent passes: 6 * 8 dof per epoch); the Moon's limb rows (with
    their body) enter the graph."""
    nees, ratio = [], []
    for seed in range(8):
        sim, res = _smoothed(seed)
        s = res.summary
        nees.append(s["nees_mean"])
        ratio.append(s["position_rms_m"] / s["sigma_position_rms_m"])
        p = res.pass_
        assert {"body_direction", "limb_radius"} <= set(p.families)
        assert np.count_nonzero(np.isfinite(p.families["limb_radius"].values["body"])) > 20
    # chi2(48)/8: 99 % band [25.0, 76.2] / 8
    assert 25.0 / 8 < np.mean(nees) < 76.2 / 8, nees
    assert np.sqrt(np.mean(np.square(ratio))) < 2.0, ratio


@pytest.mark.parametrize("method", ["isam2", "fixed-lag", "ekf"])
def test_every_method_smooths_the_near_body_rows(method):
    """A 1.5 h pass: every method takes the rows (the EKF by the compiled dispatch, the same
    numbers as the numpy EKF) and ends within 3 sigma of the truth."""
    sim, res = _smoothed(5, method, hours=1.5)
    s = res.summary
    assert s["position_rms_m"] < 3.0 * s["sigma_position_rms_m"], s
    if method == "ekf":
        p = build_pass(sim.log)
        assert ekf_numba.numba_supports(p)
        fast, ref = ekf_numba.run_ekf_numba(p), run_ekf(p)
        assert np.allclose(fast.x_eci, ref.x_eci, rtol=0.0, atol=1e-3)


def test_body_frame_rows_wait_for_the_attitude():
    """``body_direction_body`` rows need the attitude: deferred without it, a factor on
    (orbit, attitude) with ``--estimate attitude``."""
    scn = load_scenario("geo-limb").with_options(duration_h=0.5)
    sim = simulate_pass(replace(scn, sensors=scn.sensors + (
        SensorSpec("body_direction_body", body="moon", sigma_deg=2e-3),)), seed=1)
    p = build_pass(sim.log)
    assert "body_direction_body" in p.deferred and "body_direction_body" not in p.families
    assert MODELS["body_direction_body"].enters(with_estimates(p, ("attitude",)).layout)


def test_a_rebuilt_log_keeps_the_kinds_it_was_read_with(tmp_path):
    """A log read with the models' schema carries it: a fault drawn on it
    (:func:`fgnav.simulate.faults.with_rows`), and :func:`write_log` without a ``schema``,
    accept the near-body kinds the format's own table does not list (before, both refused
    them as unknown kinds), and the rebuilt log keeps the log's centre."""
    sim = simulate_pass(_gto(1.0), seed=3)
    chunks = simulate_near_body_rows(SensorSpec("x", body="moon", sigma_deg=1e-3),
                                     sim.t_s[::10], sim.x_true[::10], sim.epoch0, _NoNoise(),
                                     form="direction")
    path = tmp_path / "moon.csv"
    write_log(path, chunks_to_log(sim.epoch0, chunks), schema=LOG_SCHEMA)
    log = read_log(path, schema=LOG_SCHEMA)
    with pytest.raises(UserError, match="body_direction"):
        read_log(path)                      # the format's own kinds: refused, by name
    keep = np.arange(len(log)) % 2 == 0
    sub = with_rows(log, keep=keep)
    assert len(sub) == keep.sum() and set(np.unique(sub.kind)) == {"body_direction"}
    assert sub.centre == log.centre and sub.schema is log.schema
    write_log(tmp_path / "sub.csv", sub)     # the log's own schema
    back = read_log(tmp_path / "sub.csv", schema=LOG_SCHEMA)
    assert np.allclose(back.xyz, sub.xyz) and np.all(back.kind == sub.kind)
