"""fgnav.chi2 gives exactly (bit for bit) what scipy.stats gives for the same arguments."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from fgnav.chi2 import chi2_isf, chi2_logsf, chi2_ppf, norm_isf

DOFS = [1, 2, 3, 6, 12, 480, 6 * 14400, 3e6]


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_logsf_is_scipy_stats_bit_for_bit(dof):
    xs = np.concatenate([[0.0, -1.0, 1e-300, np.inf, np.nan],
                         np.geomspace(1e-6, 1e8, 200) * math.sqrt(dof),
                         dof + np.linspace(-50.0, 50.0, 41)])
    for x in xs:
        a, b = float(chi2.logsf(x, dof)), chi2_logsf(x, dof)
        assert a == b or (math.isnan(a) and math.isnan(b)), (x, dof, a, b)


@pytest.mark.parametrize("dof", DOFS)
def test_quantiles_are_scipy_stats_bit_for_bit(dof):
    ps = np.concatenate([[0.0, 0.5, 1.0], np.geomspace(1e-15, 0.999999, 100)])
    for p in ps:
        assert chi2_ppf(p, dof) == float(chi2.ppf(p, dof)), (p, dof)
        if 0.0 < p < 1.0:
            assert chi2_isf(p, dof) == float(chi2.isf(p, dof)), (p, dof)
            assert norm_isf(p) == float(norm.isf(p)), p
    np.testing.assert_array_equal(chi2_ppf([0.025, 0.975], dof), chi2.ppf([0.025, 0.975], dof))


def test_smooth_imports_no_scipy_stats():
    """The integrity tests and gates of a smooth run do not load scipy.stats (1-2 s)."""
    import subprocess
    import sys

    code = ("import sys, fgnav.diagnostics.integrity, fgnav.robust, fgnav.start, fgnav.chi2 as c;"
            "c.chi2_logsf(3.0, 2); c.norm_isf(0.01); c.chi2_isf(0.01, 3); c.chi2_ppf(0.9, 6);"
            "print('scipy.stats' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "False"
