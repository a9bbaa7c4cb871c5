"""Numeric options of every command (but `smooth`, see test_cli_smooth): NaN, infinity and
values out of range are exit 2 with argparse's message naming the option and what was
expected; the files they name are never read."""

from __future__ import annotations

import pytest

from fgnav.cli import main

CASES = [
    (["extract", "F", "--out", "o.csv"], "--edge-floor-px", ["-1", "nan"]),
    (["extract", "F", "--out", "o.csv"], "--seed", ["-1", "x"]),
    (["stars", "i.png", "--fov-deg", "10"], "--fov-tolerance", ["1", "-0.1", "inf"]),
    (["stars", "i.png", "--fov-deg", "10"], "--k-sigma", ["0", "nan"]),
    (["limb", "i.png", "--pixel-um", "5"], "--focal-mm", ["0", "-18", "inf"]),
    (["limb", "i.png", "--focal-mm", "18"], "--pixel-um", ["0", "nan"]),
    (["limb", "i.png", "--focal-mm", "18", "--pixel-um", "5"], "--cx-px", ["nan", "inf"]),
    (["limb", "i.png", "--focal-mm", "18", "--pixel-um", "5"], "--r-limb-km", ["0", "-6375"]),
    (["limb", "i.png", "--focal-mm", "18", "--pixel-um", "5"], "--seed", ["-1"]),
    (["formation", "conditioning"], "--sigma-cm", ["0", "nan"]),
    (["formation", "track", "--out", "d"], "--duration-s", ["0", "inf"]),
    (["formation", "track", "--out", "d"], "--step-s", ["0", "-10", "nan"]),
    (["formation", "track", "--out", "d"], "--radius-m", ["0"]),
    (["formation", "track", "--out", "d"], "--alt-km", ["-500", "50", "nan"]),
    (["formation", "track", "--out", "d"], "--max-epochs", ["1"]),
    (["schemes", "refraction"], "--duration-h", ["0", "nan"]),
    (["schemes", "refraction"], "--process-noise", ["-1e-12", "inf"]),
    (["schemes", "refraction"], "--seed", ["-2"]),
    (["schemes", "misalignment"], "--seeds", ["0", "-1", "two"]),
    (["simulate", "geo-limb", "--out", "d", "--raw-stars"], "--star-mounting-sigma-arcsec",
     ["-1", "nan", "4000"]),
    (["campaign", "gto-nees", "--out", "d"], "--workers", ["0", "-1", "two"]),
    (["check", "x.csv"], "--sigma-deg", ["0", "nan", "90"]),
    (["report", "d"], "--sigma", ["0", "-3", "nan"]),
    (["demo"], "--step-s", ["0", "inf"]),
    (["demo"], "--duration-h", ["-1", "nan"]),
    (["demo"], "--seed", ["-1"]),
]


@pytest.mark.parametrize("argv, option, value",
                         [(a, o, v) for a, o, vals in CASES for v in vals],
                         ids=lambda x: x if isinstance(x, str) else " ".join(x)[:30])
def test_bad_numeric_option_is_exit_2_naming_it(argv, option, value, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main([*argv, f"{option}={value}"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: expected" in err and repr(value) in err, err
    assert list(tmp_path.iterdir()) == []       # nothing written


def test_options_checked_at_run_time_are_exit_2(tmp_path, capsys):
    assert main(["formation", "conditioning", "--runs", "0"]) == 2
    assert "--runs" in capsys.readouterr().err
    for v in ("-1", "nan", "inf"):
        assert main(["limb", str(tmp_path / "i.png"), "--focal-mm", "18", "--pixel-um", "5",
                     f"--psf-px={v}"]) == 2
        assert "--psf-px" in capsys.readouterr().err


def test_formation_track_beyond_its_epoch_limit_is_refused(tmp_path, capsys):
    assert main(["formation", "track", "--out", str(tmp_path / "d"), "--duration-s", "1e9"]) == 2
    err = capsys.readouterr().err
    assert "limit of 1,000" in err and "--max-epochs" in err, err


def test_stars_bad_fov_and_epoch_are_exit_2(tmp_path, capsys):
    import numpy as np
    import cv2

    img = tmp_path / "i.png"
    cv2.imwrite(str(img), np.zeros((32, 32), np.uint16))
    assert main(["stars", str(img), "--fov-deg", "10", "--epoch", "2016-12-31T23:59:61Z"]) == 2
    assert "--epoch" in capsys.readouterr().err
    for fov in ("0", "180", "nan", "-3", "inf"):
        assert main(["stars", str(img), f"--fov-deg={fov}"]) == 2
        assert "--fov-deg" in capsys.readouterr().err


@pytest.mark.parametrize("missing, raised", [("gtsam", True), ("not_a_dependency", False)])
def test_a_missing_dependency_is_a_message_not_a_traceback(monkeypatch, capsys, missing, raised):
    """A Python without one of fgnav's dependencies (gtsam not installed: 'fgnav smooth' ended
    in a ModuleNotFoundError traceback) gets one error line naming the package and exit 2; a
    missing module that is not a dependency stays the bug it is."""
    import fgnav.commands.check as check

    def run(args):
        raise ModuleNotFoundError(f"No module named '{missing}'", name=missing)

    monkeypatch.setattr(check, "run", run)
    if raised:
        assert main(["check", "log.csv"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("fgnav: error:") and f"'{missing}'" in err and "pip install" in err
    else:
        with pytest.raises(ModuleNotFoundError):
            main(["check", "log.csv"])
