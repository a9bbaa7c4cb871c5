"""Nothing lost: outputs replaced as a set or not at all; iSAM2 checkpoint/resume."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.measurements import build_pass
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.incremental import smooth_incremental


def _snapshot(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


@pytest.fixture
def small_pass(tmp_path):
    d = tmp_path / "pass"
    assert main(["simulate", "gto-transfer", "--out", str(d), "--step-s", "120", "--quiet"]) == 0
    return d


def test_an_interrupt_while_writing_leaves_the_previous_outputs_untouched(tmp_path, small_pass, monkeypatch):
    out = tmp_path / "result"
    assert main(["smooth", str(small_pass / "measurements.csv"), "--out", str(out), "--quiet"]) == 0
    before = _snapshot(out)
    import fgnav.results

    def interrupted(*a, **k):  # the last file of the set: everything else is already staged
        raise KeyboardInterrupt

    # patched where write_outputs looks it up (fgnav.results imports it at module level)
    monkeypatch.setattr(fgnav.results, "write_summary", interrupted)
    rc = main(["smooth", str(small_pass / "measurements.csv"), "--out", str(out), "--quiet",
               "--method", "ekf"])
    assert rc == 130
    assert _snapshot(out) == before  # same files, same bytes, no staging left behind


def test_killing_fgnav_smooth_mid_run_leaves_the_previous_output_untouched(tmp_path, small_pass):
    out = tmp_path / "result"
    assert main(["smooth", str(small_pass / "measurements.csv"), "--out", str(out), "--quiet"]) == 0
    before = _snapshot(out)
    big = tmp_path / "big"
    assert main(["simulate", "gto-transfer", "--out", str(big), "--step-s", "1", "--quiet"]) == 0
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "smooth", str(big / "measurements.csv"),
                             "--out", str(out), "--method", "isam2", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(3.0)  # well inside the 14,400-epoch iSAM2 run
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert _snapshot(out) == before


def test_isam2_resumes_from_a_checkpoint_with_the_same_answer(tmp_path):
    scn = load_scenario("gto-transfer").with_options(step_s=60.0, duration_h=2.0)
    p = build_pass(simulate_pass(scn, 11).log)
    opt = SmootherOptions(gate_probability=0.9999)
    whole = smooth_incremental(p, opt)
    ckpt = str(tmp_path / "run.ckpt.npz")

    def stop_at_70(k):
        if k == 70:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        smooth_incremental(p, opt, progress=stop_at_70, checkpoint=ckpt, checkpoint_every=25)
    assert os.path.exists(ckpt)
    resumed = smooth_incremental(p, opt, checkpoint=ckpt, checkpoint_every=25, resume=True)
    sig = np.sqrt(np.trace(whole.P_eci[:, :3, :3], axis1=1, axis2=2))
    d = np.linalg.norm(resumed.x_eci[:, :3] - whole.x_eci[:, :3], axis=1)
    assert np.all(d < 1e-5 * sig)  # the tolerance the README states for --resume
    np.testing.assert_allclose(resumed.online_x_eci[:50], whole.online_x_eci[:50])  # restored history
    assert resumed.extras.get("rejected") == whole.extras.get("rejected")


def test_a_checkpoint_of_another_log_is_refused(tmp_path):
    from fgnav.errors import UserError

    scn = load_scenario("gto-transfer").with_options(step_s=120.0, duration_h=1.0)
    ckpt = str(tmp_path / "a.npz")
    smooth_incremental(build_pass(simulate_pass(scn, 1).log), checkpoint=ckpt, checkpoint_every=10)
    other = build_pass(simulate_pass(scn.with_options(step_s=60.0), 1).log)
    with pytest.raises(UserError, match="another log"):
        smooth_incremental(other, checkpoint=ckpt, resume=True)
