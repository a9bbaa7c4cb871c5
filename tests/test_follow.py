"""``fgnav follow``: live online navigation from a stream (issue 30), end to end.

The final trajectory of a live run is the batch chain solver over every row received, so it
must equal ``fgnav smooth LOG`` (batch) within 1e-3 of its sigma, from stdin, from a file
grown while it runs, with malformed lines in the stream and after a kill -9 and --resume.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fgnav.cli import main
from fgnav.io.oem import read_oem
from fgnav.online.stream import StreamReader
from fgnav.pipeline import smooth_file

ROOT = Path(__file__).resolve().parents[1]
OUTPUTS = ("trajectory.oem", "summary.json", "residuals.csv", "online.oem", "latency.csv")


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


@pytest.fixture(scope="module")
def log_1h(tmp_path_factory):
    d = tmp_path_factory.mktemp("gto1h")
    assert main(["simulate", "gto-transfer", "--out", str(d), "--duration-h", "1", "--seed", "3",
                 "--quiet"]) == 0
    return d / "measurements.csv"


@pytest.fixture(scope="module")
def batch_1h(log_1h):
    return smooth_file(log_1h, "batch")[0].solution


@pytest.fixture(scope="module")
def log_20min(tmp_path_factory):
    d = tmp_path_factory.mktemp("gto20")
    assert main(["simulate", "gto-transfer", "--out", str(d), "--duration-h", "0.34",
                 "--seed", "4", "--quiet"]) == 0
    return d / "measurements.csv"


def _assert_equals_batch(out: Path, ref, tol_sigma=1e-3):
    oem = read_oem(out / "trajectory.oem")
    assert oem.x_eci.shape == ref.x_eci.shape
    sig = np.sqrt(np.einsum("kii->ki", ref.P_eci))
    assert np.max(np.abs(oem.x_eci - ref.x_eci) / sig) < tol_sigma


def _epochs(jsonl: str) -> list[dict]:
    return [e for e in map(json.loads, jsonl.splitlines()) if e["event"] == "epoch"]


def _follow(args, **kw):
    return subprocess.run([sys.executable, "-m", "fgnav", "follow", *args], env=_env(),
                          capture_output=True, timeout=600, **kw)


def test_stdin_stream_one_line_per_epoch_and_batch_history(log_1h, batch_1h, tmp_path):
    out = tmp_path / "live"
    with open(log_1h, "rb") as f:
        r = _follow(["-", "--out", str(out)], stdin=f)
    assert r.returncode == 0, r.stderr.decode()
    ep = _epochs(r.stdout.decode())
    assert len(ep) == len(batch_1h.t_s) == 361
    assert [e["t_s"] for e in ep] == pytest.approx(list(batch_1h.t_s))
    for key in ("epoch", "t_s", "r_eci_m", "v_eci_mps", "sigma_r_m", "sigma_v_mps", "verdict",
                "latency_s"):
        assert key in ep[0]
    assert all(e["verdict"] in ("ok", "suspect", "failed") for e in ep)
    # the online state is a filter's: near truth within its own sigma at the end
    truth = read_oem(log_1h.parent / "truth.oem")
    err = np.linalg.norm(np.array(ep[-1]["r_eci_m"]) - truth.x_eci[-1, :3])
    assert err < 4 * np.linalg.norm(ep[-1]["sigma_r_m"])
    _assert_equals_batch(out, batch_1h)
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    online = read_oem(out / "online.oem")   # one segment per block: a valid OEM
    assert len(online.t_s) == 361 and np.all(np.diff(online.t_s) > 0)
    assert online.x_eci[-1] == pytest.approx(ep[-1]["r_eci_m"] + ep[-1]["v_eci_mps"], abs=1e-5)
    lat = (out / "latency.csv").read_text().splitlines()
    assert lat[0] == "t_s,latency_s,cpu_s" and len(lat) == 362
    s = json.loads((out / "summary.json").read_text())
    assert s["integrity"]["status"] in ("ok", "suspect", "failed")
    assert s["online"]["epochs"] == 361 and s["online"]["stream"]["rows"] == 363


def test_file_grown_while_it_runs(log_1h, batch_1h, tmp_path):
    lines = log_1h.read_bytes().splitlines(keepends=True)
    grow = tmp_path / "growing.csv"
    grow.write_bytes(b"".join(lines[:40]))
    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "follow", str(grow), "--out",
                             str(out), "--idle-timeout", "3", "--method", "fixed-lag"],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def writer():
        with open(grow, "ab") as f:
            for i in range(40, len(lines), 25):
                time.sleep(0.05)
                chunk = b"".join(lines[i:i + 25])
                half = len(chunk) // 2   # a line written in two pieces: read whole
                f.write(chunk[:half])
                f.flush()
                time.sleep(0.02)
                f.write(chunk[half:])
                f.flush()

    t = threading.Thread(target=writer)
    t.start()
    stdout, stderr = proc.communicate(timeout=600)
    t.join()
    assert proc.returncode == 0, stderr.decode()
    assert len(_epochs(stdout.decode())) == 361
    assert b"skipped" not in stderr
    _assert_equals_batch(out, batch_1h)


def test_malformed_lines_reported_by_line(log_1h, batch_1h, tmp_path):
    lines = log_1h.read_bytes().splitlines(keepends=True)
    bad = {50: b"2025-03-01T00:07:00Z,earth_direction,0.1,0.2\n",
           120: b"this is not a row\n",
           200: b"2025-03-01T00:20:00Z,earth_direction,1,0,0,-1\n",
           260: b"\xff\xfe garbage\n"}
    stream, lineno = [], {}
    for i, line in enumerate(lines):
        if i in bad:
            stream.append(bad[i])
            lineno[i] = len(stream)
        stream.append(line)
    path = tmp_path / "with_garbage.csv"
    path.write_bytes(b"".join(stream))
    out = tmp_path / "live"
    r = _follow([str(path), "--out", str(out), "--idle-timeout", "0.2"])
    assert r.returncode == 0, r.stderr.decode()
    err = r.stderr.decode()
    for i, n in lineno.items():
        assert f"with_garbage.csv, line {n}," in err or f"with_garbage.csv, line {n}:" in err, \
            (n, err)
    s = json.loads((out / "summary.json").read_text())
    assert sum(s["online"]["stream"]["skipped"].values()) == len(bad)
    assert len(_epochs(r.stdout.decode())) == 361
    _assert_equals_batch(out, batch_1h)


@pytest.mark.parametrize("method", ["ekf", "isam2"])
def test_kill9_then_resume_same_answer(log_1h, tmp_path, method):
    full = tmp_path / "full"
    with open(log_1h, "rb") as f:
        r = _follow(["-", "--out", str(full), "--method", method], stdin=f)
    assert r.returncode == 0, r.stderr.decode()
    lines = log_1h.read_bytes().splitlines(keepends=True)
    out, ck = tmp_path / "live", tmp_path / "ck.npz"
    args = ["-", "--out", str(out), "--method", method, "--checkpoint", str(ck),
            "--checkpoint-every", "50"]
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "follow", *args], env=_env(),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    proc.stdin.write(b"".join(lines[:200]))
    proc.stdin.flush()
    seen = 0
    while seen < 170:   # epochs past the third checkpoint, then a kill in mid-run
        line = proc.stdout.readline()
        assert line, "follow ended early"
        seen += b'"epoch"' in line
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    for pipe in (proc.stdin, proc.stdout):
        try:
            pipe.close()
        except BrokenPipeError:
            pass
    assert ck.exists()
    with open(log_1h, "rb") as f:
        r = _follow(args + ["--resume"], stdin=f)
    assert r.returncode == 0, r.stderr.decode()
    resumed = _epochs(r.stdout.decode())
    assert 0 < len(resumed) < 361 and resumed[0]["t_s"] == 1500.0   # after 150 epochs
    a, b = read_oem(full / "trajectory.oem"), read_oem(out / "trajectory.oem")
    assert np.array_equal(a.x_eci, b.x_eci)
    online = read_oem(out / "online.oem")
    assert len(online.t_s) == 361 and len(np.unique(online.t_s)) == 361
    ref = read_oem(full / "online.oem")
    # before the checkpoint: the killed run's own states; after it, the EKF continues from
    # the saved state exactly, the iSAM2 window restarts from it as its prior
    assert np.allclose(online.x_eci[:150], ref.x_eci[:150], rtol=0, atol=1e-3)
    if method == "ekf":
        assert np.allclose(online.x_eci, ref.x_eci, rtol=0, atol=1e-3)
    else:
        sig = np.sqrt(np.einsum("kii->ki", ref.P_eci))
        assert np.max(np.abs(online.x_eci - ref.x_eci) / sig) < 0.5
    assert len((out / "latency.csv").read_text().splitlines()) == 362


def test_reader_late_duplicate_torn():
    rd = StreamReader("s", reorder_window_s=10.0, report=lambda m: None)
    rd.feed(b"epoch,kind,x,y,z,sigma\n")
    row = "2025-03-01T00:00:{:02d}Z,earth_direction,1,0,0,1e-4\n"
    assert rd.feed(row.format(0).encode()) == []
    ev = rd.feed(row.format(5).encode())
    assert [(e[0], len(e[2])) for e in ev] == [("epoch", 1)]
    assert rd.feed(row.format(5).encode()) == []                     # duplicate
    assert rd.feed(row.format(30).encode())[0][0] == "epoch"         # completes :05
    late = rd.feed(b"2025-03-01T00:00:25Z,earth_direction,0,1,0,1e-4\n")
    assert late == []        # not yet completed: pending, joins its epoch
    assert rd.feed(b"2025-03-01T00:00:01Z,earth_direction,0,1,0,1e-4\n") == []   # too late
    assert rd.feed(b"2025-03-01T00:00:40Z,earth_direction,0,1,0,1e-4\n")[0][1] > 0
    rd.feed(b"2025-03-01T00:00:50Z,earth_dir")                        # torn last line
    c = rd.counts
    assert (c.duplicates, c.late_dropped, c.torn_last_line) == (1, 1, True)
    assert c.skipped == {"truncated": 1}
    assert [e[0] for e in rd.end()] == ["epoch"]


def test_navigator_python_api(log_20min):
    from fgnav.io.log_csv import read_log
    from fgnav.online import Navigator
    from fgnav.solvers.options import SmootherOptions

    log = read_log(log_20min)
    nav = Navigator(SmootherOptions(), method="fixed-lag", lag_s=120.0)
    half = log.t_s <= 600.0
    from fgnav.io.log_csv import log_from_arrays
    state = None
    for mask in (half, ~half):
        part = log_from_arrays(log.epoch0, log.t_s[mask], log.kind[mask], log.xyz[mask],
                               log.sigma[mask])
        state = nav.add(part)
    assert state.t_s == log.t_s[-1] and state.P.shape == (6, 6) and state.verdict == "ok"
    sol = nav.smoothed()
    ref = smooth_file(log_20min, "batch")[0].solution
    sig = np.sqrt(np.einsum("kii->ki", ref.P_eci))
    assert np.max(np.abs(sol.x_eci - ref.x_eci) / sig) < 1e-3


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutated_streams_complete_outputs(log_20min, tmp_path, data, capsys):
    lines = log_20min.read_bytes().splitlines(keepends=True)
    head, rows = lines[:4], lines[4:]   # comment, header, prior rows
    n = len(rows)
    for _ in range(data.draw(st.integers(0, 12), label="mutations")):
        i = data.draw(st.integers(0, len(rows) - 1))
        what = data.draw(st.sampled_from(["drop", "dup", "swap", "garbage", "cut"]))
        if what == "drop" and len(rows) > n * 0.8:
            rows.pop(i)
        elif what == "dup":
            rows.insert(i, rows[i])
        elif what == "swap" and i + 1 < len(rows):
            rows[i], rows[i + 1] = rows[i + 1], rows[i]
        elif what == "garbage":
            rows.insert(i, data.draw(st.binary(max_size=60)).replace(b"\n", b"") + b"\n")
        elif what == "cut":
            rows[i] = rows[i][:data.draw(st.integers(0, len(rows[i]) - 1))] + b"\n"
    if data.draw(st.booleans(), label="torn end"):
        rows[-1] = rows[-1][:len(rows[-1]) // 2]
    path = tmp_path / "mutated.csv"
    path.write_bytes(b"".join(head + rows))
    out = tmp_path / f"live{data.draw(st.integers(0, 10**9))}"
    rc = main(["follow", str(path), "--out", str(out), "--idle-timeout", "0.05", "--quiet",
               "--reorder-window-s", "30", "--method",
               data.draw(st.sampled_from(["isam2", "ekf"]))])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "Traceback" not in captured.err
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert json.loads(captured.out.splitlines()[-1])["event"] == "end"


def test_integrity_change_is_an_event_and_a_line(log_20min, tmp_path, capsys):
    """Directions biased by 0.05 deg (5 sigma) from the 10th minute: the live verdict leaves
    ok, printed once as a JSON event on stdout and a line on stderr."""
    from fgnav.io.log_csv import read_log, write_log
    from factors.geometry import so3_exp

    log = read_log(log_20min)
    late = (log.kind == "earth_direction") & (log.t_s >= 600.0)
    R = so3_exp(np.array([0.0, 0.0, np.radians(0.05)]))
    log.xyz[late] = log.xyz[late] @ R.T
    path = tmp_path / "biased.csv"
    write_log(path, log)
    rc = main(["follow", str(path), "--out", str(tmp_path / "live"), "--idle-timeout", "0",
               "--integrity-window-s", "120", "--method", "ekf"])
    captured = capsys.readouterr()
    assert rc == 0
    events = [json.loads(x) for x in captured.out.splitlines()]
    changes = [e for e in events if e["event"] == "integrity"]
    assert changes and changes[0]["from"] == "ok" and changes[0]["to"] in ("suspect", "failed")
    first_bad = next(e for e in events if e["event"] == "epoch" and e["verdict"] != "ok")
    assert first_bad["t_s"] >= 600.0
    assert captured.err.count("fgnav: integrity ") == len(changes)
    assert "window" in changes[0] and "all" in changes[0]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_ends_the_input_and_writes_the_final_set(log_20min, tmp_path, sig):
    """A file followed without an idle timeout runs until a signal: SIGTERM or SIGINT ends
    the input, and the final set is written for the rows received."""
    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "follow", str(log_20min), "--out",
                             str(out)], env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    n = 0
    while n < 100:
        n += b'"epoch"' in proc.stdout.readline()
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr.decode()
    assert json.loads(stdout.splitlines()[-1])["event"] == "end"
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert len(read_oem(out / "trajectory.oem").t_s) == len(read_oem(out / "online.oem").t_s)


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_rerun_serve_streams_the_recording(log_20min, tmp_path):
    """--rerun-serve: the web viewer answers over HTTP while it runs, and a Rerun client
    connected to the served stream receives the online state per epoch and, at the end, the
    smoothed history (saved with ``rerun --save``, read back with ``rerun rrd stats``).
    (No headless browser on the test machines: the viewer's page is fetched, not drawn.)"""
    import shutil
    import urllib.request

    rerun = shutil.which("rerun", path=os.path.dirname(sys.executable)) or shutil.which("rerun")
    if rerun is None:
        pytest.skip("the rerun command line is not installed")
    web, grpc = _free_port(), _free_port()
    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "follow", str(log_20min), "--out",
                             str(out), "--idle-timeout", "6", "--quiet", "--rerun-serve",
                             "--rerun-web-port", str(web), "--rerun-grpc-port", str(grpc)],
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    line = proc.stderr.readline().decode()
    assert "Rerun web viewer: http://localhost:" in line, line
    page = urllib.request.urlopen(f"http://localhost:{web}/", timeout=30).read()
    assert len(page) > 1000
    saved = tmp_path / "served.rrd"
    client = subprocess.run([rerun, "--save", str(saved), f"rerun+http://127.0.0.1:{grpc}/proxy"],
                            capture_output=True, timeout=300)
    proc.wait(timeout=300)
    proc.stderr.close()
    assert proc.returncode == 0 and client.returncode == 0, client.stderr.decode()[-500:]
    stats = subprocess.run([rerun, "rrd", "stats", str(saved)], capture_output=True, text=True,
                           timeout=120).stdout
    for entity in ("/world/online/state", "/online/sigma_position_m",
                   "/world/estimate/trajectory", "/residuals/earth_direction"):
        assert entity in stats, entity
    for name in OUTPUTS:
        assert (out / name).is_file(), name
