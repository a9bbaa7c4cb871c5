"""What the stellar-aberration correction is worth: the same simulated passes (apparent
star directions, the truth) solved with the correction (the models' default) and without
(:func:`fgnav.apparent.without_aberration`, ``fgnav smooth --no-aberration``), against the
independent DOP853 truth and the simulator's true attitude.

- geo-limb ``--raw-stars`` (GEO, zenith star camera, 5 arcsec stars, body-frame Earth
  direction; the attitude estimated): without the correction the attitude takes the
  aberration (~20 arcsec from the Earth's orbit, 2 arcsec from the GEO orbit's own velocity)
  as an error, and the body-frame Earth direction turns the orbit by it (1e-4 rad at 42,000
  km: kilometres); with it, attitude and position are within their sigmas.
- refraction-leo (starlight refraction, LEO): without the correction every star's ray is
  off by the Earth's aberration, the tangent heights by up to ~|r.s| 1e-4 rad (~250 m); with
  it the position is within its sigma.
- sextant-leo (attitude-free angles, LEO): the star's line of sight is aberrated by the
  Earth's orbital velocity and the Earth's limb is not (it moves with the observer's frame),
  so the limb-star angles are off by up to ~27 arcsec without the correction.
The figures of docs/aberration.md come from these passes at full length.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.constants import ARCSEC
from factors.geometry import so3_exp, so3_log
from fgnav.apparent import without_aberration
from fgnav.measurements import build_pass
from fgnav.models.registry import ATTITUDE_VARIABLE
from fgnav.pipeline import solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import raw_star_scenario, simulate_pass
from fgnav.solvers.options import SmootherOptions

CHI2_3_999 = 16.27   # 99.9 % point of chi-square with 3 degrees of freedom


def _position(sim, sol):
    """Position error RMS (m), the solution's position sigma RMS (m) and the NEES per epoch."""
    idx = np.searchsorted(sim.t_s, sol.t_s)
    err = sol.x_eci[:, :3] - sim.x_true[idx, :3]
    nees = np.einsum("ki,ki->k", err, np.linalg.solve(sol.P_eci[:, :3, :3], err[..., None])[..., 0])
    sig = np.sqrt(np.mean(np.trace(sol.P_eci[:, :3, :3], axis1=1, axis2=2)))
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))), float(sig), nees


def test_raw_stars_attitude_and_position_with_and_without_aberration():
    sim = simulate_pass(raw_star_scenario(load_scenario("geo-limb").with_options(
        duration_h=6.0)), seed=1)
    opts = replace(SmootherOptions(third_body=True), estimate=(ATTITUDE_VARIABLE.name,))
    p = build_pass(sim.log)
    out = {}
    for name, pp in (("on", p), ("off", without_aberration(p))):
        sol = solve(pp, "batch", opts)
        idx = np.searchsorted(sim.t_s, sol.t_s)
        w, P = sol.variables[ATTITUDE_VARIABLE.name]
        err = so3_log(np.swapaxes(sim.truth_attitude()[idx], 1, 2) @ so3_exp(w))
        att_rms = np.sqrt(np.mean(err[:, :2] ** 2, axis=0)) / ARCSEC   # cross-boresight
        att_sig = np.sqrt(np.mean(P[:, [0, 1], [0, 1]], axis=0)) / ARCSEC
        out[name] = (att_rms, att_sig, *_position(sim, sol))
    att_on, sig_on, r_on, rs_on, nees_on = out["on"]
    att_off, _, r_off, _, nees_off = out["off"]
    print(f"raw stars: attitude x/y RMS {att_on} arcsec (sigma {sig_on}) with, {att_off} "
          f"without; position RMS {r_on:.0f} m (sigma {rs_on:.0f}) with, {r_off:.0f} without; "
          f"position NEES mean {np.mean(nees_on):.1f} / max {np.max(nees_on):.1f} with, "
          f"{np.mean(nees_off):.1f} / {np.max(nees_off):.1f} without")
    assert np.all(att_on < 1.5 * sig_on)                        # within its sigma
    assert np.max(nees_on) < CHI2_3_999 and 0.3 < np.mean(nees_on) < 9.0   # as test_raw_stars
    assert np.min(att_off) > 3.0 * np.max(sig_on)
    assert np.mean(nees_off) > 4.0 * np.mean(nees_on) and np.max(nees_off) > CHI2_3_999


@pytest.mark.parametrize("scenario, hours, seed, worse", [
    ("refraction-leo", 1.0, 2, 5.0),
    # the sextant's limb-star, Moon-star and Earth-Moon angles: the star's line of sight is
    # aberrated by the Earth's orbital velocity and the Earth's limb is not (~27 arcsec)
    ("sextant-leo", 2.0, 3, 3.0)])
def test_position_with_and_without_aberration(scenario, hours, seed, worse):
    sim = simulate_pass(load_scenario(scenario).with_options(duration_h=hours), seed=seed)
    p = build_pass(sim.log)
    r_on, sig, nees_on = _position(sim, solve(p, "batch", SmootherOptions()))
    r_off, _, nees_off = _position(sim, solve(without_aberration(p), "batch", SmootherOptions()))
    print(f"{scenario}: position RMS {r_on:.1f} m (sigma {sig:.1f}) with, {r_off:.1f} without; "
          f"NEES mean {np.mean(nees_on):.1f} with, {np.mean(nees_off):.1f} without")
    assert r_on < 1.5 * sig and np.mean(nees_on) < 6.0
    assert r_off > worse * sig and np.mean(nees_off) > 25.0


def test_smooth_no_aberration_option(tmp_path):
    """``fgnav smooth --no-aberration`` solves the same log without the correction: on a
    short refraction pass the position error grows well past the corrected one's."""
    import json

    from fgnav.cli import main

    d = tmp_path / "pass"
    assert main(["simulate", "refraction-leo", "--out", str(d), "--duration-h", "0.5",
                 "--seed", "4", "--quiet"]) == 0
    rms = {}
    for name, extra in (("on", []), ("off", ["--no-aberration"])):
        out = tmp_path / name
        code = main(["smooth", str(d / "measurements.csv"), "--out", str(out), "--truth",
                     str(d / "truth.oem"), "--quiet", *extra])
        assert code == (0 if name == "on" else code) and code in (0, 1)   # 1: integrity fails
        s = json.loads((out / "summary.json").read_text())
        rms[name] = (s["position_rms_m"], s["sigma_position_rms_m"])
    assert rms["on"][0] < 1.5 * rms["on"][1]
    assert rms["off"][0] > 5.0 * rms["on"][1]
