"""``fgnav extract --raw-stars``: the identified stars of each star frame as
``star_direction_body`` rows (tight coupling) instead of one solved attitude.

The eight REAL night-sky images (ESA tetra3 test data, ~11.4 deg field, see
tests/test_star_id_real.py) go through the same front end as a simulated pass (a
``frames.csv`` index -> :func:`fgnav.extract.extract_frames`); the attitude a one-key
factor graph solves from one frame's star rows (GTSAM ``Rot3``, the star-direction factor,
Levenberg-Marquardt, marginal covariance) must equal the SVD solution of Wahba's problem
on the same rows (Markley 1988) and the identification's own refined attitude, each within
its sigma.
"""

from shared_data import SHARED_DATA  # noqa: E402

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.cli import main
from fgnav.io.log_csv import STAR_COLUMNS, read_log
from fgnav.vision.attitude import quest_covariance, wahba_svd
from fgnav.vision.camera import PinholeCamera

IMAGES = sorted((SHARED_DATA / "star_images").glob("*.tiff"))
EPOCH0 = np.datetime64("2019-07-29T20:47:26", "s")


def _write_index(d, images, camera: PinholeCamera):
    """A frames.csv for the real images: one star frame a second (they were taken one after
    another; the header's columns are those fgnav.simulate.images writes)."""
    from fgnav.simulate.images import FRAME_COLUMNS

    lines = [",".join(FRAME_COLUMNS)]
    for k, p in enumerate(images):
        row = dict.fromkeys(FRAME_COLUMNS, "")
        row.update(epoch=str(EPOCH0 + np.timedelta64(k, "s")) + "Z", file=str(p), camera="star",
                   focal_mm=repr(float(camera.focal_mm)), pixel_um=repr(float(camera.pixel_um)),
                   width_px=str(camera.width_px), height_px=str(camera.height_px),
                   cx_px=repr(float(camera.cx)), cy_px=repr(float(camera.cy)), q_body_from_cam_w="1.0",
                   q_body_from_cam_x="0.0", q_body_from_cam_y="0.0", q_body_from_cam_z="0.0")
        lines.append(",".join(row[c] for c in FRAME_COLUMNS))
    (d / "frames.csv").write_text("\n".join(lines) + "\n")
    return d / "frames.csv"


def graph_attitude(u_body, s_eci, sigma_rad, R0):
    """Single-frame attitude from star rows: one Rot3 key, one star-direction factor per
    row, Levenberg-Marquardt from ``R0``; (R_eci_from_body, marginal covariance rad^2)."""
    import gtsam

    from factors.direction import make_star_direction_factor

    A = gtsam.symbol("a", 0)
    graph = gtsam.NonlinearFactorGraph()
    for u, s, sg in zip(u_body, s_eci, sigma_rad):
        graph.add(make_star_direction_factor(A, s, u, float(sg)))
    values = gtsam.Values()
    values.insert(A, gtsam.Rot3(R0))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return result.atRot3(A).matrix(), gtsam.Marginals(graph, result).marginalCovariance(A)


@pytest.fixture(scope="module")
def real_extraction(tmp_path_factory):
    if len(IMAGES) != 8:
        pytest.skip("real star images not present")
    from fgnav.extract import extract_frames

    d = tmp_path_factory.mktemp("real_stars")
    idx = _write_index(d, IMAGES, PinholeCamera.from_fov(11.4 * 1.05, 1024, 768))
    return idx, extract_frames(idx, rows="raw-stars")


def test_real_images_single_frame_graph_attitude_equals_wahba_and_lost_in_space(real_extraction):
    _, res = real_extraction
    log = res.log
    assert res.failures == {} and set(log.counts()) == {"star_direction_body"}
    kinds = np.asarray(log.kind).astype(str)
    s_all = np.column_stack([log.extra[c] for c in STAR_COLUMNS])
    epochs = np.unique(log.t_s)
    assert len(epochs) == 8
    rng = np.random.default_rng(4)
    for t, ep in zip(epochs, res.epochs):
        rows = (log.t_s == t) & (kinds == "star_direction_body")
        u, s, sig = log.xyz[rows], s_all[rows], log.sigma[rows]
        assert rows.sum() == ep.stars_matched >= 7
        # the rows: unit vectors; sigma = centroid sigma / f, ~0.05-0.5 px at ~40 arcsec/px
        assert np.allclose(np.linalg.norm(u, axis=1), 1) and np.allclose(np.linalg.norm(s, axis=1), 1)
        assert np.all((sig > 0.2 / 3600 * np.pi / 180) & (sig < 40 / 3600 * np.pi / 180))
        # the lost-in-space fit sees apparent directions (the catalogue aberrated by the
        # Earth's barycentric velocity: these frames come with no orbit prior), so the graph
        # is given the same directions
        from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
        from fgnav.time import j2000_seconds

        v_earth = earth_velocity_bcrs_mps(np.array([float(j2000_seconds(log.epoch0)) + t]))
        s, _ = apparent_direction(s, np.broadcast_to(v_earth, s.shape))
        w = wahba_svd(u, s, sig)
        R0 = w.R_ref_from_body @ so3_exp(rng.normal(0, 0.01, 3))   # ~0.6 deg off
        R_g, P_g = graph_attitude(u, s, sig, R0)
        # graph vs SVD/QUEST: the same least-squares problem -> the same attitude, far
        # inside its sigma, and the graph's marginal = the QUEST covariance (Shuster & Oh)
        d = so3_log(w.R_ref_from_body.T @ R_g)
        assert d @ np.linalg.solve(P_g, d) < 1e-6
        assert np.allclose(P_g, quest_covariance(u, sig), rtol=1e-3)
        # graph vs the lost-in-space refinement (pixel model, focal length fitted, covariance
        # scaled by its a-posteriori variance factor): equal within its sigma
        d2 = so3_log(ep.R_eci_from_body.T @ R_g)
        assert np.all(np.abs(d2) < np.sqrt(np.diag(ep.P_att_rad2))), d2 / np.sqrt(np.diag(ep.P_att_rad2))


def test_cli_raw_stars_and_rows_conflict(real_extraction, tmp_path, capsys):
    idx, res = real_extraction
    out = tmp_path / "raw.csv"
    assert main(["extract", str(idx), "--raw-stars", "--out", str(out), "--quiet"]) == 0
    log = read_log(out)
    assert log.counts() == res.log.counts()
    assert np.allclose(log.extra["star_x"], res.log.extra["star_x"], rtol=0, atol=1e-15)
    assert main(["extract", str(idx), "--raw-stars", "--rows", "body", "--out", str(out)]) == 2
    assert "--raw-stars" in capsys.readouterr().err


def test_simulated_pass_raw_stars_rows(tmp_path):
    """A simulated pass: per epoch the star rows of every identified star and one body-frame
    Earth row (+ limb radius); every star row's measured direction is its catalogue
    direction seen with the TRUE attitude to within ~5 of its sigma, and the sigma is
    honest: the squared normalized error averages 1 per tangent axis (0.40 with the
    detector's sigma unscaled, measured on a 31-epoch pass)."""
    import csv

    from fgnav.extract import extract_frames
    from fgnav.vision.attitude import matrix_from_quat

    assert main(["simulate", "geo-limb", "--out", str(tmp_path), "--duration-h", "0.2", "--step-s", "120",
                 "--seed", "2", "--images", "--quiet"]) == 0
    res = extract_frames(tmp_path, rows="raw-stars")
    c = res.log.counts()
    n_ep = len(res.epochs)
    assert n_ep == 7 and c["earth_direction_body"] == n_ep == c["limb_radius"]
    assert c["star_direction_body"] == sum(e.stars_matched for e in res.epochs) >= 10 * n_ep
    assert "attitude" not in c and "earth_direction" not in c
    rows = [r for r in csv.DictReader(l for l in (tmp_path / "frames.csv").read_text().splitlines()
                                      if not l.startswith("#")) if r["camera"] == "star"]
    kinds = np.asarray(res.log.kind).astype(str)
    s_all = np.column_stack([res.log.extra[c] for c in STAR_COLUMNS])
    # the frames show apparent directions: the catalogue aberrated by the Earth's barycentric
    # velocity plus the spacecraft's true velocity
    from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
    from fgnav.io.oem import read_oem
    from fgnav.orbit import truth_at
    from fgnav.time import j2000_seconds, seconds_since

    oem = read_oem(tmp_path / "truth.oem")
    z = []
    for t, r in zip(np.unique(res.log.t_s), rows):
        R = matrix_from_quat([float(r[f"truth_q_eci_from_body_{c}"]) for c in "wxyz"])
        m = (res.log.t_s == t) & (kinds == "star_direction_body")
        t_oem = float(seconds_since(res.log.epoch0, oem.epoch0)) + t
        v = earth_velocity_bcrs_mps(np.array([float(j2000_seconds(res.log.epoch0)) + t])) \
            + truth_at(oem.t_s, oem.x_eci, np.array([t_oem]))[:, 3:]
        s_app, _ = apparent_direction(s_all[m], np.broadcast_to(v, s_all[m].shape))
        e = np.linalg.norm(np.cross(res.log.xyz[m], s_app @ R), axis=1)   # angle (rad)
        z.extend(e / res.log.sigma[m])
    z = np.array(z)
    assert np.max(z) < 6.0
    assert 0.7 < np.mean(z ** 2) / 2 < 1.4, np.mean(z ** 2) / 2      # chi2_2 / 2 per row
