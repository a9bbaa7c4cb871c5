"""Rerun recording of a solution: written with the columnar API and read back with Rerun's
own reader (``rerun.chunk.RrdReader``), checking entities, time points and values."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from factors.constants import R_EARTH_M  # noqa: E402
from fgnav.orbit import kepler_states  # noqa: E402
from fgnav.solution import Solution  # noqa: E402
from fgnav.viz import rerun_log  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def make_solution(n=300, dt_s=20.0, seed=1, sig_rtn=(40.0, 150.0, 25.0, 0.15, 0.04, 0.03),
                  method="isam2"):
    """Synthetic solution: LEO Kepler truth, RTN-diagonal covariance rotated to ECI, and an
    estimate = truth + a draw from that covariance (so NEES ~ chi2(6))."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    truth = kepler_states(t, R_EARTH_M + 700e3, 0.01, np.radians(97.0), np.radians(77.0),
                          np.radians(55.0), 0.3)
    R = rerun_log.rtn_rotations(truth)
    T = np.zeros((n, 6, 6))
    T[:, :3, :3] = R
    T[:, 3:, 3:] = R
    D = np.diag(np.square(sig_rtn))
    P = np.einsum("nji,jk,nkl->nil", T, D, T)          # T^T D T: RTN -> ECI
    L = np.linalg.cholesky(P)
    x = truth + np.einsum("nij,nj->ni", L, rng.standard_normal((n, 6)))
    residuals = {"earth_dir": rng.standard_normal((n, 2)), "star": rng.standard_normal((2 * n, 2))}
    sol = Solution(method=method, epoch0=np.datetime64("2024-03-01T00:00:00", "ns"), t_s=t,
                   x_eci=x, P_eci=P, iterations=3, chi2=12.0, wall_s=0.1, residuals=residuals,
                   online_x_eci=x + 10.0, online_P_eci=P, latency_s=np.full(n, 2e-3),
                   extras={"residual_t_s": {"star": np.repeat(t, 2)}})
    return sol, truth


def read_back(path):
    """entity -> list of chunks' (num_rows, timelines, record batch) via Rerun's reader."""
    reader = rr.chunk.RrdReader(str(path))
    out = {}
    for c in reader.stream().to_chunks():
        out.setdefault(c.entity_path, []).append(c)
    return reader, out


def time_points(chunks, timeline="t_s"):
    vals = []
    for c in chunks:
        rb = c.to_record_batch()
        if timeline in rb.schema.names:
            vals.append(np.asarray(rb.column(timeline).cast("int64")))
    return np.unique(np.concatenate(vals)) if vals else np.array([])


def scalars(chunks, timeline="t_s"):
    """(times_ns (M,), values (M, k)) of a Scalars entity."""
    ts, vs = [], []
    for c in chunks:
        rb = c.to_record_batch()
        if timeline not in rb.schema.names:
            continue
        col = [n for n in rb.schema.names if n.endswith("scalars")][0]
        ts.append(np.asarray(rb.column(timeline).cast("int64")))
        vs.append(np.array(rb.column(col).to_pylist(), dtype=float))
    t = np.concatenate(ts)
    v = np.concatenate(vs)
    o = np.argsort(t, kind="stable")
    return t[o], v[o]


def test_rtn_sigma_matches_construction():
    """Sigma rotated back to RTN equals the diagonal the covariance was built from."""
    sig = (40.0, 150.0, 25.0, 0.15, 0.04, 0.03)
    sol, truth = make_solution(n=50, sig_rtn=sig)
    _, s = rerun_log.error_and_sigma(sol.x_eci, sol.P_eci, truth, frame="rtn")
    np.testing.assert_allclose(s, np.broadcast_to(sig, s.shape), rtol=1e-9)
    # RTN: R along r, N along h, right-handed
    R = rerun_log.rtn_rotations(truth)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    r_rtn = np.einsum("nij,nj->ni", R, truth[:, :3])
    np.testing.assert_allclose(r_rtn[:, 1:], 0.0, atol=1e-6)


def test_nees_is_chi2_6_for_consistent_draws():
    sol, truth = make_solution(n=2000, seed=7)
    v = rerun_log.nees(sol.x_eci, sol.P_eci, truth)
    # mean of 2000 chi2(6) draws: 6 +- 3.5 * sqrt(12/2000)
    assert abs(np.mean(v) - 6.0) < 3.5 * np.sqrt(12 / 2000)
    # an overconfident covariance (P/4) doubles... quadruples NEES
    v4 = rerun_log.nees(sol.x_eci, sol.P_eci / 4.0, truth)
    np.testing.assert_allclose(v4, 4 * v, rtol=1e-8)


def test_covariance_ellipsoid_axes_and_rotation():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    half, q = rerun_log.covariance_ellipsoids(P, 3.0)
    from scipy.spatial.transform import Rotation

    Rm = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]]).as_matrix()
    # R diag((half/3)^2) R^T reproduces P
    P2 = np.einsum("nij,nj,nkj->nik", Rm, (half / 3.0) ** 2, Rm)
    np.testing.assert_allclose(P2, P, rtol=1e-9, atol=1e-12)


def test_recording_round_trip(tmp_path):
    n = 300
    sol, truth = make_solution(n=n)
    meas = {"earth_dir": (sol.t_s, -truth[:, :3] / np.linalg.norm(truth[:, :3], axis=1, keepdims=True)),
            "star": {"t_s": np.repeat(sol.t_s[::10], 3), "u_eci": np.tile(np.eye(3), (n // 10, 1))}}
    out = rerun_log.log_solution(tmp_path / "pass.rrd", sol, truth_x_eci=truth, measurements=meas)
    path = Path(out["path"])
    assert path.stat().st_size > 0
    reader, ents = read_back(path)
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1, "default blueprint stored in the file"

    mag = out["magnification"]
    assert mag >= 1.0 and np.log10(mag) == int(np.log10(mag))
    ell = f"/world/estimate/covariance_3sigma_x{mag:g}"
    expected_static = ["/world/earth", "/world/estimate/trajectory", "/world/truth/trajectory", ell + "/trail"]
    for e in expected_static:
        assert e in ents, e
        assert all(c.is_static for c in ents[e])
    t_ns = np.round(sol.t_s * 1e9).astype(np.int64)
    timed = ["/world/estimate/state", "/world/truth/state", ell + "/current",
             "/world/measurements/earth_dir", "/errors/position_rtn_m/R", "/errors/velocity_rtn_mps/N",
             "/errors/position_eci_m/x", "/consistency/nees", "/timing/latency_ms",
             "/residuals/earth_dir", "/errors/position_norm_m"]
    for e in timed:
        assert e in ents, e
        np.testing.assert_array_equal(time_points(ents[e]), t_ns, err_msg=e)
    # stars: 30 time points, 3 rays each
    assert len(time_points(ents["/world/measurements/star"])) == n // 10
    assert sum(c.num_rows for c in ents["/world/measurements/star"] if not c.is_static) == n // 10
    # star residuals: two rows per epoch at the given times
    assert sum(c.num_rows for c in ents["/residuals/star"] if not c.is_static) == 2 * n

    # values: RTN position error series = [error, +3 sigma, -3 sigma] from independent truth
    tt, v = scalars(ents["/errors/position_rtn_m/T"])
    np.testing.assert_array_equal(tt, t_ns)
    R = rerun_log.rtn_rotations(truth)
    e_t = np.einsum("nj,nj->n", R[:, 1], sol.x_eci[:, :3] - truth[:, :3])
    np.testing.assert_allclose(v[:, 0], e_t, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(v[:, 1], 3 * 150.0, rtol=1e-9)
    np.testing.assert_allclose(v[:, 2], -3 * 150.0, rtol=1e-9)
    _, lat = scalars(ents["/timing/latency_ms"])
    np.testing.assert_allclose(lat[:, 0], 2.0)
    # the 3-D scene is in km
    rb = ents["/world/estimate/state"][0].to_record_batch()
    col = [c for c in rb.schema.names if c.endswith("positions")][0]
    p0 = np.array(rb.column(col).to_pylist()[0], dtype=float)
    np.testing.assert_allclose(p0[0], sol.x_eci[0, :3] / 1e3, rtol=1e-6)


def test_recording_without_truth(tmp_path):
    sol, _ = make_solution(n=120, method="batch")
    sol.latency_s = None
    sol.online_x_eci = None
    out = rerun_log.log_solution(tmp_path / "b.rrd", sol, magnification=500)
    _, ents = read_back(out["path"])
    assert not any(e.startswith("/errors") or e.startswith("/consistency") for e in ents)
    assert "/world/estimate/covariance_3sigma_x500/current" in ents
    tt, v = scalars(ents["/sigma/position_rtn_m/R"])
    assert len(tt) == 120
    # without truth the RTN frame is the estimate's (tens of m off the truth's): ~1e-7 rotation
    np.testing.assert_allclose(v, np.broadcast_to([120.0, -120.0], v.shape), rtol=1e-6)


def test_bad_shapes_raise(tmp_path):
    sol, truth = make_solution(n=20)
    with pytest.raises(ValueError):
        rerun_log.log_solution(tmp_path / "x.rrd", sol, truth_x_eci=truth[:-1])


def test_spawn_headless_prints_command(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    sol, _ = make_solution(n=10)
    out = rerun_log.log_solution(tmp_path / "h.rrd", sol, spawn=True)
    assert out["viewer"] is False
    err = capsys.readouterr().err
    assert "rerun h.rrd" in err and "No display" in err


# ---------------------------------------------------------------- fgnav view ----------
def test_view_missing_file(tmp_path, capsys):
    from fgnav.cli import main

    assert main(["view", str(tmp_path / "nope.rrd")]) == 2
    assert "nope.rrd" in capsys.readouterr().err


def test_view_headless_and_with_display(tmp_path, monkeypatch, capsys):
    from fgnav.cli import main

    sol, _ = make_solution(n=10)
    rrd = rerun_log.log_solution(tmp_path / "v.rrd", sol)["path"]
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert main(["view", rrd]) == 0
    out = capsys.readouterr().out
    assert "rerun v.rrd" in out

    assert main(["view", rrd, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["launched"] is False and info["command"][-1] == rrd and info["entities"] > 10

    calls = []

    class FakePopen:
        def __init__(self, cmd, **kw):
            calls.append(cmd)

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(subprocess, "Popen", FakePopen)
    assert main(["view", rrd]) == 0
    assert calls and calls[0][-1] == rrd and "rerun" in " ".join(calls[0])


def test_view_rejects_non_rrd(tmp_path, capsys):
    from fgnav.cli import main

    bad = tmp_path / "bad.rrd"
    bad.write_text("not a recording\n")
    assert main(["view", str(bad)]) == 2
    assert "bad.rrd" in capsys.readouterr().err


@pytest.mark.bench
def test_bench_rerun_script():
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "bench_rerun.py"), "--epochs", "14400"],
                         capture_output=True, text=True, check=True)
    info = json.loads(out.stdout)
    assert info["epochs"] == 14400


def test_rays_from_measurement_log(tmp_path):
    """Earth-direction rows of a MeasurementLog (epoch0 10 s later than the solution's)
    become rays from the spacecraft that end at the Earth's centre."""
    log_csv = pytest.importorskip("fgnav.io.log_csv")
    sol, truth = make_solution(n=60)
    t_log = sol.t_s[::3] - 10.0                       # log times relative to its own epoch0
    u = -truth[::3, :3] / np.linalg.norm(truth[::3, :3], axis=1, keepdims=True)
    log = log_csv.log_from_arrays(sol.epoch0 + np.timedelta64(10, "s"), t_log,
                                  ["earth_direction"] * len(t_log), u, np.full(len(t_log), 1e-4))
    out = rerun_log.log_solution(tmp_path / "m.rrd", sol, truth_x_eci=truth, measurements=log)
    _, ents = read_back(out["path"])
    chunks = ents["/world/measurements/earth_direction"]
    np.testing.assert_array_equal(time_points(chunks), np.round(sol.t_s[::3] * 1e9).astype(np.int64))
    rb = chunks[0].to_record_batch()
    o = np.array([v[0] for v in rb.column([c for c in rb.schema.names if c.endswith("origins")][0]).to_pylist()])
    v = np.array([v[0] for v in rb.column([c for c in rb.schema.names if c.endswith("vectors")][0]).to_pylist()])
    # origin = estimated position (km); tip within the estimate error of the Earth centre
    np.testing.assert_allclose(o, sol.x_eci[::3, :3][: len(o)] / 1e3, rtol=1e-6)
    assert np.max(np.linalg.norm(o + v, axis=1)) < 2.0   # km (estimate errors ~ 0.2 km)


def blueprint_views(path):
    """display name -> {component column: value} of each view of the stored blueprint."""
    reader = rr.chunk.RrdReader(str(path))
    by_id: dict[str, dict] = {}
    for c in reader.stream(store=reader.blueprints()[0]).to_chunks():
        parts = c.entity_path.strip("/").split("/")
        if parts[0] != "view":
            continue
        rb = c.to_record_batch()
        d = by_id.setdefault(parts[1], {})
        for n in rb.schema.names:
            if ":" in n:
                d[n] = rb.column(n).to_pylist()[0]
    return {v["ViewBlueprint:display_name"][0]: v for v in by_id.values()
            if "ViewBlueprint:display_name" in v}


def series_names_colors(chunks):
    """(names, colors) of the static SeriesLines / SeriesPoints of an entity."""
    rb = [c for c in chunks if c.is_static][0].to_record_batch()
    names = rb.column([n for n in rb.schema.names if n.endswith(":names")][0]).to_pylist()[0]
    colors = rb.column([n for n in rb.schema.names if n.endswith(":colors")][0]).to_pylist()[0]
    return names, colors


def test_blueprint_whole_pass_named_axes_and_framed_orbit(tmp_path):
    """The stored blueprint: every time plot's x range is the whole pass (not a window at the
    cursor), the 3-D eye looks at the Earth from outside the orbit; the R, T, N series carry
    their axis in their names and each axis its own colour."""
    sol, truth = make_solution(n=200)
    out = rerun_log.log_solution(tmp_path / "b.rrd", sol, truth_x_eci=truth)
    views = blueprint_views(out["path"])
    t_end_ns = int(round(sol.t_s[-1] * 1e9))
    plots = [v for v in views.values() if "TimeAxis:view_range" in v]
    assert {"position error R/T/N [m]", "velocity error R/T/N [m/s]", "NEES (6 dof)"} <= set(views)
    assert len(plots) >= 4
    for v in plots:
        assert v["TimeAxis:view_range"][0] == {"start": 0, "end": t_end_ns}
    eye = views["orbit (ECI, km)"]
    pos = np.array(eye["EyeControls3D:position"][0])
    rmax_km = np.max(np.linalg.norm(sol.x_eci[:, :3], axis=1)) / 1e3
    assert np.linalg.norm(pos) > 2.0 * rmax_km                       # the whole orbit in view
    np.testing.assert_allclose(eye["EyeControls3D:look_target"][0], 0.0)
    assert "star camera: rays in the body frame" not in views        # no body-frame rows
    _, ents = read_back(out["path"])
    colors = {}
    for ax in ("R", "T", "N"):
        names, cols = series_names_colors(ents[f"/errors/position_rtn_m/{ax}"])
        assert names == [f"{ax} error", f"{ax} +3σ", f"{ax} -3σ"]
        colors[ax] = cols[0]
    assert len(set(colors.values())) == 3
    names, _ = series_names_colors(ents["/errors/position_norm_m"])
    assert names == ["smoothed", "online"]                            # iSAM2: final + online
    sol_ekf, _ = make_solution(n=50, method="ekf")
    out = rerun_log.log_solution(tmp_path / "e.rrd", sol_ekf, truth_x_eci=truth[:50])
    _, ents = read_back(out["path"])
    assert series_names_colors(ents["/errors/position_norm_m"])[0] == ["filtered"]


def test_attitude_axes_star_rays_and_sigma(tmp_path):
    """An estimated attitude draws the body axes along the trajectory (columns of
    R_eci_from_body), the star rows become rays in the body-frame camera view (with the
    catalogue direction rotated into the body frame by the estimate), and the attitude error
    series equals Log(R_true^T R_est) in arcsec against 3 sigma of the covariance."""
    from scipy.spatial.transform import Rotation

    log_csv = pytest.importorskip("fgnav.io.log_csv")
    n = 40
    sol, truth = make_solution(n=n, method="batch")
    rng = np.random.default_rng(3)
    R_true = Rotation.from_rotvec(rng.normal(0.0, 1.0, (n, 3))).as_matrix()
    sig_rad = np.radians(np.array([5.0, 6.0, 40.0]) / 3600.0)
    d = rng.normal(0.0, 1.0, (n, 3)) * sig_rad
    R_est = R_true @ Rotation.from_rotvec(d).as_matrix()             # right perturbation
    sol.variables = {"attitude": (Rotation.from_matrix(R_est).as_rotvec(),
                                  np.tile(np.diag(sig_rad**2), (n, 1, 1)))}
    # two stars per epoch: body direction = R_true^T s
    s_eci = Rotation.from_rotvec(rng.normal(0, 1, (2 * n, 3))).apply([0.0, 0.0, 1.0])
    t_rows = np.repeat(sol.t_s, 2)
    u_body = np.einsum("nji,nj->ni", np.repeat(R_true, 2, axis=0), s_eci)
    log = log_csv.log_from_arrays(sol.epoch0, t_rows, ["star_direction_body"] * (2 * n), u_body,
                                  np.full(2 * n, 2.5e-5), extra={"star_x": s_eci[:, 0],
                                                                 "star_y": s_eci[:, 1], "star_z": s_eci[:, 2]})
    out = rerun_log.log_solution(tmp_path / "a.rrd", sol, truth_x_eci=truth, measurements=log,
                                 truth_attitude_R=R_true)
    _, ents = read_back(out["path"])
    t_ns = np.round(sol.t_s * 1e9).astype(np.int64)
    for e in ("/world/estimate/body_axes", "/camera/star_direction_body/measured",
              "/camera/star_direction_body/catalogue_in_body", "/attitude/error_arcsec/x"):
        np.testing.assert_array_equal(time_points(ents[e]), t_ns, err_msg=e)
    assert all(c.is_static for c in ents["/world/estimate/body_axes_trail"])
    rb = ents["/world/estimate/body_axes"][0].to_record_batch()
    vec = np.array(rb.column([c for c in rb.schema.names if c.endswith("vectors")][0]).to_pylist()[0])
    L = np.linalg.norm(vec[0])
    np.testing.assert_allclose(vec / L, R_est[0].T, atol=1e-6)        # rows = body x, y, z in ECI
    rb = ents["/camera/star_direction_body/measured"][0].to_record_batch()
    v = np.array(rb.column([c for c in rb.schema.names if c.endswith("vectors")][0]).to_pylist()[0])
    np.testing.assert_allclose(v, u_body[:2], atol=1e-6)
    rb = ents["/camera/star_direction_body/catalogue_in_body"][0].to_record_batch()
    p = np.array(rb.column([c for c in rb.schema.names if c.endswith("positions")][0]).to_pylist()[0])
    np.testing.assert_allclose(p, np.einsum("ji,nj->ni", R_est[0], s_eci[:2]), atol=1e-6)
    for i, ax in enumerate("xyz"):
        _, val = scalars(ents[f"/attitude/error_arcsec/{ax}"])
        np.testing.assert_allclose(val[:, 0], np.degrees(d[:, i]) * 3600.0, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(val[:, 1], 3 * np.degrees(sig_rad[i]) * 3600.0, rtol=1e-5)
    views = blueprint_views(out["path"])
    assert "star camera: rays in the body frame" in views
    assert "attitude error about body x/y/z [arcsec]" in views
