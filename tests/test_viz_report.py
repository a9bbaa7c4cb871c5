"""Report plots and files: axes labels/units and plotted data from the matplotlib objects,
PNG/markdown/HTML outputs, result-directory reading, and the ``fgnav report`` command."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

from factors.constants import R_EARTH_M  # noqa: E402
from fgnav.errors import InputFormatError, UserError  # noqa: E402
from fgnav import orbit  # noqa: E402
from fgnav.orbit import rtn_frame  # noqa: E402
from fgnav.viz import report  # noqa: E402
from fgnav.viz.rerun_log import attitude_error_body  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def kepler_states(t_s, a_m=R_EARTH_M + 700e3, e=0.01, i=np.radians(97.0), raan=np.radians(77.0),
                  argp=np.radians(55.0), M0=0.3):
    """Two-body ECI states (N, 6) of the test's LEO (fgnav.orbit.kepler_states)."""
    return orbit.kepler_states(t_s, a_m, e, i, raan, argp, M0)


SIG_RTN = np.array([40.0, 150.0, 25.0, 0.15, 0.04, 0.03])


def make_data(n=400, dt_s=30.0, seed=2, truth=True):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    xt = kepler_states(t)
    R = rtn_frame(xt)
    T = np.zeros((n, 6, 6))
    T[:, :3, :3] = R
    T[:, 3:, 3:] = R
    P = np.einsum("nji,jk,nkl->nil", T, np.diag(SIG_RTN**2), T)
    x = xt + np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.standard_normal((n, 6)))
    summary = {"method": "batch", "epochs": n, "wall_s": 1.25, "chi2": 812.5,
               "crb_position_rms_m": 150.0}
    if truth:
        summary.update(position_rms_m=160.2, velocity_rms_mps=0.16, nees_mean=6.1)
    return report.ResultData(summary=summary, epoch0=np.datetime64("2024-03-01T00:00:00", "ns"),
                             t_s=t, x_eci=x, P_eci=P, truth_x_eci=xt if truth else None,
                             residuals={"earth_direction": rng.standard_normal(2 * n),
                                        "limb_radius": rng.standard_normal(n)},
                             latency_t_s=t, latency_s=np.abs(rng.normal(3e-3, 1e-3, n)))


def test_error_plot_axes_and_data():
    d = make_data()
    fig = report.plot_state_errors(d.t_s, d.x_eci, d.P_eci, d.truth_x_eci)
    axs = fig.axes
    assert len(axs) == 6
    assert [a.get_ylabel() for a in axs] == [
        "R position error [m]", "T position error [m]", "N position error [m]",
        "R velocity error [m/s]", "T velocity error [m/s]", "N velocity error [m/s]"]
    assert all(a.get_xlabel() == "time since epoch0 [h]" for a in axs[3:])
    assert "RTN" in fig.get_suptitle()
    # along-track axis: the "smoothed error" line is the T component of (x - truth), time in h
    ax = axs[1]
    line = [ln for ln in ax.lines if ln.get_label() == "smoothed error"][0]
    e_t = np.einsum("nj,nj->n", rtn_frame(d.truth_x_eci)[:, 1], d.x_eci[:, :3] - d.truth_x_eci[:, :3])
    np.testing.assert_allclose(line.get_xdata(), d.t_s / 3600.0)
    np.testing.assert_allclose(line.get_ydata(), e_t, rtol=1e-12, atol=1e-9)
    # envelope: +3 sigma of the along-track position = 3 * 150 m
    env = [ln for ln in ax.lines if np.allclose(ln.get_ydata(), 450.0)]
    assert env, "no +3 sigma line at 450 m"
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "smoothed error" in labels and any("3σ" in s for s in labels)
    # errors drawn from the covariance fall inside 3 sigma ~99.7 % of the time
    assert np.mean(np.abs(e_t) < 450.0) > 0.98


def test_sigma_plot_without_truth():
    d = make_data(truth=False)
    fig = report.plot_state_errors(d.t_s, d.x_eci, d.P_eci, None)
    axs = fig.axes
    assert axs[0].get_ylabel() == "R position ±3σ [m]"
    assert axs[5].get_ylabel() == "N velocity ±3σ [m/s]"
    assert "no truth" in fig.get_suptitle()
    assert not any(ln.get_label() == "smoothed error" for a in axs for ln in a.lines)
    top = max(axs[3].lines, key=lambda ln: np.nanmean(ln.get_ydata()))
    np.testing.assert_allclose(top.get_ydata(), 3 * SIG_RTN[3], rtol=1e-6)


def test_residual_histograms():
    rng = np.random.default_rng(5)
    res = {"earth_direction": rng.standard_normal(4000), "star": 2.0 * rng.standard_normal(1000)}
    res["star"][:3] = 50.0     # outliers are counted, not lost
    fig = report.plot_residual_histograms(res)
    used = [a for a in fig.axes if a.axison]
    assert len(used) == 2
    for ax, kind in zip(used, res):
        assert ax.get_xlabel() == "whitened residual [σ]"
        assert ax.get_ylabel() == "probability density"
        assert ax.get_title().startswith(kind)
        labels = ax.get_legend_handles_labels()[1]
        assert "N(0, 1)" in labels
        heights = np.array([p.get_height() for p in ax.patches])
        widths = np.array([p.get_width() for p in ax.patches])
        assert abs(np.sum(heights * widths) - 1.0) < 1e-9    # a density
    n_out = int(np.sum(np.abs(res["star"]) > 6.0))
    assert n_out >= 3 and f"{n_out} beyond ±6σ" in used[1].get_title()
    assert f"std={np.std(res['star']):.2f}" in used[1].get_title()
    assert "n=4,000, mean=" in used[0].get_title() and "beyond" not in used[0].get_title()


def test_orbit_and_latency_plots():
    d = make_data()
    ax = report.plot_orbit_3d(d.x_eci, d.truth_x_eci).axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x ECI [km]", "y ECI [km]", "z ECI [km]")
    assert {"truth", "estimate"} <= set(ax.get_legend_handles_labels()[1])
    est = [ln for ln in ax.lines if ln.get_label() == "estimate"][0]
    xs, ys, zs = est.get_data_3d()
    np.testing.assert_allclose(xs, d.x_eci[:, 0] / 1e3)
    ax = report.plot_latency(d.latency_t_s, d.latency_s).axes[0]
    assert ax.get_ylabel() == "update latency [ms]" and ax.get_xlabel() == "time since epoch0 [h]"


def test_write_report_files(tmp_path):
    d = make_data()
    d.notes.append("a note")
    res = report.write_report(d, tmp_path / "rep")
    assert set(res["images"]) == {"errors_rtn", "residuals_hist", "orbit_3d", "latency"}
    for p in res["images"].values():
        assert p.read_bytes()[:8] == PNG_MAGIC and p.stat().st_size > 20_000
    md = res["markdown"].read_text()
    assert "| position_rms_m | 160.2 | m |" in md
    assert "| velocity_rms_mps | 0.16 | m/s |" in md
    assert "| epochs | 400 |  |" in md
    for name in res["images"]:
        assert f"]({name}.png)" in md
    assert "a note" in md
    html = res["html"].read_text()
    assert html.count("<img ") == 4 and "<td>position_rms_m</td>" in html
    # without truth: the sigma plot replaces the error plot
    res2 = report.write_report(make_data(truth=False), tmp_path / "rep2")
    assert "sigma_rtn" in res2["images"] and "errors_rtn" not in res2["images"]
    assert "Truth: no" in res2["markdown"].read_text()


def test_states_at_hermite_against_kepler():
    t = np.arange(0.0, 6000.0, 30.0)
    x = kepler_states(t)
    tq = np.concatenate([t[5:-5:7], t[5:-5:7] + 11.3])     # coincident and in-between epochs
    got = report.states_at(tq, t, x)
    want = kepler_states(tq)
    assert np.max(np.linalg.norm(got[:, :3] - want[:, :3], axis=1)) < 0.05      # m
    assert np.max(np.linalg.norm(got[:, 3:] - want[:, 3:], axis=1)) < 2e-4      # m/s
    assert np.all(np.isnan(report.states_at([-1.0, 1e5], t, x)))


def test_residual_and_latency_csv(tmp_path):
    p = tmp_path / "residuals.csv"
    p.write_text("t_s,kind,component,whitened\n0,earth_direction,0,0.5\n0,earth_direction,1,-1.5\n"
                 "1,limb_radius,0,2\n")
    r = report.read_residuals_csv(p)
    np.testing.assert_array_equal(r["earth_direction"], [0.5, -1.5])
    np.testing.assert_array_equal(r["limb_radius"], [2.0])
    p.write_text("t,kind,component,whitened\n")
    with pytest.raises(InputFormatError, match="line 1"):
        report.read_residuals_csv(p)
    p.write_text("t_s,kind,component,whitened\n0,earth_direction,0,abc\n")
    with pytest.raises(InputFormatError, match="line 2.*whitened"):
        report.read_residuals_csv(p)
    q = tmp_path / "latency.csv"
    q.write_text("t_s,latency_s\n0,0.001\n1,0.002\n")
    t, lat = report.read_latency_csv(q)
    np.testing.assert_array_equal(lat, [0.001, 0.002])


def test_report_command_errors(tmp_path, capsys):
    from fgnav.cli import main

    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "not a result directory" in capsys.readouterr().err
    (tmp_path / "r").mkdir()
    assert main(["report", str(tmp_path / "r")]) == 2
    assert "summary.json" in capsys.readouterr().err
    with pytest.raises(UserError):
        report.load_result(tmp_path / "r")
    # --out naming an existing file: a message naming the option, not a FileExistsError
    (tmp_path / "file").write_text("")
    assert main(["report", str(tmp_path / "r"), "--out", str(tmp_path / "file")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not a directory" in err and "Traceback" not in err


def _write_oem(path, epoch0, t, x, P=None):
    oem = pytest.importorskip("fgnav.io.oem")
    writer = getattr(oem, "write_oem", None)
    if writer is None:
        pytest.skip("fgnav.io.oem.write_oem not available")
    writer(path, epoch0, t, x, P)


def test_report_command_end_to_end(tmp_path, capsys):
    """A result directory as `fgnav smooth --out` writes it, through `fgnav report --json`."""
    from fgnav.cli import main
    from fgnav.io.summary import write_summary

    d = make_data(n=200)
    out = tmp_path / "res"
    out.mkdir()
    _write_oem(out / "trajectory.oem", d.epoch0, d.t_s, d.x_eci, d.P_eci)
    _write_oem(tmp_path / "truth.oem", d.epoch0, d.t_s, d.truth_x_eci)
    write_summary(out / "summary.json", dict(d.summary, truth_path=str(tmp_path / "truth.oem")))
    rows = ["t_s,kind,component,whitened"] + [f"{t},earth_direction,{c},{w}" for t, c, w in
                                              zip(np.repeat(d.t_s, 2), np.tile([0, 1], 200),
                                                  d.residuals["earth_direction"])]
    (out / "residuals.csv").write_text("\n".join(rows) + "\n")
    assert main(["report", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert set(info["images"]) == {"errors_rtn", "residuals_time", "residuals_hist", "orbit_3d"}
    data = report.load_result(out)
    np.testing.assert_allclose(data.truth_x_eci, d.truth_x_eci, rtol=1e-9, atol=1e-6)
    assert len(data.residuals["earth_direction"]) == 400


def _legend_labels(fig):
    return [t.get_text() for t in fig.legends[0].get_texts()]


def _texts(fig):
    """Every title, axis label and legend entry of a figure."""
    out = [fig.get_suptitle()] + [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
        if ax.get_legend() is not None:
            out += [t.get_text() for t in ax.get_legend().get_texts()]
    return " | ".join(out)


def test_labels_follow_the_method(tmp_path):
    """An EKF's states are filtered: no "smoothed" anywhere in its error plot; iSAM2's online
    error gets its own figure against the online covariance, not the smoothed one."""
    d = make_data(n=200)
    d.summary["method"] = "ekf"
    d.online_x_eci = d.x_eci.copy()                       # what the EKF's results hold
    res = report.write_report(d, tmp_path / "ekf")
    fig = res["figures"]["errors_rtn"]
    assert "filtered error" in _legend_labels(fig) and "±3σ (filtered covariance)" in _legend_labels(fig)
    assert "smoothed" not in _texts(fig).lower() and "Filtered" in fig.get_suptitle()
    assert "online_errors_rtn" not in res["figures"]
    assert "Filtered position and velocity error" in res["markdown"].read_text()

    d = make_data(n=200)
    d.summary["method"] = "isam2"
    rng = np.random.default_rng(9)
    d.online_P_eci = 4.0 * d.P_eci                            # online sigma = 2 x smoothed
    d.online_x_eci = d.truth_x_eci + np.einsum("nij,nj->ni", np.linalg.cholesky(d.online_P_eci),
                                               rng.standard_normal((200, 6)))
    res = report.write_report(d, tmp_path / "isam2")
    assert "smoothed error" in _legend_labels(res["figures"]["errors_rtn"])
    fig = res["figures"]["online_errors_rtn"]
    assert _legend_labels(fig) == ["±3σ (online covariance)", "online error"]
    ax = fig.axes[1]                                           # along-track position
    line = [ln for ln in ax.lines if ln.get_label() == "online error"][0]
    e_t = np.einsum("nj,nj->n", rtn_frame(d.truth_x_eci)[:, 1], d.online_x_eci[:, :3] - d.truth_x_eci[:, :3])
    np.testing.assert_allclose(line.get_ydata(), e_t, atol=1e-9)
    assert any(np.allclose(ln.get_ydata(), 2 * 3 * SIG_RTN[1]) for ln in ax.lines), "online 3σ = 900 m"
    assert not any(np.allclose(ln.get_ydata(), 3 * SIG_RTN[1]) for ln in ax.lines)
    # fixed-lag: its own word
    assert report.estimate_label("fixed-lag") == "fixed-lag smoothed"


def test_residuals_against_time_with_gap_marks():
    """Residuals are drawn at their times (h); the gap of the log is shaded; a prior observed
    at one epoch gets no panel; a value beyond the clip is drawn at the edge and counted."""
    t = np.concatenate([np.arange(0.0, 3600.0, 30.0), np.arange(7200.0, 10800.0, 30.0)])
    rng = np.random.default_rng(4)
    w = rng.standard_normal(2 * len(t))
    w[5] = 40.0
    times = {"earth_direction": np.repeat(t, 2), "prior_position": np.zeros(3)}
    res = {"earth_direction": w, "prior_position": np.array([0.1, -0.3, 0.2])}
    comp = {"earth_direction": np.tile([0, 1], len(t)), "prior_position": np.arange(3)}
    gaps = report.residual_gaps(times)
    assert len(gaps) == 1 and gaps[0][0] == pytest.approx(3570.0) and gaps[0][1] == pytest.approx(3630.0)
    fig = report.plot_residuals_time(times, res, comp, gaps=gaps)
    used = [a for a in fig.axes]
    assert len(used) == 1 and used[0].get_title().startswith("earth_direction: 480 values, 1 beyond")
    ax = used[0]
    assert ax.get_ylabel() == "whitened residual [σ]" and ax.get_xlabel() == "time since epoch0 [h]"
    c0 = [ln for ln in ax.lines if ln.get_label() == "component 0"][0]
    np.testing.assert_allclose(c0.get_xdata(), t / 3600.0)
    np.testing.assert_allclose(c0.get_ydata(), np.clip(w[::2], -6, 6))
    spans = [p for p in ax.patches if p.get_label() == "gap in the log (no measurements)"]
    assert len(spans) == 1
    x0, x1 = spans[0].get_x(), spans[0].get_x() + spans[0].get_width()
    assert (x0, x1) == pytest.approx((3570.0 / 3600.0, 7200.0 / 3600.0))
    assert "1 gap in the log shaded" in fig.get_suptitle()


def test_few_sample_kinds_drawn_value_by_value():
    rng = np.random.default_rng(6)
    res = {"earth_direction": rng.standard_normal(500), "prior_position": np.array([0.5, -1.2, 2.5]),
           "prior_velocity": np.array([0.1, 0.2, -0.4])}
    fig = report.plot_residual_histograms(res)
    used = [a for a in fig.axes if a.axison]
    assert len(used) == 2                                           # one histogram + one strip
    strip = used[1]
    assert strip.get_title() == f"kinds with < {report.MIN_HISTOGRAM_SAMPLES} values: each value"
    assert not strip.patches                                        # no histogram bars
    pts = [ln for ln in strip.lines if ln.get_marker() == "o"]
    np.testing.assert_allclose(pts[0].get_xdata(), res["prior_position"])
    np.testing.assert_allclose(pts[1].get_ydata(), 1.0)
    assert [t.get_text() for t in strip.get_yticklabels()] == ["prior_position\n(n=3)", "prior_velocity\n(n=3)"]


def test_latency_legend_in_fitting_units():
    assert report.format_duration_s(2.1e-4) == "210 µs"
    assert report.format_duration_s(5.54e-3) == "5.54 ms"
    assert report.format_duration_s(1.5) == "1.5 s"
    t = np.arange(1000.0)
    lat = np.full(1000, 4.0e-6)
    lat[-5:] = 2.0e-3
    ax = report.plot_latency(t, lat).axes[0]
    labels = ax.get_legend_handles_labels()[1]
    assert "median 4 µs" in labels and not any("0.00 ms" in s for s in labels)
    assert ax.get_ylabel() == "update latency [µs]" and ax.get_yscale() == "log"   # 4 µs .. 2 ms
    np.testing.assert_allclose(ax.lines[0].get_ydata(), lat * 1e6)


def _attitude_case(n=120, seed=8):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = np.arange(n) * 10.0
    R_true = Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 7.3e-5]) + [0.3, -2.9, 0.4]).as_matrix()
    sig = np.radians(np.array([4.0, 4.0, 30.0]) / 3600.0)
    d = rng.standard_normal((n, 3)) * sig
    R_est = R_true @ Rotation.from_rotvec(d).as_matrix()
    return t, R_true, R_est, d, np.tile(np.diag(sig**2), (n, 1, 1)), sig


def test_attitude_error_plot():
    t, R_true, R_est, d, P, sig = _attitude_case()
    fig = report.plot_attitude_errors(t, R_est, P, R_true)
    assert [a.get_ylabel() for a in fig.axes] == [f"attitude error about body {c} [arcsec]" for c in "xyz"]
    z = [ln for ln in fig.axes[2].lines if ln.get_label() == "smoothed error"][0]
    np.testing.assert_allclose(z.get_ydata(), np.degrees(d[:, 2]) * 3600.0, rtol=1e-6, atol=1e-6)
    assert any(np.allclose(ln.get_ydata(), 90.0) for ln in fig.axes[2].lines)   # 3σ = 90 arcsec
    fig = report.plot_attitude_errors(t, R_est, 1e4 * P, None)                 # 1e4 P: 0.83 deg
    assert fig.axes[0].get_ylabel() == "attitude ±3σ about body x [deg]"
    assert "no true attitude" in fig.get_suptitle()


def test_attitude_files_to_report(tmp_path):
    """attitude.aem + attitude_covariance.csv in the result and truth_attitude.csv beside
    the truth OEM (as fgnav smooth / fgnav simulate write them) give attitude_errors.png;
    without the truth file, attitude_sigma.png."""
    from scipy.spatial.transform import Rotation

    from fgnav.io.aem import write_aem
    from fgnav.io.attitude_covariance import write_attitude_covariance
    from fgnav.io.summary import write_summary
    from fgnav.io.truth_params import TRUTH_ATTITUDE_COLUMNS, TRUTH_ATTITUDE_CSV, write_truth_params_csv

    t, R_true, R_est, d, P, sig = _attitude_case()
    dd = make_data(n=len(t), dt_s=10.0)
    out = tmp_path / "res"
    out.mkdir()
    _write_oem(out / "trajectory.oem", dd.epoch0, dd.t_s, dd.x_eci, dd.P_eci)
    _write_oem(tmp_path / "truth.oem", dd.epoch0, dd.t_s, dd.truth_x_eci)
    write_summary(out / "summary.json", dict(dd.summary, truth_path=str(tmp_path / "truth.oem")))
    write_aem(out / "attitude.aem", dd.epoch0, t, R_est)
    write_attitude_covariance(out / "attitude_covariance.csv", dd.epoch0, t, P)
    w = Rotation.from_matrix(R_true).as_rotvec()
    write_truth_params_csv(tmp_path / TRUTH_ATTITUDE_CSV, dd.epoch0, t, dict(zip(TRUTH_ATTITUDE_COLUMNS, w.T)))
    data = report.load_result(out)
    err = attitude_error_body(data.attitude_R, data.truth_attitude_R)
    np.testing.assert_allclose(err, d, atol=1e-9)                 # AEM round trip + truth file
    res = report.report_result_dir(out)
    assert "attitude_errors" in res["images"] and res["images"]["attitude_errors"].is_file()
    (tmp_path / TRUTH_ATTITUDE_CSV).unlink()
    res = report.report_result_dir(out)
    assert "attitude_sigma" in res["images"] and not (out / "attitude_errors.png").exists()


def test_resmoothing_removes_stale_plots(tmp_path):
    """`fgnav smooth` into a result folder that holds a report removes the report's plots
    (the set is replaced as a whole); a report without truth then writes sigma_rtn.png and
    no errors_rtn.png is left beside it."""
    from fgnav.cli import main

    sim = tmp_path / "pass"
    assert main(["simulate", "gto-transfer", "--out", str(sim), "--duration-h", "0.5", "--step-s", "60",
                 "--quiet"]) == 0
    out = tmp_path / "res"
    log = str(sim / "measurements.csv")
    assert main(["smooth", log, "--method", "isam2", "--out", str(out), "--truth", str(sim / "truth.oem"),
                 "--quiet"]) == 0
    assert main(["report", str(out), "--json"]) == 0
    for name in ("errors_rtn.png", "online_errors_rtn.png", "residuals_time.png", "latency.png"):
        assert (out / name).is_file(), name
    assert main(["smooth", log, "--method", "batch", "--out", str(out), "--quiet"]) == 0
    assert not list(out.glob("*.png")) and not (out / "report.md").exists()
    assert main(["report", str(out), "--json"]) == 0
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == ["orbit_3d.png", "residuals_hist.png", "residuals_time.png", "sigma_rtn.png"]
