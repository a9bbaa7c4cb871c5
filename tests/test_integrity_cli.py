"""`fgnav smooth` refuses what it cannot do before solving (exit 2, a message naming the
option / path / line, never a traceback), keeps an output directory to one run's set of
files, validates checkpoints, and resumes to the answer of an uninterrupted run."""

import io
import json
import os
import pickle
import subprocess
import sys
import zipfile

import numpy as np
import pytest

import fgnav.pipeline
import fgnav.solvers.incremental
from fgnav.cli import main
from fgnav.io.oem import read_oem

# ---- fixtures ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_pass(tmp_path_factory):
    """gto-transfer, 2 h at 60 s (121 epochs): measurements.csv + truth.oem."""
    d = tmp_path_factory.mktemp("pass")
    assert main(["simulate", "gto-transfer", "--out", str(d), "--step-s", "60",
                 "--duration-h", "2", "--quiet", "--seed", "4"]) == 0
    return d


@pytest.fixture
def no_solving(monkeypatch):
    """Any solve (or the start of the iSAM2 epoch loop) fails the test."""
    def forbidden(*a, **k):
        raise AssertionError("solving started")

    monkeypatch.setattr(fgnav.pipeline, "solve", forbidden)


@pytest.fixture(scope="module")
def checkpoint(small_pass, tmp_path_factory):
    """A valid checkpoint of the whole small pass (isam2, every 25 epochs)."""
    d = tmp_path_factory.mktemp("ckpt")
    ck = d / "run.npz"
    assert main(["smooth", str(small_pass / "measurements.csv"), "--method", "isam2",
                 "--out", str(d / "out"), "--checkpoint", str(ck), "--checkpoint-every", "25",
                 "--quiet"]) == 0
    return ck


def _smooth(log, out, *extra):
    return main(["smooth", str(log), "--out", str(out), "--quiet", *extra])


def _refused(capsys, *must_name):
    err = capsys.readouterr().err
    assert err.startswith("fgnav: error: "), err
    assert "Traceback" not in err
    for s in must_name:
        assert s in err, (s, err)
    return err


# ---- option values and applicability ----------------------------------------------------

BAD_OPTIONS = [
    (["--method", "isam2", "--checkpoint", "{ck}", "--checkpoint-every", "0"], "--checkpoint-every"),
    (["--method", "isam2", "--checkpoint", "{ck}", "--checkpoint-every", "-3"], "--checkpoint-every"),
    (["--method", "fixed-lag", "--lag-s", "0"], "--lag-s"),
    (["--method", "fixed-lag", "--lag-s", "-60"], "--lag-s"),
    (["--method", "fixed-lag", "--lag-s", "nan"], "--lag-s"),
    (["--process-noise", "nan"], "--process-noise"),
    (["--process-noise", "inf"], "--process-noise"),
    (["--process-noise", "0"], "--process-noise"),
    (["--robust", "huber", "--robust-k", "0"], "--robust-k"),
    (["--robust", "cauchy", "--robust-k", "nan"], "--robust-k"),
    (["--robust", "cauchy", "--robust-k", "-1"], "--robust-k"),
    (["--method", "ekf", "--gate", "0"], "--gate"),
    (["--method", "ekf", "--gate", "1"], "--gate"),
    (["--method", "isam2", "--gate", "1e-4"], "Did you mean 0.9999"),
    (["--method", "isam2", "--gate", "1.5"], "--gate"),
    (["--method", "ekf", "--gate", "nan"], "--gate"),
    # options the method would ignore
    (["--method", "batch", "--gate", "0.9999"], "--gate"),
    (["--method", "ekf", "--robust", "cauchy"], "--robust"),
    (["--method", "batch", "--checkpoint", "{ck}"], "--checkpoint"),
    (["--method", "fixed-lag", "--checkpoint", "{ck}"], "--checkpoint"),
    (["--method", "ekf", "--checkpoint", "{ck}", "--resume"], "--checkpoint"),
    (["--method", "batch", "--checkpoint-every", "10"], "--checkpoint-every"),
    (["--method", "isam2", "--lag-s", "100"], "--lag-s"),
    (["--method", "batch", "--lag-s", "100"], "--lag-s"),
    (["--robust-k", "2"], "--robust-k"),
    (["--method", "isam2", "--resume"], "--resume"),
    (["--method", "isam2", "--checkpoint-every", "10"], "--checkpoint-every"),
]


@pytest.mark.parametrize("extra,option", BAD_OPTIONS, ids=[" ".join(a) for a, _ in BAD_OPTIONS])
def test_a_bad_or_inapplicable_option_is_refused_before_solving(small_pass, tmp_path, capsys,
                                                                no_solving, extra, option):
    extra = [a.replace("{ck}", str(tmp_path / "c.npz")) for a in extra]
    assert _smooth(small_pass / "measurements.csv", tmp_path / "out", *extra) == 2
    _refused(capsys, option)
    assert not (tmp_path / "out").exists()


def test_the_documented_defaults_still_apply(small_pass, tmp_path):
    out = tmp_path / "out"
    assert _smooth(small_pass / "measurements.csv", out, "--method", "fixed-lag") == 0
    assert json.loads((out / "summary.json").read_text())["lag_s"] == 300.0


def test_demo_refuses_an_option_none_of_its_methods_uses(capsys):
    assert main(["demo", "--methods", "batch", "--gate", "0.999"]) == 2
    _refused(capsys, "--gate")
    assert main(["demo", "--methods", "batch,kalman"]) == 2
    _refused(capsys, "--methods", "kalman")


# ---- values in the log ------------------------------------------------------------------

def _edit_row(src, dst, kind, edit):
    """Copy the log with the first row of ``kind`` edited; returns its 1-based line."""
    lines = src.read_text().splitlines()
    for i, line in enumerate(lines):
        f = line.split(",")
        if len(f) > 1 and f[1] == kind:
            lines[i] = ",".join(edit(f))
            dst.write_text("\n".join(lines) + "\n")
            return i + 1
    raise AssertionError(kind)


@pytest.mark.parametrize("kind,edit,column", [
    ("earth_direction", lambda f: f[:5] + ["1e-300"], "sigma"),
    ("earth_direction", lambda f: f[:5] + ["1e-12"], "sigma"),
    ("earth_direction", lambda f: f[:5] + ["2.0"], "sigma"),
    ("prior_position", lambda f: f[:5] + ["1e-300"], "sigma"),
    ("prior_velocity", lambda f: f[:5] + ["1e12"], "sigma"),
    ("prior_position", lambda f: f[:2] + ["0", "0", "0"] + f[5:], "x,y,z"),
    ("prior_position", lambda f: f[:2] + ["3000e3", "-2000e3", "1000e3"] + f[5:], "x,y,z"),
], ids=["direction 1e-300", "direction 1e-12", "direction 2 rad", "prior 1e-300 m",
        "prior velocity 1e12", "prior at the centre", "prior inside the Earth"])
def test_a_nonsense_value_in_the_log_is_refused_with_its_line(small_pass, tmp_path, capsys,
                                                               no_solving, kind, edit, column):
    log = tmp_path / "bad.csv"
    line = _edit_row(small_pass / "measurements.csv", log, kind, edit)
    assert _smooth(log, tmp_path / "out") == 2
    _refused(capsys, f"{log}, line {line}, column '{column}'")


# ---- output paths -------------------------------------------------------------------------

def test_out_an_existing_file_is_refused(small_pass, tmp_path, capsys, no_solving):
    f = tmp_path / "result"
    f.write_text("mine")
    assert _smooth(small_pass / "measurements.csv", f) == 2
    _refused(capsys, "--out", str(f), "not a directory")
    assert f.read_text() == "mine"


def test_out_below_a_file_is_refused(small_pass, tmp_path, capsys, no_solving):
    f = tmp_path / "file"
    f.write_text("x")
    assert _smooth(small_pass / "measurements.csv", f / "sub") == 2
    _refused(capsys, "--out", str(f))


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_out_where_nothing_can_be_created_is_refused(small_pass, capsys, no_solving):
    assert _smooth(small_pass / "measurements.csv", "/proc/fgnav-no-such/out") == 2
    _refused(capsys, "--out", "/proc")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only directory")
def test_out_a_read_only_directory_is_refused(small_pass, tmp_path, capsys, no_solving):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    try:
        assert _smooth(small_pass / "measurements.csv", d) == 2
    finally:
        d.chmod(0o755)
    _refused(capsys, "--out", str(d))


def test_a_directory_that_refuses_files_is_refused(small_pass, tmp_path, capsys, no_solving,
                                                  monkeypatch):
    """What a read-only directory does for a user who is not root (root writes anyway): the
    probe file cannot be created."""
    import tempfile

    import fgnav.io.outputs

    ro = tmp_path / "ro"
    ro.mkdir()
    real = tempfile.mkstemp

    def refuse(*a, dir=None, **k):
        if dir is not None and os.path.abspath(dir) == str(ro):
            raise PermissionError(13, "Permission denied")
        return real(*a, dir=dir, **k)

    monkeypatch.setattr(fgnav.io.outputs.tempfile, "mkstemp", refuse)
    for extra, option in ((["--out", str(ro)], "--out"),
                          (["--out", str(tmp_path / "o"), "--method", "isam2", "--checkpoint",
                            str(ro / "c.npz")], "--checkpoint"),
                          (["--out", str(tmp_path / "o"), "--rerun", str(ro / "p.rrd")], "--rerun")):
        assert main(["smooth", str(small_pass / "measurements.csv"), "--quiet", *extra]) == 2
        _refused(capsys, option, str(ro), "Permission denied")


@pytest.mark.parametrize("extra,option", [
    (["--method", "isam2", "--checkpoint", "{tmp}/missing/c.npz"], "--checkpoint"),
    (["--method", "isam2", "--checkpoint", "{tmp}"], "--checkpoint"),
    (["--method", "isam2", "--checkpoint", "{tmp}/none.npz", "--resume"], "--checkpoint"),
    (["--method", "isam2", "--checkpoint", "/proc/fgnav-c.npz"], "--checkpoint"),
    (["--rerun", "{tmp}/missing/pass.rrd"], "--rerun"),
    (["--rerun", "{tmp}"], "--rerun"),
    (["--rerun", "/proc/pass.rrd"], "--rerun"),
    (["--truth", "{tmp}/no-truth.oem"], "--truth"),
    (["--truth", "{tmp}/garbage.oem"], "garbage.oem"),
    (["--truth", "{tmp}/short.oem"], "--truth"),
], ids=["checkpoint in a missing folder", "checkpoint a directory", "resume without the file",
        "checkpoint unwritable", "rerun in a missing folder", "rerun a directory",
        "rerun unwritable", "truth missing", "truth not an OEM", "truth not covering"])
def test_an_unusable_path_is_refused_before_solving(small_pass, tmp_path, capsys, no_solving,
                                                    extra, option):
    (tmp_path / "garbage.oem").write_bytes(b"\x00\xff garbage\n")
    oem = read_oem(small_pass / "truth.oem")
    from fgnav.io.oem import write_oem
    write_oem(tmp_path / "short.oem", oem.epoch0, oem.t_s[:10], oem.x_eci[:10], None)
    extra = [a.replace("{tmp}", str(tmp_path)) for a in extra]
    assert _smooth(small_pass / "measurements.csv", tmp_path / "out", *extra) == 2
    _refused(capsys, option)
    assert not (tmp_path / "out").exists()


def test_rerun_inside_the_output_directory_is_accepted(small_pass, tmp_path):
    out = tmp_path / "new" / "result"
    assert _smooth(small_pass / "measurements.csv", out, "--rerun", str(out / "pass.rrd")) == 0
    assert (out / "pass.rrd").is_file()


# ---- one set of outputs ----------------------------------------------------------------------

def test_a_batch_run_after_isam2_and_a_report_leaves_only_its_own_files(small_pass, tmp_path):
    out = tmp_path / "result"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    (out / "my_plot.png").write_bytes(b"the user's")
    log = small_pass / "measurements.csv"
    assert _smooth(log, out, "--method", "isam2", "--truth", str(small_pass / "truth.oem")) == 0
    assert main(["report", str(out)]) == 0
    written = {p.name for p in out.iterdir()}
    assert {"online.oem", "latency.csv", "latency.png", "errors_rtn.png", "report.md"} <= written
    assert _smooth(log, out, "--method", "batch") == 0
    assert {p.name for p in out.iterdir()} == {
        "trajectory.oem", "summary.json", "residuals.csv", ".fgnav-outputs.json",
        "notes.txt", "my_plot.png"}
    assert (out / "notes.txt").read_text() == "the user's"
    # a report of the batch solution, without truth: its own plots only
    assert main(["report", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert "sigma_rtn.png" in names and "latency.png" not in names and "errors_rtn.png" not in names


def test_a_directory_from_before_the_manifest_loses_our_stale_files_only(small_pass, tmp_path):
    out = tmp_path / "result"
    log = small_pass / "measurements.csv"
    assert _smooth(log, out, "--method", "isam2") == 0
    (out / ".fgnav-outputs.json").unlink()           # as written by an older fgnav
    (out / "report.md").write_text("# my own report\n")  # not ours: kept
    assert _smooth(log, out, "--method", "ekf") == 0
    names = {p.name for p in out.iterdir()}
    assert "online.oem" not in names and "report.md" in names


def test_staging_folders_left_by_a_killed_run_are_removed(small_pass, tmp_path):
    out = tmp_path / "result"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / f".fgnav-staging-{dead.pid}-abc").mkdir()
    (out / f".fgnav-staging-{dead.pid}-abc" / "trajectory.oem").write_text("half")
    (out / ".fgnav-staging-old").mkdir()                       # an older fgnav's name
    alive = out / f".fgnav-staging-{os.getppid()}-xyz"         # a run still writing
    alive.mkdir()
    assert _smooth(small_pass / "measurements.csv", out) == 0
    left = sorted(p.name for p in out.iterdir() if p.name.startswith(".fgnav-staging-"))
    assert left == [alive.name]


# ---- checkpoints -------------------------------------------------------------------------------

def _npz(**arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _arrays(ck):
    with np.load(ck, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _with(ck, **changes):
    a = _arrays(ck)
    for k, v in changes.items():
        if v is None:
            a.pop(k)
        else:
            a[k] = v
    return _npz(**a)


def _flip_middle_byte(data):
    b = bytearray(data)
    b[len(b) // 2] ^= 0xFF
    return bytes(b)


CORRUPTIONS = {
    "zero bytes": lambda ck, d: b"",
    "truncated to half": lambda ck, d: d[: len(d) // 2],
    "truncated to 100 bytes": lambda ck, d: d[:100],
    "last byte missing": lambda ck, d: d[:-1],
    "random bytes": lambda ck, d: np.random.default_rng(0).bytes(4096),
    "random bytes after a zip signature": lambda ck, d: b"PK\x03\x04" + np.random.default_rng(1).bytes(4096),
    "a byte flipped": lambda ck, d: _flip_middle_byte(d),
    "a pickle": lambda ck, d: pickle.dumps(_arrays(ck)),
    "a bare .npy": lambda ck, d: (lambda b: (np.save(b, np.zeros(3)), b.getvalue())[1])(io.BytesIO()),
    "an empty zip": lambda ck, d: (lambda b: (zipfile.ZipFile(b, "w").close(), b.getvalue())[1])(io.BytesIO()),
    "object array (pickled inside)": lambda ck, d: _with(ck, x_est=np.array([{"a": 1}], dtype=object)),
    "k_next missing": lambda ck, d: _with(ck, k_next=None),
    "fingerprint missing": lambda ck, d: _with(ck, fingerprint=None),
    "an extra array": lambda ck, d: _with(ck, extra=np.zeros(2)),
    "x_est wrong shape": lambda ck, d: _with(ck, x_est=_arrays(ck)["x_est"][:, :3]),
    "online_P wrong shape": lambda ck, d: _with(ck, online_P=_arrays(ck)["online_P"][:-1]),
    "x_est as integers": lambda ck, d: _with(ck, x_est=_arrays(ck)["x_est"].astype(np.int64)),
    "x_est as strings": lambda ck, d: _with(ck, x_est=_arrays(ck)["x_est"].astype(str)),
    "NaN state": lambda ck, d: _with(ck, x_est=np.where(np.arange(6) == 2, np.nan, _arrays(ck)["x_est"])),
    "infinite covariance": lambda ck, d: _with(ck, online_P=_arrays(ck)["online_P"] + np.inf),
    "k_next zero": lambda ck, d: _with(ck, k_next=np.array(0)),
    "k_next negative": lambda ck, d: _with(ck, k_next=np.array(-5)),
    "k_next beyond the log": lambda ck, d: _with(ck, k_next=np.array(10_000)),
    "k_next a float": lambda ck, d: _with(ck, k_next=np.array(50.0)),
    "k_next an array": lambda ck, d: _with(ck, k_next=np.arange(3)),
    "fingerprint a number": lambda ck, d: _with(ck, fingerprint=np.array(7)),
    "another format": lambda ck, d: _with(ck, format=np.array("fgnav isam2 checkpoint 1")),
    "rejected rows wrong length": lambda ck, d: _with(
        ck, **{"rejected_rows/earth_direction": np.zeros(3, bool)}),
}


def test_at_least_fifteen_corruptions_are_listed():
    assert len(CORRUPTIONS) >= 15


@pytest.mark.parametrize("name", list(CORRUPTIONS))
def test_a_corrupted_checkpoint_is_refused_without_a_traceback(small_pass, checkpoint, tmp_path,
                                                               capsys, monkeypatch, name):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(CORRUPTIONS[name](checkpoint, checkpoint.read_bytes()))
    capsys.readouterr()

    def forbidden(*a, **k):
        raise AssertionError("the epoch loop started")

    monkeypatch.setattr(fgnav.solvers.incremental, "_warm_up", forbidden)
    rc = _smooth(small_pass / "measurements.csv", tmp_path / "out", "--method", "isam2",
                 "--checkpoint", str(bad), "--resume")
    assert rc == 2
    _refused(capsys, str(bad), "checkpoint")


def test_a_checkpoint_of_another_log_with_the_same_epochs_is_refused(small_pass, checkpoint,
                                                                     tmp_path, capsys):
    log = tmp_path / "other.csv"   # same epochs and sigmas, one direction 1e-5 rad away

    def turned(f):
        u = np.array([float(v) for v in f[2:5]]) + np.array([1e-5, 0.0, 0.0])
        return f[:2] + [repr(float(v)) for v in u / np.linalg.norm(u)] + f[5:]

    _edit_row(small_pass / "measurements.csv", log, "earth_direction", turned)
    rc = _smooth(log, tmp_path / "out", "--method", "isam2", "--checkpoint", str(checkpoint),
                 "--resume")
    assert rc == 2
    _refused(capsys, str(checkpoint), "another log")


def test_a_checkpoint_made_with_other_options_is_refused(small_pass, checkpoint, tmp_path, capsys):
    rc = _smooth(small_pass / "measurements.csv", tmp_path / "out", "--method", "isam2",
                 "--checkpoint", str(checkpoint), "--resume", "--process-noise", "1e-10")
    assert rc == 2
    _refused(capsys, "other options")


def test_resume_after_an_interruption_equals_the_uninterrupted_run(small_pass, tmp_path,
                                                                   monkeypatch):
    """Interrupted at epoch 70 of 121 (checkpoints every 25): the resumed trajectory equals
    the uninterrupted one to 1e-5 sigma, the tolerance the README states (it was up to
    2e-3 sigma before the final Gauss-Newton polish)."""
    import fgnav.commands.smooth as smooth_cmd

    log = small_pass / "measurements.csv"
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    ck = tmp_path / "run.npz"
    assert _smooth(log, whole, "--method", "isam2", "--gate", "0.9999") == 0
    original = smooth_cmd.ProgressCallback.__call__
    calls = []

    def killed(self, *state):
        calls.append(state)
        if len(calls) == 70:
            raise KeyboardInterrupt
        return original(self, *state)

    monkeypatch.setattr(smooth_cmd.ProgressCallback, "__call__", killed)
    args = ["--method", "isam2", "--gate", "0.9999", "--checkpoint", str(ck),
            "--checkpoint-every", "25"]
    assert _smooth(log, cut, *args) == 130
    assert not cut.exists() and ck.is_file()
    monkeypatch.setattr(smooth_cmd.ProgressCallback, "__call__", original)
    assert _smooth(log, cut, *args, "--resume") == 0
    a, b = read_oem(whole / "trajectory.oem"), read_oem(cut / "trajectory.oem")
    sigma = np.sqrt(np.diagonal(a.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(b.x_eci - a.x_eci) / sigma) < 1e-5
    sa = json.loads((whole / "summary.json").read_text())
    sb = json.loads((cut / "summary.json").read_text())
    assert sa.get("rejected") == sb.get("rejected")


# ---- chi-square of the online methods ---------------------------------------------------------

@pytest.mark.parametrize("method", ["isam2", "fixed-lag"])
def test_the_chi2_of_an_online_method_is_split_and_matches_its_residuals(small_pass, tmp_path,
                                                                          method):
    out = tmp_path / "out"
    assert _smooth(small_pass / "measurements.csv", out, "--method", method) == 0
    s = json.loads((out / "summary.json").read_text())
    rows = (out / "residuals.csv").read_text().splitlines()[1:]
    sum_sq = sum(float(r.split(",")[3]) ** 2 for r in rows)
    assert s["chi2_measurements"] == pytest.approx(sum_sq, rel=1e-4)  # residuals at 6 digits
    # fixed-lag: states from different windows, so each step's motion residual is taken
    # inside the window estimate its first state was read from
    assert s["chi2"] == pytest.approx(s["chi2_measurements"] + s["chi2_motion"], rel=1e-12)


def test_two_epochs_a_millisecond_apart_are_smoothed_by_batch(small_pass, tmp_path):
    """The rank check compares a state's pivots with its own: a 1 ms step (motion pivots of
    1e11) no longer makes the last state look unobservable."""
    lines = (small_pass / "measurements.csv").read_text().splitlines()
    i = next(j for j, line in enumerate(lines) if line.startswith("2025-03-01T01:00:00.000000Z,earth"))
    lines.insert(i + 1, lines[i].replace("01:00:00.000000Z", "01:00:00.001000Z"))
    log = tmp_path / "ms.csv"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert _smooth(log, out, "--truth", str(small_pass / "truth.oem")) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] and s["epochs"] == 122
    assert s["position_rms_m"] < 3 * s["crb_position_rms_m"] and s["nees_mean"] < 12


def test_a_checkpoint_inside_a_new_output_directory_is_accepted(small_pass, tmp_path):
    out = tmp_path / "new" / "result"
    ck = out / "run.npz"
    assert _smooth(small_pass / "measurements.csv", out, "--method", "isam2", "--checkpoint",
                   str(ck), "--checkpoint-every", "50") == 0
    assert ck.is_file() and (out / "trajectory.oem").is_file()
    assert _smooth(small_pass / "measurements.csv", out, "--method", "isam2", "--checkpoint",
                   str(ck), "--resume") == 0
    assert ck.is_file()  # not one of the outputs a later run removes
