"""Chi-square and normal tail functions from ``scipy.special`` alone.

``scipy.stats`` takes 1-2 s to import (it builds every distribution and its docstrings),
longer than a short pass takes to solve; the few functions fgnav's tests and gates need are
one ``scipy.special`` call each. Each function here evaluates exactly what
``scipy.stats.chi2`` / ``scipy.stats.norm`` (scipy 1.17) evaluate for one scalar argument,
so the figures are bit-identical (tests/test_chi2.py checks them against scipy.stats):
the chi-square distribution function and its inverse are the regularized incomplete gamma
function P(k/2, x/2) and its inverse (Abramowitz & Stegun, "Handbook of Mathematical
Functions", 1964, eq. 26.4.19), the normal quantile the inverse of ``ndtr``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chi2_logsf", "chi2_ppf", "chi2_isf", "norm_isf"]


def chi2_logsf(x: float, dof: float) -> float:
    """log P(X > x) for X ~ chi-square(``dof``) (``scipy.stats.chi2.logsf``): 0 for
    x <= 0, -inf for x = inf, NaN for NaN; above the median log of the upper tail, below it
    log1p of minus the lower tail (the accurate form on each side)."""
    from scipy import special as sc

    x, dof = float(x), float(dof)
    if math.isnan(x) or not dof > 0:
        return math.nan
    if x <= 0.0:
        return 0.0
    if math.isinf(x):
        return -math.inf
    x64, df = np.float64(x), np.float64(dof)
    median = 2 * sc.gammaincinv(df / 2, 0.5)
    with np.errstate(divide="ignore"):
        if x64 > median:
            return float(np.log(sc.chdtrc(df, x64)))
        return float(np.log1p(-sc.chdtr(df, x64)))


def chi2_ppf(probability, dof):
    """The ``probability`` quantile of chi-square(``dof``) (``scipy.stats.chi2.ppf``):
    2 P^-1(dof/2, probability); ``probability`` a number or array in [0, 1]."""
    from scipy import special as sc

    q = np.asarray(probability, dtype=float)
    out = 2 * sc.gammaincinv(np.float64(dof) / 2, q)
    out = np.where(q == 1.0, np.inf, np.where(q == 0.0, 0.0, out))
    out = np.where((q < 0) | (q > 1) | np.isnan(q), np.nan, out)
    return float(out) if out.ndim == 0 else out


def chi2_isf(probability: float, dof: float) -> float:
    """x with P(X > x) = ``probability``, X ~ chi-square(``dof``) (``scipy.stats.chi2.isf``)."""
    from scipy import special as sc

    return float(sc.chdtri(np.float64(dof), np.float64(probability)))


def norm_isf(probability: float) -> float:
    """z with P(Z > z) = ``probability``, Z ~ N(0, 1) (``scipy.stats.norm.isf``)."""
    from scipy import special as sc

    return float(-sc.ndtri(np.float64(probability)))
