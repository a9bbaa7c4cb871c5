"""Consistency of the joint orbit-attitude solution (``scripts/study_attitude_anees.py``):
the 9-dimensional (position, velocity, attitude) error against the solvers' joint marginal
covariance (``Solution.P_block``, cross terms included), over independent runs.

The slow test is the study itself: 50 runs, the ANEES at the middle and the last epoch
inside the 95 % chi-square band, batch and iSAM2. The default test runs 10 and checks a
looser band (99.9 %) -- loose enough for 10 runs, tight enough that a covariance wrong by a
factor of two in either direction fails it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from fgnav.diagnostics.consistency import anees

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "study_attitude_anees.py"


def _study():
    spec = importlib.util.spec_from_file_location("study_attitude_anees", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_joint_anees_few_runs_and_a_wrong_covariance_fails():
    st = _study()
    runs, _ = st.study(n_runs=10, seed0=100, methods=("batch",))
    E, P = runs["batch"]
    # the joint covariance has orbit-attitude cross terms (body-frame Earth rows couple them)
    corr = P[..., :3, 6:9] / np.sqrt(np.diagonal(P[..., :3, :3], axis1=-2, axis2=-1)[..., :, None]
                                     * np.diagonal(P[..., 6:9, 6:9], axis1=-2, axis2=-1)[..., None, :])
    assert np.max(np.abs(corr)) > 0.1
    for scale, consistent in ((1.0, True), (0.5, False), (2.0, False)):
        v = st.nees_runs(E, P, scale)
        for epoch in (v.shape[1] // 2, -1):
            a = anees(v[:, epoch], st.DOF, alpha=1e-3)
            assert a.inside == consistent, (scale, epoch, a.as_dict())


@pytest.mark.slow
def test_joint_anees_inside_the_95_percent_band_over_50_runs():
    st = _study()
    runs, _ = st.study(n_runs=50, seed0=0, methods=("batch", "isam2"))
    res = st.summarize({m: st.nees_runs(E, P) for m, (E, P) in runs.items()})
    for method, r in res.items():
        assert r["anees_mid"]["inside"] and r["anees_final"]["inside"], (method, r)
        assert r["fraction_of_epochs_in_band"] > 0.85, (method, r)
