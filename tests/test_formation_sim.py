"""Formation scenarios (formation-gto, constellation-leo) in `fgnav simulate`: one log of
several spacecraft, truth-<id>.oem each, truth_clock.csv. The link rows are checked against
an independent prediction from the written files: the truth OEMs, a second-order Taylor
step of the transmitter back over the light time (not the simulator's re-integration), the
attitude truth and the relative clock (Montenbruck & Gill, "Satellite Orbits", 2000,
section 6.2.2, light-time iteration; Xing et al., eq. (1), the clock signs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factors.constants import C_LIGHT_M_S
from factors.geometry import so3_exp, so3_log
from fgnav.cli import main
from fgnav.constants import MU_EARTH_M3_S2
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import read_log
from fgnav.io.log_spacecraft import spacecraft_index
from fgnav.io.oem import read_oem
from fgnav.io.truth_params import read_truth_params_csv
from fgnav.paths import data_dir
from fgnav.scenarios import load_scenario
from fgnav.simulate.formation_sim import simulate_formation_pass
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.time import seconds_since


def _simulate(tmp_path, name, *args):
    out = tmp_path / name
    assert main(["simulate", name, "--out", str(out), "--quiet", *args]) == 0
    return out


def _names(log, column):
    vocab = log.spacecraft if column in ("spacecraft", "tx_spacecraft") else log.antenna_names
    return [None if math.isnan(c) else vocab[int(c)] for c in log.extra[column]]


def _predict(out, light_time=True):
    """(measured, predicted, sigma) of every isl_pseudorange row from the written files."""
    log = read_log(out / "measurements.csv")
    ids = log.spacecraft
    truth = {i: read_oem(out / f"truth-{i}.oem") for i in ids}
    t64, clk = read_truth_params_csv(out / "truth_clock.csv")
    t_clk = seconds_since(t64, log.epoch0)
    att = {}
    for i in ids:
        p = out / f"truth_attitude-{i}.csv"
        if p.exists():
            _, w = read_truth_params_csv(p)
            att[i] = so3_exp(np.column_stack([w["att_x"], w["att_y"], w["att_z"]]))
    rows = np.flatnonzero(log.kind == "isl_pseudorange")
    sc, tx = _names(log, "spacecraft"), _names(log, "tx_spacecraft")
    rxa, txa = _names(log, "rx_antenna"), _names(log, "tx_antenna")
    t_truth = truth[ids[0]].t_s + seconds_since(truth[ids[0]].epoch0, log.epoch0)
    meas, pred = log.xyz[rows, 0], np.empty(len(rows))
    for n, i in enumerate(rows):
        k = int(np.flatnonzero(np.abs(t_truth - log.t_s[i]) < 1e-6)[0])
        kc = int(np.flatnonzero(np.abs(t_clk - log.t_s[i]) < 1e-6)[0])

        def antenna(s, name):
            arm = np.zeros(3) if name is None else log.antennas[(s, name)]
            R = att[s][k] if s in att else np.eye(3)
            x = truth[s].x_eci[k]
            return x[:3] + R @ arm, x[3:]

        p_r, _ = antenna(sc[i], rxa[i])
        p_t, v_t = antenna(tx[i], txa[i])
        r_t = truth[tx[i]].x_eci[k, :3]
        a_t = -MU_EARTH_M3_S2 * r_t / np.linalg.norm(r_t) ** 3
        tau = np.linalg.norm(p_r - p_t) / C_LIGHT_M_S
        for _ in range(4 if light_time else 0):
            tau = np.linalg.norm(p_r - (p_t - v_t * tau + 0.5 * a_t * tau ** 2)) / C_LIGHT_M_S
        a, b = sorted((sc[i], tx[i]), key=ids.index)   # the pair's clock, c (dt_a - dt_b)
        col = f"clock_{a}_{b}_m" if f"clock_{a}_{b}_m" in clk else "clock_m"
        sign = 1.0 if sc[i] == a else -1.0
        pred[n] = C_LIGHT_M_S * tau + sign * clk[col][kc]
    return meas, pred, log.sigma[rows]


def test_three_spacecraft_fly_with_a_clock_per_linked_pair(tmp_path):
    """formation-gto-3: every pair linked both ways, centre of mass to centre of mass; each
    link row agrees with the independent prediction from the written truth, each pair's own
    clock column of truth_clock.csv signed by its receiver (chi-square of the whitened
    differences within 5 sigma of its dimension)."""
    out = _simulate(tmp_path, "formation-gto-3", "--duration-h", "0.25")
    names = sorted(p.name for p in out.iterdir())
    assert names == ["measurements.csv", "truth-sat1.oem", "truth-sat2.oem", "truth-sat3.oem",
                     "truth_clock.csv"]
    log = read_log(out / "measurements.csv")
    assert log.spacecraft == ("sat1", "sat2", "sat3")
    _, clk = read_truth_params_csv(out / "truth_clock.csv")
    assert set(clk) == {"clock_m", "clock_sat1_sat2_m", "clock_sat1_sat3_m", "clock_sat2_sat3_m"}
    np.testing.assert_array_equal(clk["clock_m"], clk["clock_sat1_sat2_m"])
    assert np.ptp(clk["clock_sat1_sat3_m"] - clk["clock_sat2_sat3_m"]) > 0   # own random walks
    isl = log.kind == "isl_pseudorange"
    assert isl.sum() == 6 * np.unique(log.t_s[isl]).size
    pairs = {tuple(sorted(p)) for p in zip(_names(log, "spacecraft"), _names(log, "tx_spacecraft"))
             if None not in p}
    assert pairs == {("sat1", "sat2"), ("sat1", "sat3"), ("sat2", "sat3")}
    ok, chi2 = _chi2_ok(*_predict(out))
    assert ok, chi2


def _chi2_ok(meas, pred, sigma):
    z = (meas - pred) / sigma
    n = z.size
    chi2 = float(np.sum(z ** 2))
    return abs(chi2 - n) < 5.0 * math.sqrt(2.0 * n) and abs(z.mean()) < 5.0 / math.sqrt(n), chi2


def test_formation_gto_writes_one_log_and_truth_per_spacecraft(tmp_path):
    out = _simulate(tmp_path, "formation-gto", "--duration-h", "0.5")
    names = sorted(p.name for p in out.iterdir())
    assert names == ["measurements.csv", "truth-sat1.oem", "truth-sat2.oem",
                     "truth_attitude-sat1.csv", "truth_attitude-sat2.csv", "truth_clock.csv"]
    log = read_log(out / "measurements.csv")
    assert log.spacecraft == ("sat1", "sat2")
    assert set(log.antenna_names) == {"tx0", "rx1", "rx2", "rx3"}
    np.testing.assert_array_equal(log.antennas[("sat2", "rx3")], [0.5, -0.5, -0.5])
    epochs = np.unique(log.t_s)
    isl = log.kind == "isl_pseudorange"
    assert isl.sum() == 6 * epochs.size                      # six links at every epoch
    for kind in ("earth_direction", "attitude", "prior_position"):
        got = [s for s, k in zip(_names(log, "spacecraft"), log.kind) if k == kind]
        assert got.count("sat1") == got.count("sat2") > 0, kind
    # ~1 km apart, antenna faces facing: sat2 on sat1's body +x, M21 = diag(-1, -1, 1)
    x1, x2 = read_oem(out / "truth-sat1.oem").x_eci, read_oem(out / "truth-sat2.oem").x_eci
    d = np.linalg.norm(x2[:, :3] - x1[:, :3], axis=1)
    assert 900.0 < d[0] < 1000.0 and d.min() > 500.0
    _, w1 = read_truth_params_csv(out / "truth_attitude-sat1.csv")
    _, w2 = read_truth_params_csv(out / "truth_attitude-sat2.csv")
    R1 = so3_exp(np.column_stack([w1["att_x"], w1["att_y"], w1["att_z"]]))
    R2 = so3_exp(np.column_stack([w2["att_x"], w2["att_y"], w2["att_z"]]))
    M21 = np.einsum("kji,kjl->kil", R1, R2)
    assert np.abs(M21 - np.diag([-1.0, -1.0, 1.0])).max() < 1e-3
    los = np.einsum("kji,kj->ki", R1, (x2[:, :3] - x1[:, :3]) / d[:, None])
    assert los[:, 0].min() > 0.5                             # in front of sat1's antenna face


def test_formation_gto_ranges_are_truth_geometry_light_time_and_clock(tmp_path):
    out = _simulate(tmp_path, "formation-gto", "--duration-h", "0.5", "--seed", "4")
    meas, pred, sigma = _predict(out)
    ok, chi2 = _chi2_ok(meas, pred, sigma)
    assert ok, (chi2, meas.size)
    assert np.all(sigma == 0.01)
    # 10 km/s x 3.2 us: the light time moves the transmitter by ~3 cm, three sigmas
    assert not _chi2_ok(meas, _predict(out, light_time=False)[1], sigma)[0]
    # the lever arms matter: centre-of-mass ranges are wrong by centimetres to decimetres
    log = read_log(out / "measurements.csv")
    rows = log.kind == "isl_pseudorange"
    r_rx = log.xyz[rows, 0].reshape(-1, 6)
    assert np.ptp(r_rx, axis=1).min() > 0.05                 # six different antenna pairs


def test_constellation_leo_light_time_matters(tmp_path):
    out = _simulate(tmp_path, "constellation-leo", "--duration-h", "1")
    meas, pred, sigma = _predict(out)
    ok, chi2 = _chi2_ok(meas, pred, sigma)
    assert ok, (chi2, meas.size)
    _, pred0, _ = _predict(out, light_time=False)
    err = np.abs(meas - pred0)
    assert np.sqrt(np.mean((pred - pred0) ** 2)) > 5.0       # metres without the light time
    assert not _chi2_ok(meas, pred0, sigma)[0]
    d = np.array([np.linalg.norm(a[:3] - b[:3]) for a, b in zip(
        read_oem(out / "truth-leo1.oem").x_eci, read_oem(out / "truth-leo2.oem").x_eci)])
    assert 500e3 < d.min() and d.max() < 2000e3 and err.max() > 10.0
    log = read_log(out / "measurements.csv")
    assert "attitude" not in set(log.kind)                   # centre-of-mass links


def test_first_spacecraft_rows_equal_the_one_spacecraft_pass():
    """sat1 draws from the seed's stream as gto-transfer does: its rows are that pass's."""
    one = simulate_pass(load_scenario("gto-transfer").with_options(duration_h=0.2), seed=3)
    two = simulate_formation_pass(load_scenario("formation-gto").with_options(duration_h=0.2),
                                  seed=3)
    sc = np.array(_names(two.log, "spacecraft"))
    for kind in ("prior_position", "earth_direction"):
        a = one.log.xyz[one.log.kind == kind]
        b = two.log.xyz[(two.log.kind == kind) & (sc == "sat1")]
        c = two.log.xyz[(two.log.kind == kind) & (sc == "sat2")]
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(b, c, rtol=0, atol=1e-9)      # sat2: own draws
    np.testing.assert_array_equal(one.x_true, two.x_true["sat1"])


def test_deterministic_per_seed_and_carrier_phase(tmp_path):
    scn = load_scenario("formation-gto").with_options(duration_h=0.1)
    a, b = simulate_formation_pass(scn, 7), simulate_formation_pass(scn, 7)
    np.testing.assert_array_equal(a.log.xyz, b.log.xyz)
    assert not np.array_equal(a.log.xyz, simulate_formation_pass(scn, 8).log.xyz)
    # carrier phase: code + a constant ambiguity per link, 10 um noise
    from dataclasses import replace

    f = replace(scn.formation, ranging=replace(scn.formation.ranging, carrier_sigma_m=1e-5,
                                               ambiguity_sigma_m=2.0))
    c = simulate_formation_pass(scn.with_options(formation=f), 7)
    code = c.log.xyz[c.log.kind == "isl_pseudorange", 0].reshape(-1, 6)
    phase = c.log.xyz[c.log.kind == "isl_carrier_phase", 0].reshape(-1, 6)
    diff = phase - code                                       # ambiguity + code noise
    np.testing.assert_allclose(diff.mean(axis=0), c.ambiguity_m, atol=5 * 0.01 / math.sqrt(len(diff)))
    assert np.abs(c.ambiguity_m).max() > 0.1
    assert np.all(c.log.sigma[c.log.kind == "isl_carrier_phase"] == 1e-5)
    np.testing.assert_array_equal(code, a.log.xyz[a.log.kind == "isl_pseudorange", 0].reshape(-1, 6))


FORMATION = (data_dir() / "scenarios" / "formation-gto.toml").read_text()
# the bad formation TOMLs (a key named in the message) are cases of
# tests/test_scenario_validation.py::test_bad_scenario_toml_is_exit_2_naming_the_key


def _bad(old, new, count=1):
    assert old in FORMATION, old
    return FORMATION.replace(old, new, count)


def test_formation_options_and_limits(tmp_path, capsys):
    for opt in ("--raw-stars", "--images"):
        assert main(["simulate", "formation-gto", "--out", str(tmp_path / "o"), opt]) == 2
        assert "several spacecraft" in capsys.readouterr().err
    # the size limit counts both spacecraft's sensor epochs and the link epochs
    assert main(["simulate", "formation-gto", "--out", str(tmp_path / "o"),
                 "--max-epochs", "4000"]) == 2
    assert "4,323 sensor epochs" in capsys.readouterr().err
    with pytest.raises(UserError, match="several spacecraft"):
        simulate_pass(load_scenario("formation-gto"))
    three = FORMATION.replace("[[antenna]]", '[[spacecraft]]\nid = "sat3"\nlead_s = 0.2\n\n'
                              "[[antenna]]", 1)
    path = tmp_path / "three.toml"
    path.write_text(three)   # a third spacecraft flies, with its own rows and no links
    sim = simulate_formation_pass(load_scenario(str(path)))
    assert sim.ids == ("sat1", "sat2", "sat3") and list(sim.clocks) == [("sat1", "sat2")]
    assert sim.log.spacecraft == sim.ids and np.sum(spacecraft_index(sim.log) == 2) > 0
    path.write_text(_bad("sigma_m = 0.01", "sigma_m = nan"))
    with pytest.raises(InputFormatError):
        load_scenario(str(path))


def test_gyros_add_their_rows_and_change_no_other():
    """``gyro=True``: each spacecraft's gyro rows at every epoch of the log but the first, from
    streams of their own (the ``--body-frame`` log's rows unchanged), their rates the true
    attitude law's over each interval plus the spacecraft's bias (within 6 sigma of the
    noise), the biases of the two spacecraft different."""
    scn = load_scenario("formation-gto").with_options(duration_h=0.5, step_s=60)
    a = simulate_formation_pass(scn, 0, body_frame=True)
    b = simulate_formation_pass(scn, 0, body_frame=True, gyro=True)
    gyro = np.asarray(b.log.kind) == "gyro"
    assert np.array_equal(a.log.xyz, b.log.xyz[~gyro], equal_nan=True)
    assert np.array_equal(a.log.t_s, b.log.t_s[~gyro]) and not a.gyro_bias
    t_log = np.unique(b.log.t_s)
    sc = spacecraft_index(b.log)
    for k, i in enumerate(b.ids):
        rows = np.flatnonzero(gyro & (sc == k))
        assert np.array_equal(b.log.t_s[rows], t_log[1:])
        R = b.R_eci_from_body[i][np.searchsorted(b.t_s, t_log)]
        rate = so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) / np.diff(t_log)[:, None]
        noise = b.log.xyz[rows] - rate - b.gyro_bias[i]
        assert np.max(np.abs(noise)) < 6 * b.log.sigma[rows][0]
    assert np.min(np.abs(b.gyro_bias[b.ids[0]] - b.gyro_bias[b.ids[1]])) > 1e-6
