"""No confident wrong answer, no traceback, on the routes added last (the integrity issue:
formations, attitude, the cruise, campaigns): each defect the adversary found, with a variant
that is not its reproducer, the verdict asserted."""

from __future__ import annotations

import json

import pytest

from fgnav.cli import main


@pytest.fixture(scope="module")
def cruise_log(tmp_path_factory):
    """A week of the mars-cruise scenario (angles every 4 h, no prior rows)."""
    d = tmp_path_factory.mktemp("cruise")
    assert main(["simulate", "mars-cruise", "--out", str(d), "--duration-h", "168", "--quiet"]) == 0
    return (d / "measurements.csv").read_text().splitlines()


@pytest.mark.parametrize("position_m", ["1.0e7,2.0e7,0.5e7", "-3.0e8,1.0e8,2.0e8"])
def test_a_heliocentric_prior_inside_the_sun_fails_without_a_traceback(cruise_log, tmp_path,
                                                                        capsys, position_m):
    """A '# centre: sun' log whose prior lies inside the Sun drives the iterates beyond the
    speed of light, where the aberration model is undefined (it raised 'math domain error');
    now those rows are outside the model's domain and the verdict says the solution failed."""
    head = cruise_log[:3]
    assert head[1] == "# centre: sun" and head[2].startswith("epoch,kind")
    t0 = cruise_log[3].split(",")[0]
    rows = [f"{t0},prior_position,{position_m},1.0e4,,,,,",
            f"{t0},prior_velocity,10.0,20.0,0.0,100.0,,,,,"]
    log = tmp_path / "inside_sun.csv"
    log.write_text("\n".join(head + rows + cruise_log[3:]) + "\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "domain error" not in err
    if rc == 0:
        summary = json.loads((tmp_path / "r" / "summary.json").read_text())
        assert summary["integrity"]["status"] == "failed", summary["integrity"]
    else:
        assert rc == 2 and "line" in err, err


def _keep_star_epochs(lines: list[str], every: int) -> list[str]:
    """The log with star_direction_body rows kept at one epoch in ``every`` only."""
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch,")]
    rows = [ln for ln in lines if ln not in head]
    epochs = sorted({r.split(",", 1)[0] for r in rows})
    keep = set(epochs[::every])
    return head + [r for r in rows
                   if r.split(",")[1] != "star_direction_body" or r.split(",", 1)[0] in keep]


@pytest.fixture(scope="module")
def raw_star_pass(tmp_path_factory):
    """2 h of geo-limb with raw stars (every 60 s), seeds 0 and 3."""
    out = {}
    for seed in (0, 3):
        d = tmp_path_factory.mktemp(f"raw{seed}")
        assert main(["simulate", "geo-limb", "--raw-stars", "--duration-h", "2", "--seed",
                     str(seed), "--out", str(d), "--quiet"]) == 0
        out[seed] = d
    return out


@pytest.mark.parametrize("seed, every", [(0, 20), (3, 30)])
def test_ekf_constant_rate_with_sparse_stars_is_not_called_ok(raw_star_pass, tmp_path, seed,
                                                             every):
    """The EKF's constant-rate attitude with stars at one epoch in 20 ended at orbit NEES 29 and
    roll 46 sigma off with the verdict ok (the integrity issue, item 2): its innovations were
    normalized by a covariance rebuilt with the attitude's random walk (4 deg per minute), so
    every star looked small. The verdict now takes the filter's own normalized innovations,
    which show the stars' misfit."""
    d = raw_star_pass[seed]
    log = tmp_path / "sparse.csv"
    log.write_text("\n".join(_keep_star_epochs((d / "measurements.csv").read_text().splitlines(),
                                               every)) + "\n")
    args = ["--attitude", "estimate", "--attitude-motion", "constant-rate", "--third-body",
            "--truth", str(d / "truth.oem"), "--quiet"]
    assert main(["smooth", str(log), "--method", "ekf", "--out", str(tmp_path / "ekf"), *args]) == 0
    ekf = json.loads((tmp_path / "ekf" / "summary.json").read_text())
    # inconsistent against truth (NEES of 6 dof beyond its 95 % bound) exactly when not ok
    consistent = ekf["nees_mean"] < 12.6
    assert (ekf["integrity"]["status"] == "ok") == consistent, (ekf["nees_mean"],
                                                              ekf["integrity"]["reasons"])
    if not consistent:
        assert ekf["integrity"]["families"]["star_direction_body"]["status"] != "ok"
    # the batch on the same log is consistent and called ok
    assert main(["smooth", str(log), "--out", str(tmp_path / "batch"), *args]) == 0
    batch = json.loads((tmp_path / "batch" / "summary.json").read_text())
    assert batch["integrity"]["status"] == "ok" and batch["nees_mean"] < 12.6


def test_ekf_constant_rate_with_every_star_epoch_stays_ok(raw_star_pass, tmp_path):
    """No false alarm from the filter's own innovations: stars at every epoch, NEES ~3, ok."""
    d = raw_star_pass[0]
    assert main(["smooth", str(d / "measurements.csv"), "--method", "ekf", "--out",
                 str(tmp_path / "ekf"), "--attitude", "estimate", "--attitude-motion",
                 "constant-rate", "--third-body", "--truth", str(d / "truth.oem"),
                 "--quiet"]) == 0
    s = json.loads((tmp_path / "ekf" / "summary.json").read_text())
    assert s["integrity"]["status"] == "ok" and s["nees_mean"] < 12.6
    star = s["integrity"]["families"]["star_direction_body"]
    assert 0.7 < star["normalized"] < 1.4


def _centre_variants(lines: list[str]) -> dict[str, list[str]]:
    assert lines[1] == "# centre: sun"
    return {"deleted": [lines[0]] + lines[2:],
            "earth": [lines[0], "# centre: earth"] + lines[2:],
            "below the header": [lines[0], lines[2], lines[1]] + lines[3:]}


@pytest.mark.parametrize("variant", ["deleted", "earth", "below the header"])
def test_a_heliocentric_log_without_its_centre_line_is_refused_at_once(cruise_log, tmp_path,
                                                                        capsys, variant):
    """Read as geocentric, the cruise's angles put the first fixes 0.065 AU from the Earth,
    and the track fit then ran for hours about the Earth (the integrity issue, item 3) while
    `fgnav check` said the log could be smoothed. Now both say what is wrong, before any long
    work."""
    log = tmp_path / "log.csv"
    log.write_text("\n".join(_centre_variants(cruise_log)[variant]) + "\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "'# centre: sun'" in err and "AU from the earth" in err, err
    assert main(["check", str(log)]) == 0
    out = capsys.readouterr().out
    assert "without a prior: cannot be smoothed" in out and "'# centre: sun'" in out


def test_a_heliocentric_prior_in_a_log_read_as_geocentric_is_refused(cruise_log, tmp_path,
                                                                      capsys):
    """With prior rows (the true state, 1.03 AU from the Earth) and no centre line, the solve
    about the Earth ran for minutes; the start policy now names the prior's line."""
    t0 = cruise_log[3].split(",")[0]
    # the cruise's true state at its first epoch (its truth.oem, km -> m)
    x = "-71411267196.027,125952896819.755,54598746250.093"
    v = "-29785.150028,-10095.289159,-4375.961482"
    rows = [f"{t0},prior_position,{x},10000.0,,,,,", f"{t0},prior_velocity,{v},1.0,,,,,"]
    log = tmp_path / "log.csv"
    log.write_text("\n".join([cruise_log[0], cruise_log[2]] + rows + cruise_log[3:]) + "\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and f"{log}, line 3" in err and "'# centre: sun'" in err, err


@pytest.fixture(scope="module")
def formation_log(tmp_path_factory):
    """1 h of formation-gto at 60 s (seed 0): three links each way per epoch."""
    d = tmp_path_factory.mktemp("formation")
    assert main(["simulate", "formation-gto", "--duration-h", "1", "--step-s", "60", "--out",
                 str(d), "--quiet"]) == 0
    return d


@pytest.mark.parametrize("antenna", ["rx1", "rx2"])
def test_a_formation_in_its_mirror_minimum_is_not_called_ok(formation_log, tmp_path, antenna):
    """Links received through one antenna each way: batch put sat2 950 m behind sat1 instead
    of ahead, 1,404 m RMS against a 26 m sigma, relative NEES 3e11, verdict ok (the integrity
    issue, item 1). The mirrored relative geometry is now solved too, and it fits better."""
    lines = (formation_log / "measurements.csv").read_text().splitlines()
    others = {"rx1", "rx2", "rx3"} - {antenna}
    keep = [ln for ln in lines if not any(f",{o}," in ln for o in others)]
    log = tmp_path / "one_antenna.csv"
    log.write_text("\n".join(keep) + "\n")
    assert main(["smooth", str(log), "--out", str(tmp_path / "r"), "--truth", str(formation_log),
                 "--quiet"]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    rel = s["relative"]
    assert rel["position_rms_m"] > 10 * rel["sigma_position_rms_m"]   # it is the mirror ...
    assert s["integrity"]["status"] == "failed"                      # ... and says so
    assert s["integrity"]["tests"]["mirror"]["status"] == "failed"
    assert any("mirror image" in r for r in s["integrity"]["reasons"])


def test_a_formation_with_every_link_passes_the_mirror_test(formation_log, tmp_path):
    """No false alarm: with three receive antennas the mirror is refuted by far."""
    assert main(["smooth", str(formation_log / "measurements.csv"), "--out", str(tmp_path / "r"),
                 "--truth", str(formation_log), "--quiet"]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    mirror = s["integrity"]["tests"]["mirror"]
    assert s["integrity"]["status"] == "ok" and mirror["status"] == "ok"
    assert mirror["chi2_mirrored"] > mirror["chi2"] + 1e3
    assert s["relative"]["position_rms_m"] < 2 * s["relative"]["sigma_position_rms_m"]


@pytest.mark.parametrize("year, bodies", [("2150", "all"), ("1850", "earth only")])
def test_a_geocentric_angle_log_outside_the_ephemeris_span_is_refused(tmp_path, capsys, year,
                                                                      bodies):
    """Geocentric angle logs outside 1900-2100 were solved (verdict failed) where the
    heliocentric route refused them (the integrity issue, item 8): now both refuse, naming a
    line, also when every body is the Earth (no ERFA call; the aberration's Earth velocity came
    from the low-precision series, extrapolated)."""
    d = tmp_path / "pass"
    assert main(["simulate", "sextant-leo", "--duration-h", "1", "--out", str(d), "--quiet"]) == 0
    lines = (d / "measurements.csv").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch,")]
    rows = [ln.replace("2025-", f"{year}-", 1) for ln in lines if ln not in head]
    if bodies == "earth only":
        rows = [r for r in rows if r.split(",")[1].startswith("prior") or r.endswith(",earth,")]
    assert any(",moon," in r for r in rows) == (bodies == "all")
    log = tmp_path / "shifted.csv"
    log.write_text("\n".join(head + rows) + "\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "line" in err and "1900-2100" in err, err


@pytest.mark.parametrize("value", ["1e9", "3e8"])
def test_a_wild_link_row_is_a_message_not_a_warning_and_an_unobservable_state(formation_log,
                                                                              tmp_path, capsys,
                                                                              value):
    """One link row of 1e9 m drove the estimate beyond light speed, where the light time has
    no root: numpy warned 'invalid value in sqrt' and the solve ended 'state component x not
    observable' (the integrity issue, item 8). Now the model's domain error names a log line."""
    lines = (formation_log / "measurements.csv").read_text().splitlines()
    i = next(n for n, ln in enumerate(lines) if ",isl_pseudorange," in ln and "T00:10" in ln)
    f = lines[i].split(",")
    f[2] = value
    lines[i] = ",".join(f)
    log = tmp_path / "wild.csv"
    log.write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert "Warning" not in err and "Traceback" not in err, err
    if rc == 2:
        assert "log line" in err and "not observable" not in err, err
    else:   # solved: then the verdict must not call it ok
        s = json.loads((tmp_path / "r" / "summary.json").read_text())
        assert rc == 0 and s["integrity"]["status"] != "ok"


@pytest.mark.parametrize("seed", [0, 3])
def test_a_raw_star_log_without_a_prior_starts_from_its_stars(raw_star_pass, tmp_path, seed):
    """Each frame's stars fix the attitude (Wahba), which turns the body-frame Earth
    directions into ECI for the initial orbit: a raw-star log without prior rows could not be
    started (the integrity issue, item 8), so `fgnav extract --raw-stars` without priors gave
    an unusable log. Now it is solved from the data alone, consistent with truth."""
    d = raw_star_pass[seed]
    lines = (d / "measurements.csv").read_text().splitlines()
    log = tmp_path / "noprior.csv"
    log.write_text("\n".join(ln for ln in lines if ",prior_" not in ln) + "\n")
    assert main(["check", str(log)]) == 0
    assert main(["smooth", str(log), "--out", str(tmp_path / "r"), "--estimate", "attitude",
                 "--third-body", "--truth", str(d / "truth.oem"), "--quiet"]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["initial_orbit"]["prior"] == "initial_orbit"
    assert s["integrity"]["status"] == "ok" and s["nees_mean"] < 12.6
    assert s["position_rms_m"] < 2.0 * s["sigma_position_rms_m"]


@pytest.mark.parametrize("duration_h, seed", [(168, 0), (96, 2)])
def test_the_cruise_without_aberration_is_not_called_ok(cruise_log, tmp_path, duration_h, seed):
    """--no-aberration on the cruise gave ok with NEES 974 (the integrity issue, item 9): the
    fit absorbs the 20-arcsec shift into the orbit (chi-square 114.3 against 113.6 with the
    correction), so no residual test sees it. The consider analysis of the omitted correction
    predicts the error it causes, and the verdict says so; with the correction the same log
    is ok and its NEES honest."""
    if (duration_h, seed) == (168, 0):
        log = tmp_path / "cruise.csv"
        log.write_text("\n".join(cruise_log) + "\n")
        truth = None
    else:   # a variant: another seed, a shorter cruise
        d = tmp_path / "sim"
        assert main(["simulate", "mars-cruise", "--out", str(d), "--duration-h", str(duration_h),
                     "--seed", str(seed), "--quiet"]) == 0
        log, truth = d / "measurements.csv", d / "truth.oem"
    runs = {}
    for label, extra in (("physics", []), ("no aberration", ["--no-aberration"])):
        out = tmp_path / label.replace(" ", "_")
        args = ["smooth", str(log), "--out", str(out), "--quiet", *extra]
        if truth is not None:
            args += ["--truth", str(truth)]
        assert main(args) == 0
        runs[label] = json.loads((out / "summary.json").read_text())
    ok, off = runs["physics"]["integrity"], runs["no aberration"]["integrity"]
    assert ok["status"] == "ok" and "aberration_omitted" not in ok
    assert off["status"] == "suspect", off
    assert any(r.startswith("--no-aberration") for r in off["reasons"])
    predicted = off["aberration_omitted"]
    assert predicted["mean_nees"] > 24.0
    if truth is not None:   # the prediction is the error: NEES against truth within 2x
        nees = runs["no aberration"]["nees_mean"]
        assert 0.5 < predicted["mean_nees"] / nees < 2.0, (predicted, nees)
        assert runs["physics"]["nees_mean"] < 12.0


@pytest.mark.parametrize("seed", [4, 9])
def test_a_star_camera_mounting_the_stars_reveal_is_not_called_ok(tmp_path, seed):
    """An unestimated star-camera mounting error of 60 arcsec (1 sigma per axis) gave ok with
    orbit NEES 47-361 (the integrity issue, item 9; here 4,168-11,157). Solved again with the
    mounting in the graph, the chi-square falls by 28 (seeds 4, 9) where 16.3 is its 1e-3
    false-alarm threshold: the verdict says suspect and names the option, which then gives
    an honest orbit."""
    d = tmp_path / "sim"
    assert main(["simulate", "geo-limb", "--raw-stars", "--duration-h", "2",
                 "--star-mounting-sigma-arcsec", "60", "--seed", str(seed), "--out", str(d),
                 "--quiet"]) == 0
    runs = {}
    for label, extra in (("ignored", []), ("estimated", ["--estimate", "camera-alignment"])):
        out = tmp_path / label
        assert main(["smooth", str(d / "measurements.csv"), "--out", str(out), "--truth",
                     str(d / "truth.oem"), "--attitude", "estimate", "--third-body", "--quiet",
                     *extra]) == 0
        runs[label] = json.loads((out / "summary.json").read_text())
    ignored, estimated = runs["ignored"], runs["estimated"]
    assert ignored["nees_mean"] > 100.0                      # the error is real ...
    assert ignored["integrity"]["status"] == "suspect"       # ... and the verdict says so
    test = ignored["integrity"]["camera_mounting"]
    assert test["chi2_drop"] > test["threshold"] and test["mounting_arcsec"] > 30.0
    assert any("camera-alignment" in a for a in ignored["integrity"]["advice"])
    assert estimated["integrity"]["status"] == "ok" and estimated["nees_mean"] < 18.0
    assert "camera_mounting" not in estimated["integrity"]   # (estimated: nothing to test)


def test_star_rows_in_the_body_frame_pass_the_mounting_test(raw_star_pass, tmp_path):
    """No false alarm: star rows in the body frame (no mounting error drawn), seeds 0 and 3."""
    for seed, d in raw_star_pass.items():
        out = tmp_path / f"r{seed}"
        assert main(["smooth", str(d / "measurements.csv"), "--out", str(out), "--truth",
                     str(d / "truth.oem"), "--attitude", "estimate", "--third-body",
                     "--quiet"]) == 0
        s = json.loads((out / "summary.json").read_text())
        test = s["integrity"]["camera_mounting"]
        assert test["status"] == "ok" and test["chi2_drop"] < test["threshold"], test
        assert s["integrity"]["status"] == "ok" and s["nees_mean"] < 18.0
