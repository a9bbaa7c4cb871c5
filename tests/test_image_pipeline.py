"""Image pipeline end to end : `fgnav simulate --images` -> `fgnav extract`
-> `fgnav smooth`, compared with the smoother fed ideal measurements of the same noise.

Pass: built-in ``geo-limb`` (GEO, Wu et al. sensor: the whole limb in one 30.5° UV
sub-aperture, 12.85° star field), 1 h, one epoch every 120 s, seed 3. Truth from the
independent DOP853 integrator (truth.oem).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log, tangent_basis
from fgnav.cli import main
from fgnav.errors import InputFormatError, UserError

SEED = 3


def _frames_rows(d: Path) -> list[dict]:
    import csv

    return list(csv.DictReader(l for l in (d / "frames.csv").read_text().splitlines()
                               if not l.startswith("#")))


def _truth(d: Path, epoch0):
    from fgnav.io.oem import read_oem
    from fgnav.time import seconds_since

    oem = read_oem(d / "truth.oem")
    t = seconds_since(np.asarray(oem.epoch0 + (oem.t_s * 1e9).astype("timedelta64[ns]")), epoch0)
    return np.asarray(t, float), oem.x_eci


@pytest.fixture(scope="module")
def pass_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("geo_images")
    assert main(["simulate", "geo-limb", "--out", str(d), "--duration-h", "1", "--step-s", "120",
                 "--seed", str(SEED), "--images", "--quiet"]) == 0
    return d


@pytest.fixture(scope="module")
def extraction(pass_dir):
    from fgnav.extract import extract_frames

    return extract_frames(pass_dir / "frames", seed=0)


def test_frames_index_attitude_plan(pass_dir):
    """Every epoch has a star frame and a limb0 frame; the plan puts limb0's boresight on the
    Earth's centre (checked against the truth position, independently of the renderer)."""
    from fgnav.extract import read_frames_index
    from fgnav.vision.attitude import matrix_from_quat
    from fgnav.vision.sensor import confocal_limb_subapertures

    rows = _frames_rows(pass_dir)
    assert sum(r["camera"] == "star" for r in rows) == 31
    assert sum(r["camera"] == "limb0" for r in rows) == 31
    b0 = confocal_limb_subapertures()[0].boresight_body
    for r in rows:
        R = matrix_from_quat([float(r[f"truth_q_eci_from_body_{c}"]) for c in "wxyz"])
        pos = np.array([float(r[f"truth_r_eci_{c}_m"]) for c in "xyz"])
        assert np.allclose(R @ b0, -pos / np.linalg.norm(pos), atol=1e-9)
        if r["camera"] == "limb0":
            assert float(r["truth_rho_rad"]) == pytest.approx(np.arcsin(6375e3 / np.linalg.norm(pos)), rel=1e-12)
            assert (pass_dir / r["file"]).is_file()
    entries = read_frames_index(pass_dir)
    assert len(entries) == 62 and entries[1].psf_sigma_px == 1.0


def test_per_frame_covariances_are_honest(pass_dir, extraction):
    """Attitude, ECI Earth direction and limb radius of each epoch against the truth columns:
    normalized errors have the chi-square means of their dimension (31 epochs)."""
    rows = [r for r in _frames_rows(pass_dir) if r["camera"] == "star"]
    from fgnav.vision.attitude import matrix_from_quat

    assert extraction.failures == {}
    z_att, z_dir, z_rho = [], [], []
    for ep, r in zip(extraction.epochs, rows):
        R_true = matrix_from_quat([float(r[f"truth_q_eci_from_body_{c}"]) for c in "wxyz"])
        pos = np.array([float(r[f"truth_r_eci_{c}_m"]) for c in "xyz"])
        e = so3_log(R_true.T @ ep.R_eci_from_body)
        z_att.append(e @ np.linalg.solve(ep.P_att_rad2, e))
        u_true = -pos / np.linalg.norm(pos)
        e2 = tangent_basis(ep.u_eci) @ u_true
        z_dir.append(e2 @ np.linalg.solve(ep.C_eci_rad2, e2))
        assert np.linalg.norm(e2) <= 6 * ep.sigma_dir_rad
        z_rho.append((ep.rho_rad - np.arcsin(6375e3 / np.linalg.norm(pos))) / ep.sigma_rho_rad)
    n = len(z_att)
    # chi2_k mean k, sd of the mean sqrt(2k/n); 4-sigma bands (over-honest below is allowed)
    assert 0.3 < np.mean(z_att) < 3 + 4 * np.sqrt(6 / n)
    assert 0.3 < np.mean(z_dir) < 2 + 4 * np.sqrt(4 / n)
    assert abs(np.mean(z_rho)) < 4 / np.sqrt(n) and 0.4 < np.std(z_rho) < 1.5
    # the direction sigma is ~1 arcsec (attitude roll dominates), rho ~0.3 arcsec (Wu et al.
    # full-circle class: 0.007 deg 2-sigma for the ellipse fit)
    assert np.degrees(np.median([e.sigma_dir_rad for e in extraction.epochs])) < 5e-4


def test_curvature_correction_removes_rho_bias(pass_dir):
    """Without the edge-curvature correction the Christian-Robinson limb radius is biased
    low by > 1 sigma on average (range too long); with it the bias is gone."""
    from fgnav.extract import horizon_from_limb_frame, read_frames_index, _load_image

    entries = [e for e in read_frames_index(pass_dir) if not e.is_star][:12]
    truth = {r["file"]: float(r["truth_rho_rad"]) for r in _frames_rows(pass_dir)
             if r["camera"] == "limb0"}
    z = {True: [], False: []}
    for k, e in enumerate(entries):
        img = _load_image(e)
        rel = str(e.path.relative_to(pass_dir))
        for cc in (True, False):
            fix = horizon_from_limb_frame(img, e, "christian-robinson", [0, k], cc)
            z[cc].append((fix.rho_rad - truth[rel]) / fix.sigma_rho_rad)
    assert np.mean(z[False]) < -1.0
    assert abs(np.mean(z[True])) < 0.8


def test_end_to_end_vs_ideal_measurements(pass_dir, tmp_path):
    """images -> fgnav extract -> fgnav smooth: position RMS within 2x of the smoother fed
    ideal measurements with the same per-row sigmas (3 noise draws), and a credible NEES."""
    from fgnav.io.log_csv import read_log, write_log
    from fgnav.simulate.images import ideal_log_like

    out = tmp_path / "extracted.csv"
    assert main(["extract", str(pass_dir / "frames"), "--out", str(out), "--quiet"]) == 0
    log = read_log(out)
    assert log.counts() == {"earth_direction": 31, "limb_radius": 31, "prior_position": 1,
                            "prior_velocity": 1}
    assert main(["smooth", str(out), "--out", str(tmp_path / "img"), "--truth", str(pass_dir / "truth.oem"),
                 "--third-body", "--quiet"]) == 0
    s_img = json.loads((tmp_path / "img" / "summary.json").read_text())
    t_truth, x_truth = _truth(pass_dir, log.epoch0)
    ideal_rms, ideal_nees = [], []
    for k in range(3):
        p = tmp_path / f"ideal{k}.csv"
        write_log(p, ideal_log_like(log, log.epoch0, t_truth, x_truth, seed=k))
        assert main(["smooth", str(p), "--out", str(tmp_path / f"ideal{k}"), "--truth",
                     str(pass_dir / "truth.oem"), "--third-body", "--quiet"]) == 0
        s = json.loads((tmp_path / f"ideal{k}" / "summary.json").read_text())
        ideal_rms.append(s["position_rms_m"])
        ideal_nees.append(s["nees_mean"])
    print(f"image-fed: position RMS {s_img['position_rms_m']:.1f} m, NEES {s_img['nees_mean']:.2f}; "
          f"ideal: RMS {np.round(ideal_rms, 1)} m, NEES {np.round(ideal_nees, 2)}")
    assert s_img["position_rms_m"] < 2.0 * np.mean(ideal_rms)
    # 6-dof state: chi2_6 99.7% quantile is 20; without the curvature correction it is ~116
    assert s_img["nees_mean"] < 20.0


def test_deterministic_by_seed(tmp_path):
    """Same seed -> identical frames and identical extracted log; another seed -> other noise."""
    import cv2

    from fgnav.extract import extract_frames
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.images import render_pass_frames
    from fgnav.simulate.pass_sim import simulate_pass

    sim = simulate_pass(load_scenario("geo-limb").with_options(duration_h=0.04, step_s=120.0), seed=1)
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        render_pass_frames(sim, tmp_path / name, seed=seed)
    img = {n: cv2.imread(str(tmp_path / n / "frames" / "000001_limb0.png"), cv2.IMREAD_UNCHANGED)
           for n in "abc"}
    assert img["a"].dtype == np.uint16 and np.array_equal(img["a"], img["b"])
    assert not np.array_equal(img["a"], img["c"])
    assert (tmp_path / "a" / "frames.csv").read_bytes() == (tmp_path / "b" / "frames.csv").read_bytes()
    la, lb = (extract_frames(tmp_path / n, priors=None).log for n in "ab")
    assert np.array_equal(la.xyz, lb.xyz, equal_nan=True) and np.array_equal(la.sigma, lb.sigma)


def test_fuse_horizons_information_weighting():
    """Two independent fixes of the same direction: the fused covariance is the inverse of
    the summed information; equal fixes halve it and keep the mean."""
    from fgnav.extract import fuse_horizons

    u = np.array([0.1, -0.2, 1.0])
    u /= np.linalg.norm(u)
    B = tangent_basis(u)
    C2a, C2b = np.diag([4e-10, 1e-10]), np.diag([1e-10, 4e-10])
    C4a, C4b = np.zeros((4, 4)), np.zeros((4, 4))
    C4a[:3, :3], C4a[3, 3] = B.T @ C2a @ B, 9e-12
    C4b[:3, :3], C4b[3, 3] = B.T @ C2b @ B, 1e-12
    ub = u + B.T @ np.array([1e-5, -2e-5])
    ub /= np.linalg.norm(ub)
    uf, Cf, rho, srho = fuse_horizons([(u, C4a, 0.15), (ub, C4b, 0.15 + 1e-6)])
    P = np.linalg.inv(np.linalg.inv(C2a) + np.linalg.inv(C2b))
    assert np.allclose(B @ Cf @ B.T, P, rtol=1e-9, atol=1e-22)
    assert srho == pytest.approx(np.sqrt(1 / (1 / 9e-12 + 1 / 1e-12)))
    assert rho == pytest.approx(0.15 + 0.9e-6, abs=1e-12)
    d_expected = P @ np.linalg.inv(C2b) @ (B @ ub)
    assert np.allclose(B @ uf, d_expected, atol=1e-10)


def test_attitude_fold_matches_monte_carlo():
    """ECI direction covariance R([u]x P_att [u]x^T + C_u)R^T against 40,000 draws of
    R Exp(phi) (u_body + noise)."""
    from fgnav.extract import earth_direction_eci

    rng = np.random.default_rng(11)
    R = so3_exp(np.array([0.3, -1.1, 2.0]))
    u_b = np.array([0.2, 0.3, -0.93])
    u_b /= np.linalg.norm(u_b)
    A = rng.standard_normal((3, 3)) * 1e-5
    P_att = A @ A.T + np.diag([1e-11, 1e-11, 1e-10])
    Bb = tangent_basis(u_b)
    C_u = Bb.T @ np.diag([4e-11, 9e-11]) @ Bb
    u, C2 = earth_direction_eci(R, P_att, u_b, C_u)
    n = 40_000
    phi = rng.multivariate_normal(np.zeros(3), P_att, n)
    nb = rng.standard_normal((n, 2)) * np.sqrt([4e-11, 9e-11])
    ub = u_b + nb @ Bb
    ub /= np.linalg.norm(ub, axis=1, keepdims=True)
    us = np.einsum("ij,njk,nk->ni", R, so3_exp(phi), ub)
    e = us @ tangent_basis(u).T
    C_mc = np.cov(e.T)
    assert np.allclose(C_mc, C2, rtol=0.05, atol=0.03 * np.max(np.abs(C2)))


def test_frames_index_errors(tmp_path, pass_dir):
    from fgnav.extract import extract_frames, read_frames_index

    with pytest.raises(UserError, match="no frames.csv"):
        read_frames_index(tmp_path)
    lines = (pass_dir / "frames.csv").read_text().splitlines()
    hdr = next(i for i, l in enumerate(lines) if l.startswith("epoch,"))
    bad = lines[:hdr + 1] + [lines[hdr + 1].replace(",50.0,", ",fifty,", 1)]
    (tmp_path / "frames.csv").write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFormatError) as ei:
        read_frames_index(tmp_path)
    assert ei.value.line == hdr + 2 and ei.value.column == "focal_mm"
    missing = lines[:hdr + 1] + [lines[hdr + 1].replace("frames/000000_star.png", "frames/nope.png")]
    (tmp_path / "frames.csv").write_text("\n".join(missing) + "\n")
    with pytest.raises(UserError, match="does not exist"):
        extract_frames(tmp_path)
    with pytest.raises(UserError, match="unknown horizon method"):
        extract_frames(pass_dir, method="circle")
    assert main(["extract", str(tmp_path), "--out", str(tmp_path / "x.csv"), "--quiet"]) == 2


def test_attitude_csv_round_trips_and_its_covariance_is_credible(pass_dir, tmp_path):
    """fgnav extract --attitude-out: the star-derived attitude per epoch,
    read back and compared with the true attitude of each star frame."""
    import gtsam

    from fgnav.io.attitude_csv import read_attitude_csv
    from fgnav.time import parse_utc

    att = tmp_path / "attitude.csv"
    assert main(["extract", str(pass_dir / "frames"), "--out", str(tmp_path / "x.csv"),
                 "--attitude-out", str(att), "--quiet"]) == 0
    t, R, P = read_attitude_csv(att)
    truth = {parse_utc(r["epoch"]): np.array([float(r[f"truth_q_eci_from_body_{c}"]) for c in "wxyz"])
             for r in _frames_rows(pass_dir) if r["camera"] == "star"}
    assert len(t) == len(truth) == 31
    nees = []
    for ti, Ri, Pi in zip(t, R, P):
        Rt = gtsam.Rot3.Quaternion(*truth[ti]).matrix()
        w = gtsam.Rot3.Logmap(gtsam.Rot3(Rt.T @ Ri))  # body-frame error of the estimate
        nees.append(w @ np.linalg.solve(Pi, w))
    assert np.max(np.degrees(np.sqrt(np.diagonal(P, axis1=1, axis2=2)))) < 0.01  # arc-second class
    assert 0.5 < np.mean(nees) / 3 < 2.0  # 3-dof NEES near 3 over 31 frames


def test_default_image_period_bounds_the_pass():
    """Without --image-period-s a pass renders at most DEFAULT_MAX_IMAGE_EPOCHS epochs, on
    the measurement grid: geo-limb (12 h at 60 s, 721 epochs) every 480 s (91 epochs, each
    a measurement epoch); a short pass keeps every epoch; an explicit period wins."""
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.images import DEFAULT_MAX_IMAGE_EPOCHS, default_image_period_s, frame_epochs
    from fgnav.simulate.pass_sim import sensor_epochs

    scn = load_scenario("geo-limb")
    t = frame_epochs(scn, None)
    assert default_image_period_s(scn) == 480.0 and len(t) == 91 <= DEFAULT_MAX_IMAGE_EPOCHS
    assert np.all(np.isin(t, sensor_epochs(scn, None))) and t[-1] == 12 * 3600.0
    short = scn.with_options(duration_h=1.0, step_s=120.0)
    assert len(frame_epochs(short, None)) == 31 == len(sensor_epochs(short, None))
    assert len(frame_epochs(scn, 60.0)) == 721
    with pytest.raises(UserError, match="image period"):
        frame_epochs(scn, 0.0)
