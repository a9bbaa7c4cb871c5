"""Pictures of a formation: the Rerun recording of ``fgnav smooth --rerun`` on a log of two
spacecraft (read back with Rerun's own reader and checked against the result files and the
truth from the independent integrator) and ``fgnav report`` on the result folder."""

from __future__ import annotations

import csv
import subprocess
import sys

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from formation_data import EPOCH, formation_log  # noqa: E402
from test_viz_rerun import blueprint_views, read_back, scalars, time_points  # noqa: E402
from fgnav.errors import UserError  # noqa: E402
from fgnav.frames import relative_state_lvlh  # noqa: E402
from fgnav.io.log_csv import log_from_arrays, write_log  # noqa: E402
from fgnav.io.oem import read_oem, write_oem  # noqa: E402
from fgnav.time import parse_utc  # noqa: E402
from fgnav.viz.rerun_log import residual_color  # noqa: E402


def _smooth(tmp_path, log, truth, *extra):
    """``fgnav smooth`` on ``log`` (truth-<id>.oem beside it); returns the result folder."""
    write_log(tmp_path / "pass.csv", log)
    for sc in ("A", "B"):
        if sc in truth:
            write_oem(tmp_path / f"truth-{sc}.oem", parse_utc(EPOCH), *truth[sc])
    out = tmp_path / "result"
    r = subprocess.run([sys.executable, "-m", "fgnav", "smooth", str(tmp_path / "pass.csv"),
                        "--out", str(out), "--quiet", *extra], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return out


def _relative_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {c: np.array([float(r[c] or "nan") for r in rows]) for c in rows[0]
            if c not in ("epoch", "reference", "spacecraft")}


def _link_residual_max(path, kind):
    """t_s -> the largest |whitened| of ``kind``'s rows at that time, from residuals.csv."""
    out = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["kind"] == kind:
                t = float(r["t_s"])
                out[t] = max(out.get(t, 0.0), abs(float(r["whitened"])))
    return out


def test_residual_colour_scale():
    """Green at 0, yellow at 1.5, red at 3 (linear between), magenta beyond 3, grey for NaN."""
    c = residual_color([0.0, 0.75, 1.5, -3.0, 3.01, np.nan])
    np.testing.assert_array_equal(c[0], [44, 160, 44])
    np.testing.assert_array_equal(c[1], np.round((np.array([44, 160, 44]) + [255, 210, 0]) / 2))
    np.testing.assert_array_equal(c[2], [255, 210, 0])
    np.testing.assert_array_equal(c[3], [214, 39, 40])
    np.testing.assert_array_equal(c[4], [200, 0, 200])
    np.testing.assert_array_equal(c[5], [128, 128, 128])


def test_formation_recording_holds_both_orbits_the_links_and_the_relative_state(tmp_path):
    log, truth = formation_log(6, lever_arms=True)
    out = _smooth(tmp_path, log, truth, "--truth", str(tmp_path), "--rerun",
                  str(tmp_path / "result" / "pass.rrd"))
    reader, ents = read_back(out / "pass.rrd")
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    t = truth["A"][0]
    t_ns = np.round(t * 1e9).astype(np.int64)
    for sc in "AB":
        for e in (f"/world/{sc}/estimate/trajectory", f"/world/{sc}/truth/trajectory"):
            assert e in ents and all(c.is_static for c in ents[e]), e
        np.testing.assert_array_equal(time_points(ents[f"/world/{sc}/estimate/state"]), t_ns)
        # each spacecraft's orbit is its own OEM's, in km
        rb = [c for c in ents[f"/world/{sc}/estimate/trajectory"]][0].to_record_batch()
        strip = np.array(rb.column([n for n in rb.schema.names if n.endswith("strips")][0])
                         .to_pylist()[0][0], float)
        np.testing.assert_allclose(strip, read_oem(out / f"trajectory-{sc}.oem").x_eci[:, :3] / 1e3,
                                   rtol=1e-6)
        assert f"/spacecraft/{sc}/errors/position_rtn_m/R" in ents
    # the links: one segment A-B per epoch in both views, coloured by the largest |whitened
    # residual| of the epoch's two rows (residuals.csv)
    wmax = _link_residual_max(out / "residuals.csv", "isl_pseudorange")
    want = residual_color([wmax[float(x)] for x in t])
    rel = _relative_csv(out / "relative.csv")
    for root in ("world", "lvlh"):
        chunks = ents[f"/{root}/links/isl_pseudorange"]
        np.testing.assert_array_equal(time_points(chunks), t_ns)
        rb = chunks[0].to_record_batch()
        cols = rb.column([n for n in rb.schema.names if n.endswith(":colors")][0]).to_pylist()
        rgba = np.array([[(v >> 24) & 255, (v >> 16) & 255, (v >> 8) & 255] for (v,) in cols])
        np.testing.assert_array_equal(rgba, want[:len(rgba)])
        if root == "lvlh":   # from the reference at the origin to the deputy's LVLH position
            strips = rb.column([n for n in rb.schema.names if n.endswith("strips")][0]).to_pylist()
            seg = np.array(strips[0][0], float)
            np.testing.assert_allclose(seg[0], 0.0, atol=1e-9)
            np.testing.assert_allclose(seg[1], [rel["lvlh_x_m"][0], rel["lvlh_y_m"][0],
                                                rel["lvlh_z_m"][0]], rtol=1e-6)
    # the relative state in LVLH: values, and the error against the truth's relative state
    # with +-3 sigma of relative.csv
    _, v = scalars(ents["/relative/B/position_lvlh_m"])
    np.testing.assert_allclose(v, np.column_stack([rel["lvlh_x_m"], rel["lvlh_y_m"],
                                                   rel["lvlh_z_m"]]), rtol=1e-6, atol=1e-6)
    rel_true = relative_state_lvlh(truth["A"][1], truth["B"][1])[0]
    for i, ax in enumerate("xyz"):
        tt, v = scalars(ents[f"/relative/B/errors/position_lvlh_m/{ax}"])
        np.testing.assert_array_equal(tt, t_ns)
        np.testing.assert_allclose(v[:, 0], rel[f"lvlh_{ax}_m"] - rel_true[:, i], atol=1e-5)
        np.testing.assert_allclose(v[:, 1], 3 * rel[f"lvlh_{ax}_sigma_m"], rtol=1e-6)
        assert np.all(np.abs(v[:, 0]) < v[:, 1])     # a consistent pass stays inside 3 sigma
    assert "/relative/B/errors/velocity_lvlh_mps/z" in ents and "/relative/B/nees" in ents
    assert "/residuals/isl_pseudorange/A_from_B" in ents and "/residuals/earth_direction/B" in ents
    legend = ents["/legend"][0].to_record_batch()
    text = legend.column([n for n in legend.schema.names if n.endswith(":text")][0]).to_pylist()[0][0]
    assert "0 green → 1.5 yellow → 3 red" in text and "magenta" in text
    views = blueprint_views(out / "pass.rrd")
    assert {"orbits (ECI, km)", "formation in the LVLH frame of A (m)",
            "B relative to A: position in LVLH x/y/z [m]",
            "B relative position error LVLH x/y/z [m]"} <= set(views)
    eye = views["formation in the LVLH frame of A (m)"]
    target = np.array(eye["EyeControls3D:look_target"][0])
    assert np.linalg.norm(target) < np.max(np.linalg.norm(rel_true[:, :3], axis=1))


def test_formation_report_writes_its_plots_with_and_without_truth(tmp_path, capsys):
    from fgnav.viz.report import report_result_dir

    log, truth = formation_log(6, duration_s=900.0)
    out = _smooth(tmp_path, log, truth)          # no --truth: sigmas only
    res = report_result_dir(out)
    assert set(res["images"]) == {"sigma_rtn-A", "sigma_rtn-B", "relative_lvlh-B",
                                  "relative_sigma_lvlh-B", "residuals_time", "residuals_hist",
                                  "orbit_3d"}
    for p in res["images"].values():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000
    # with the truth directory: errors, the earlier report's sigma plots removed
    res = report_result_dir(out, truth_path=tmp_path)
    assert {"errors_rtn-A", "errors_rtn-B", "relative_errors_lvlh-B"} <= set(res["images"])
    assert not (out / "sigma_rtn-A.png").exists()
    assert not (out / "relative_sigma_lvlh-B.png").exists()
    # the relative error drawn is relative.csv's state minus the truth's relative state
    rel = _relative_csv(out / "relative.csv")
    rel_true = relative_state_lvlh(truth["A"][1], truth["B"][1])[0]
    ax = res["figures"]["relative_errors_lvlh-B"].axes[1]       # position y (along-track)
    line = [ln for ln in ax.get_lines() if ln.get_label().endswith("error")][0]
    np.testing.assert_allclose(line.get_ydata(), rel["lvlh_y_m"] - rel_true[:, 1], atol=1e-5)
    assert "## Each spacecraft" in res["markdown"].read_text()
    with pytest.raises(UserError, match="truth-<id>.oem"):
        report_result_dir(out, truth_path=tmp_path / "nowhere")
    from fgnav.cli import main

    assert main(["report", str(out), "--truth", str(tmp_path / "nowhere")]) == 2
    assert "fgnav: error:" in capsys.readouterr().err


def test_one_spacecraft_recording_and_report_are_unchanged(tmp_path):
    """A log of one spacecraft keeps the one-spacecraft recording (log_solution's entities)
    and report (errors_rtn.png)."""
    from fgnav.viz.report import report_result_dir

    log, truth = formation_log(7, links=False)
    keep = np.flatnonzero(log.extra["spacecraft"] == 0)
    one = log_from_arrays(log.epoch0, t_s=log.t_s[keep], kind=log.kind[keep], xyz=log.xyz[keep],
                          sigma=log.sigma[keep])
    write_oem(tmp_path / "truth.oem", parse_utc(EPOCH), *truth["A"])
    out = _smooth(tmp_path, one, {}, "--truth", str(tmp_path / "truth.oem"), "--rerun",
                  str(tmp_path / "one.rrd"))
    _, ents = read_back(tmp_path / "one.rrd")
    assert {"/world/estimate/trajectory", "/world/truth/trajectory", "/errors/position_rtn_m/R",
            "/consistency/nees"} <= set(ents)
    assert not any(e.startswith(("/lvlh", "/relative", "/world/links")) for e in ents)
    res = report_result_dir(out)
    assert "errors_rtn" in res["images"] and "relative_lvlh-B" not in res["images"]
