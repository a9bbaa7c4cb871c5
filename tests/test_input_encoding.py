"""Files users hand us: UTF-8 with a byte-order mark is read as plain UTF-8, CRLF line ends
are accepted, and a file in another encoding (Latin-1 from a spreadsheet) is exit 2 with a
message naming the file, the line and the byte -- frames.csv (`fgnav extract`), the
measurement log (`fgnav check`), the attitude CSV."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.errors import InputFormatError

BOM = b"\xef\xbb\xbf"


@pytest.fixture(scope="module")
def tiny_pass(tmp_path_factory):
    """geo-limb, 2 epochs (4 frames: star + limb), seed 5; extracted once as the reference."""
    d = tmp_path_factory.mktemp("tiny_images")
    assert main(["simulate", "geo-limb", "--out", str(d), "--duration-h", "0.04", "--step-s", "120",
                 "--seed", "5", "--images", "--quiet"]) == 0
    assert main(["extract", str(d), "--out", str(d / "ref.csv"), "--quiet"]) == 0
    return d


def _rows(path):
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]


def _copy_pass(src, dst, frames_bytes):
    shutil.copytree(src / "frames", dst / "frames")
    shutil.copy(src / "measurements.csv", dst / "measurements.csv")
    (dst / "frames.csv").write_bytes(frames_bytes)


@pytest.mark.parametrize("variant", ["bom", "crlf", "bom_crlf"])
def test_extract_reads_a_bom_or_crlf_frames_csv_like_the_plain_one(variant, tiny_pass, tmp_path):
    raw = (tiny_pass / "frames.csv").read_bytes()
    if "crlf" in variant:
        raw = raw.replace(b"\n", b"\r\n")
    if "bom" in variant:
        raw = BOM + raw
    _copy_pass(tiny_pass, tmp_path, raw)
    assert main(["extract", str(tmp_path), "--out", str(tmp_path / "x.csv"), "--quiet"]) == 0
    ref = _rows(tiny_pass / "ref.csv")
    assert len(ref) == 7 and _rows(tmp_path / "x.csv") == ref    # header + 6 rows, identical


def test_extract_non_utf8_frames_csv_is_exit_2_naming_line_and_byte(tiny_pass, tmp_path, capsys):
    raw = (tiny_pass / "frames.csv").read_bytes()
    lines = raw.split(b"\n")
    lines.insert(1, "# camera from the caf\xe9 lab".encode("latin-1"))   # a Latin-1 comment
    bad = b"\n".join(lines)
    _copy_pass(tiny_pass, tmp_path, bad)
    rc = main(["extract", str(tmp_path), "--out", str(tmp_path / "x.csv"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    offset = bad.index(b"\xe9")
    assert f"{tmp_path / 'frames.csv'}, line 2" in err, err
    assert "0xe9" in err and f"byte offset {offset}" in err and "UTF-8" in err, err
    assert not (tmp_path / "x.csv").exists()


def test_read_frames_index_unreadable_is_a_user_error(tmp_path):
    from fgnav.errors import UserError
    from fgnav.extract import read_frames_index

    (tmp_path / "frames.csv").mkdir()
    with pytest.raises(UserError):
        read_frames_index(tmp_path / "frames.csv")


LOG = ("epoch,kind,x,y,z,sigma\n"
       "2024-03-01T00:00:00Z,prior_position,7000000,0,0,1000\n"
       "2024-03-01T00:00:00Z,prior_velocity,0,7546,0,1\n"
       "2024-03-01T00:00:00Z,earth_direction,-1,0,0,1e-4\n"
       "2024-03-01T00:01:00Z,earth_direction,0,-1,0,1e-4\n")


def test_log_with_bom_checks_like_the_plain_one(tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text(LOG)
    b.write_bytes(BOM + LOG.replace("\n", "\r\n").encode())
    assert main(["check", str(a), "--json"]) == 0
    out_a = capsys.readouterr().out
    assert main(["check", str(b), "--json"]) == 0
    assert capsys.readouterr().out.replace(str(b), str(a)) == out_a


def test_log_in_latin1_is_exit_2_naming_the_line(tmp_path, capsys):
    p = tmp_path / "a.csv"
    p.write_bytes(("# pass from the caf\xe9 lab\n" + LOG).encode("latin-1"))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"{p}, line 1" in err and "UTF-8" in err and "0xe9" in err, err
    p.write_bytes(LOG.replace("prior_velocity", "prior_v\xe9locity").encode("latin-1"))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"{p}, line 3" in err and "0xe9" in err, err


ATT_HEADER = ("epoch,qw,qx,qy,qz,sigma_x_rad,sigma_y_rad,sigma_z_rad,cov_xy_rad2,cov_xz_rad2,"
              "cov_yz_rad2\n")
ATT_ROW = "2016-12-31T23:59:60.500000Z,1.0,0.0,0.0,0.0,1e-5,2e-5,3e-5,0.0,0.0,0.0\n"


def test_attitude_csv_bom_and_leap_second(tmp_path):
    from fgnav.io.attitude_csv import read_attitude_csv, write_attitude_csv
    from fgnav.time import format_utc

    p = tmp_path / "att.csv"
    p.write_bytes(BOM + (ATT_HEADER + ATT_ROW).encode())
    t, R, P = read_attitude_csv(p)
    assert format_utc(t[0]) == "2016-12-31T23:59:60.500000Z"
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(np.sqrt(np.diag(P[0])), [1e-5, 2e-5, 3e-5], rtol=1e-12)
    write_attitude_csv(tmp_path / "b.csv", t, R, P)
    assert "2016-12-31T23:59:60.500000Z" in (tmp_path / "b.csv").read_text()
    t2, R2, P2 = read_attitude_csv(tmp_path / "b.csv")
    assert t2[0] == t[0]


@pytest.mark.parametrize("content, line, column, phrase", [
    ((ATT_HEADER + ATT_ROW.replace("1e-5", "nan")).encode(), 2, "sigma_x_rad", "finite"),
    ((ATT_HEADER + ATT_ROW.replace("2e-5", "-2e-5")).encode(), 2, "sigma_y_rad", ">= 0"),
    ((ATT_HEADER + ATT_ROW.replace(",1.0,0.0,", ",0.0,0.0,")).encode(), 2, "qw", "unit quaternion"),
    ((ATT_HEADER + ATT_ROW.replace("23:59:60.5", "23:59:61.5")).encode(), 2, "epoch", "ISO-8601"),
    ((ATT_HEADER + ATT_ROW.replace("0.0,0.0,0.0\n", "0.0,zero,0.0\n")).encode(), 2, "cov_xz_rad2",
     "finite"),
    (("# caf\xe9\n" + ATT_HEADER + ATT_ROW).encode("latin-1"), 1, None, "UTF-8"),
    (ATT_HEADER.encode(), None, None, "at least one row"),
])
def test_attitude_csv_errors_name_line_and_column(content, line, column, phrase, tmp_path):
    from fgnav.io.attitude_csv import read_attitude_csv

    p = tmp_path / "att.csv"
    p.write_bytes(content)
    with pytest.raises(InputFormatError) as exc:
        read_attitude_csv(p)
    assert exc.value.line == line and exc.value.column == column and phrase in str(exc.value)
