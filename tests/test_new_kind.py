"""A kind defined in one module is read, simulated and filtered without touching another file.

A throw-away kind (``geocentric_range_test``: the distance to the Earth's centre, m) is
written in a temporary module as CONTRIBUTING.md's "Add a measurement" describes: its
residual and Jacobian, its numba row kernel, its :class:`MeasurementModel`, its log schema
row (``LOG_KINDS``) and its simulator. Registering the module's objects (what the registry
does for the modules in ``FAMILY_MODULES``; ``fgnav.simulate.simulators.register``) is all it
takes for the simulator to write its rows (truth from the independent integrator), the CSV
reader to read them back, the pass builder to make a family of them and the compiled EKF to
dispatch on its kernel (a dispatch generated for the new kernel table) with the numpy EKF's
numbers.
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fgnav.errors import InputFormatError
from fgnav.io.log_csv import read_log
from fgnav.measurements import build_pass
from fgnav.models import registry
from fgnav.pipeline import read_measurements
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate import simulators
from fgnav.simulate.pass_sim import simulate_pass, write_pass_files
from fgnav.solvers import ekf_numba
from fgnav.solvers.ekf import run_ekf

ROOT = Path(__file__).resolve().parents[1]
KIND = "geocentric_range_test"

MODULE = f'''
"""A throw-away kind: the distance |r| from the Earth's centre, m (CONTRIBUTING's example)."""
import math

import numpy as np

from factors.jit import njit
from fgnav.io.log_csv import KindSpec, RowError, fmt_found
from fgnav.models.model import MeasurementModel
from fgnav.simulate.simulators import Simulator, readings


def residual(r, rho):
    """e = |r| - rho, H = r^T / |r| (M, 1, 3)."""
    n = np.linalg.norm(r, axis=1)
    return (n - rho)[:, None], (r / n[:, None])[:, None, :]


@njit(cache=False)
def kernel(x, data, B, e, H):
    n = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    if n <= 0.0:
        return -1
    e[0] = n - data[0]
    for j in range(6):
        H[0, j] = x[j] / n if j < 3 else 0.0
    return 1


def _residual(fam, v):
    e, H = residual(v["orbit"][:, :3], fam.values["rho_m"])
    return e, {{"position": H}}


def _data(fam):
    d = np.zeros((len(fam), 3))
    d[:, 0] = fam.values["rho_m"]
    return d, None


MODEL = MeasurementModel(
    kind="{KIND}", dim=1, unit="m", observes_orbit=True, summary="distance to the Earth's centre, m",
    values=lambda log, i: {{"rho_m": np.asarray(log.xyz, dtype=float)[i, 0]}},
    residual=_residual, numba_kernel=kernel, numba_data=_data)
MEASUREMENT_MODELS = (MODEL,)


def _check(x, y, z, sigma_model):
    if not x > 0.0:
        raise RowError("out_of_range", "x", "a distance > 0 m", fmt_found(x))


LOG_KINDS = {{"{KIND}": KindSpec(("r", "", "", "", ""), "x = distance to the Earth's centre, m",
                                1e-3, 1e7, "m", check=_check)}}


def _readings(spec, t_s, x_true, rng):
    rho = np.linalg.norm(x_true[:, :3], axis=1) + spec.sigma_m * rng.standard_normal(len(t_s))
    return np.column_stack([rho, np.full((len(t_s), 2), np.nan)]), spec.sigma_m


SIMULATOR = Simulator("{KIND}", readings(_readings), ("sigma_m",))
'''


@pytest.fixture
def new_kind(tmp_path, monkeypatch):
    """The temporary module, imported, its kind registered for the test's duration."""
    (tmp_path / "throwaway_kind.py").write_text(MODULE, encoding="utf-8")
    spec = importlib.util.spec_from_file_location("throwaway_kind", tmp_path / "throwaway_kind.py")
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "throwaway_kind", mod)
    spec.loader.exec_module(mod)
    for m in mod.MEASUREMENT_MODELS:      # what the registry does for its FAMILY_MODULES
        monkeypatch.setitem(registry.MODELS, m.kind, m)
    for kind, row in mod.LOG_KINDS.items():
        monkeypatch.setitem(registry.LOG_SCHEMA, kind, row)
    monkeypatch.setitem(simulators.SIMULATORS, KIND, mod.SIMULATOR)
    return mod


def test_no_file_of_the_project_names_the_new_kind():
    for path in list((ROOT / "fgnav").rglob("*.py")) + list((ROOT / "factors").rglob("*.py")):
        assert KIND not in path.read_text(encoding="utf-8"), path


def test_a_kind_in_one_module_is_simulated_read_and_filtered(new_kind, tmp_path):
    scn = load_scenario("gto-transfer").with_options(duration_h=1.0, step_s=60.0)
    scn = replace(scn, sensors=scn.sensors + (SensorSpec(KIND, sigma_m=50.0, period_s=120.0),))
    sim = simulate_pass(scn, seed=3)
    assert np.count_nonzero(sim.log.kind == KIND) == 31          # every 120 s over an hour
    out = tmp_path / "pass"
    out.mkdir()
    write_pass_files(out, sim)

    # read back through the models' schema; the format's own table refuses the kind
    log = read_measurements(out / "measurements.csv")
    assert np.array_equal(log.xyz[log.kind == KIND, 0], sim.log.xyz[sim.log.kind == KIND, 0])
    with pytest.raises(InputFormatError, match=r"measurements\.csv.*line \d+.*kind"):
        read_log(out / "measurements.csv")

    # filtered: the generated dispatch holds the new kernel, both EKFs give the same numbers
    p = build_pass(log)
    assert KIND in p.families and ekf_numba.numba_supports(p)
    kernels = ekf_numba.row_kernels(registry.MODELS.values())
    assert kernels[-1] is new_kind.kernel and len(kernels) == len(ekf_numba.ROW_KERNELS) + 1
    fast, ref = ekf_numba.run_ekf_numba(p), run_ekf(p)
    assert np.allclose(fast.x_eci, ref.x_eci, rtol=0.0, atol=1e-6)
    assert np.allclose(fast.residuals[KIND], ref.residuals[KIND], rtol=0.0, atol=1e-6)

    # and the range rows carry information: against the truth (scipy DOP853), the filter with
    # them ends nearer than without them
    x_true = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    without = ekf_numba.run_ekf_numba(build_pass(log.__class__(**{
        **log.__dict__, **_rows(log, log.kind != KIND)})))
    err = np.linalg.norm(fast.x_eci[:, :3] - x_true[:, :3], axis=1)
    err0 = np.linalg.norm(without.x_eci[:, :3] - x_true[:, :3], axis=1)
    assert np.sqrt(np.mean(err[-20:] ** 2)) < 0.8 * np.sqrt(np.mean(err0[-20:] ** 2))


def _rows(log, keep):
    """The fields of ``log`` that hold one entry per row, at the rows ``keep``."""
    return {"t_s": log.t_s[keep], "kind": log.kind[keep], "xyz": log.xyz[keep],
            "sigma": log.sigma[keep], "line": log.line[keep],
            "extra": {c: a[keep] for c, a in log.extra.items()}}
