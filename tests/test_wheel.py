"""The product as a user installs it: a wheel in a fresh virtual environment, run elsewhere.

Builds the wheel from this checkout (``pip wheel``, build isolation as a user's pip would),
installs it without dependencies into a new venv that sees this interpreter's packages
(gtsam, numba, ... are the same, also when the tests run in a virtual environment; the fgnav
under test is the wheel's), and runs the commands
that need the data shipped inside the package from a directory outside the checkout:
``fgnav demo``, ``fgnav simulate``, ``fgnav campaign --list`` and ``fgnav stars`` (the star
catalogue). The first run in the new location compiles the numba kernels (~30 s).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from shared_data import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, cwd, env, timeout=600):
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\nstdout:\n{r.stdout}\nstderr:\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "FGNAV_DATA")}
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(base / "dist"),
          str(ROOT)], base, env)
    wheel, = (base / "dist").glob("fgnav-*.whl")
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], base, env)
    # the new venv sees this interpreter's packages (its own venv's, where the tests run in
    # one: --system-site-packages would see only the base interpreter's): a .pth file naming
    # them, which puts them after the venv's own site-packages, where the wheel goes; the
    # .pth files inside them (an editable fgnav's finder) are not read from there
    purelib = subprocess.run([str(venv / "bin" / "python"), "-c",
                              "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    outer = [p for p in sys.path if p.endswith("site-packages") and Path(p).is_dir()]
    (Path(purelib) / "_fgnav_test_outer.pth").write_text("\n".join(outer) + "\n")
    _run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", str(wheel)],
         base, env)
    work = base / "elsewhere"
    work.mkdir()
    return venv / "bin", work, env


def test_the_wheel_is_the_fgnav_that_runs(installed):
    bindir, work, env = installed
    r = _run([str(bindir / "python"), "-c", "import fgnav, fgnav.paths as p; "
              "print(fgnav.__file__); print(p.data_dir())"], work, env)
    module, data = r.stdout.split()
    assert str(bindir.parent) in module and str(ROOT) not in module
    assert (Path(data) / "scenarios" / "gto-transfer.toml").is_file()


def test_demo_simulate_and_campaign_list_from_elsewhere(installed):
    bindir, work, env = installed
    r = _run([str(bindir / "fgnav"), "demo", "--duration-h", "0.5", "--methods", "batch,ekf",
              "--out", "demo"], work, env)
    assert "batch" in r.stdout and "CRB" in r.stdout
    summary = json.loads(next((work / "demo").rglob("summary.json")).read_text())
    assert summary["integrity"]["status"] == "ok"
    _run([str(bindir / "fgnav"), "simulate", "refraction-leo-bias", "--duration-h", "0.1",
          "--out", "sim"], work, env)
    assert (work / "sim" / "truth_refraction_bias.csv").is_file()
    r = _run([str(bindir / "fgnav"), "campaign", "--list"], work, env)
    assert "seed002-noise" in r.stdout and "gto-nees" in r.stdout


def test_stars_finds_the_shipped_catalogue(installed):
    image = SHARED_DATA / "star_images" / "2019-07-29T204726_Alt40_Azi-45_Try1.tiff"
    if not image.is_file():
        pytest.skip(f"{image} not found (../shared beside the checkout)")
    bindir, work, env = installed
    r = _run([str(bindir / "fgnav"), "stars", str(image), "--fov-deg", "11.4",
              "--epoch", "2019-07-29T20:47:26Z", "--json"], work, env)
    assert json.loads(r.stdout)["matched"] >= 10
