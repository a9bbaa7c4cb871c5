"""``fgnav check LOG``: validation without solving (fgnav.commands.check)."""

from __future__ import annotations

import json
import subprocess
import sys

from fgnav.cli import main

LOG = """\
epoch,kind,x,y,z,sigma
2024-03-01T00:00:00Z,prior_position,7000000,0,0,1000
2024-03-01T00:00:00Z,prior_velocity,0,7546,0,1
2024-03-01T00:00:00Z,earth_direction,-1,0,0,1e-4
2024-03-01T00:01:00Z,earth_direction,0,-1,0,1e-4
2024-03-01T00:00:30Z,limb_radius,1.1,6378137,,1e-4
"""

TDM = """\
CCSDS_TDM_VERS = 2.0
CREATION_DATE = 2024-03-02T00:00:00
ORIGINATOR = TEST
META_START
TIME_SYSTEM = UTC
PARTICIPANT_1 = SAT
PARTICIPANT_2 = EARTH
PATH = 2,1
ANGLE_TYPE = RADEC
REFERENCE_FRAME = EME2000
META_STOP
DATA_START
ANGLE_1 = 2024-03-01T00:00:00 10.0
ANGLE_2 = 2024-03-01T00:00:00 20.0
DATA_STOP
"""


def test_valid_log_exit_0_with_counts(tmp_path, capsys):
    p = tmp_path / "pass.csv"
    p.write_text(LOG)
    assert main(["check", str(p)]) == 0
    out = capsys.readouterr().out
    assert "valid, 5 measurements at 3 epochs" in out
    assert "earth_direction" in out and " 2\n" in out
    assert "2024-03-01T00:00:00.000000Z .. 2024-03-01T00:01:00.000000Z (60.000 s)" in out
    assert "out of time order" in out  # the warning is shown


def test_json_output_is_one_object(tmp_path, capsys):
    p = tmp_path / "pass.csv"
    p.write_text(LOG)
    assert main(["check", str(p), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["valid"] is True
    assert rep["counts"] == {"prior_position": 1, "prior_velocity": 1, "earth_direction": 2,
                             "limb_radius": 1}
    assert rep["epochs"] == 3 and rep["rows"] == 5 and rep["span_s"] == 60.0
    assert len(rep["warnings"]) == 1


def test_invalid_log_exit_2_names_file_line_column(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text(LOG.replace("1.1,6378137", "2.0,6378137"))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"{p}, line 6, column 'x': expected a limb angular radius in (0, pi/2)" in err
    assert "Traceback" not in err


def test_invalid_log_json(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text(LOG.replace("prior_velocity", "prior_speed"))
    assert main(["check", str(p), "--json"]) == 2
    rep = json.loads(capsys.readouterr().out)
    assert rep["valid"] is False and rep["line"] == 3 and rep["column"] == "kind"
    assert rep["found"] == "prior_speed"


def test_drop_bad_rows(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text(LOG + "2024-03-01T00:02:00Z,earth_direction,0,0,2,1e-4\n")
    assert main(["check", str(p)]) == 2
    capsys.readouterr()
    assert main(["check", str(p), "--drop-bad-rows", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["dropped"] == {"not_unit": 1} and rep["rows"] == 5


def test_tdm_is_detected(tmp_path, capsys):
    p = tmp_path / "angles.tdm"
    p.write_text(TDM)
    assert main(["check", str(p)]) == 2  # no sigma in the file
    assert "sigma_deg" in capsys.readouterr().err
    assert main(["check", str(p), "--sigma-deg", "0.01", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["counts"] == {"earth_direction": 1}


def test_missing_file_exit_2(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nope.csv")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_console_script_and_lazy_imports(tmp_path):
    p = tmp_path / "pass.csv"
    p.write_text(LOG)
    r = subprocess.run([sys.executable, "-m", "fgnav", "check", str(p), "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["rows"] == 5
    code = ("import sys, fgnav.commands.check as c; "
            "print(sorted(m for m in ('numpy', 'gtsam', 'cv2', 'numba') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "[]"
