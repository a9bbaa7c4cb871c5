"""docs/api.md's worked example runs as written, and the API it shows behaves as documented."""

import re
from pathlib import Path

import numpy as np
import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def _python_blocks(text):
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_worked_example_runs(capsys):
    blocks = _python_blocks(DOC.read_text(encoding="utf-8"))
    assert len(blocks) == 1, "docs/api.md: expected one worked example"
    namespace = {"__name__": "__api_doc__"}
    exec(compile(blocks[0], str(DOC), "exec"), namespace)
    out = capsys.readouterr().out
    result, sim = namespace["result"], namespace["sim"]
    # The example's figures are real: the batch solution against the simulation's truth.
    s = result.summary
    assert s["method"] == "batch" and s["epochs"] == len(result.solution.t_s)
    x_true = sim.x_true[np.searchsorted(sim.t_s, result.solution.t_s)]
    err = np.linalg.norm(result.solution.x_eci[:, :3] - x_true[:, :3], axis=1)
    assert s["position_rms_m"] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-9)
    assert s["nees_mean"] < 20.0 and s["integrity"]["status"] == "ok"
    work = namespace["work"]
    for name in ("trajectory.oem", "summary.json", "residuals.csv"):
        assert (work / "result" / name).is_file(), name
    assert (work / "errors.png").stat().st_size > 10_000
    assert "errors_rtn" in namespace["rep"]["images"]
    assert "batch: position RMS" in out and "ekf:" in out


def test_api_matches_the_cli(tmp_path):
    """fg.smooth on a file gives the trajectory `fgnav smooth` writes (same library)."""
    import fgnav.api as fg
    from fgnav.cli import main
    from fgnav.io.oem import read_oem

    assert main(["simulate", "gto-transfer", "--out", str(tmp_path / "pass"), "--duration-h",
                 "0.5", "--step-s", "60", "--quiet"]) == 0
    log = tmp_path / "pass" / "measurements.csv"
    assert main(["smooth", str(log), "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    res = fg.smooth(fg.read_log(log), truth=tmp_path / "pass" / "truth.oem")
    fg.write_outputs(res, tmp_path / "api")
    a, b = read_oem(tmp_path / "cli" / "trajectory.oem"), read_oem(tmp_path / "api" / "trajectory.oem")
    np.testing.assert_array_equal(a.x_eci, b.x_eci)
    assert res.summary["truth_path"].endswith("truth.oem") and "nees_mean" in res.summary


def test_api_errors_are_user_errors():
    import fgnav.api as fg
    from fgnav.errors import UserError

    with pytest.raises(UserError, match="method: expected one of batch"):
        fg.smooth("nowhere.csv", method="kalman")
    with pytest.raises(UserError, match="nowhere.csv: no such file"):
        fg.read_log("nowhere.csv")
    with pytest.raises(UserError, match="gravity: expected one of"):
        fg.simulate("gto-transfer", gravity="flat")
    with pytest.raises(UserError, match="not both"):
        fg.smooth("nowhere.csv", opts=fg.options(), q_m2_s3=1e-10)


def test_import_is_light():
    """`import fgnav.api` loads neither NumPy's solvers nor GTSAM, numba or matplotlib."""
    import subprocess
    import sys

    code = ("import sys, fgnav.api; heavy = [m for m in ('gtsam', 'numba', 'matplotlib', "
            "'scipy', 'fgnav.pipeline') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1], check=True).stdout
    assert out.strip() == "[]"
