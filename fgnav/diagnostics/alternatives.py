"""Alternative models the data may prefer: a likelihood-ratio test of the solution's model
against a richer one that the solution left out.

A star camera mounted apart from the body frame (the Earth camera's) turns every star row by
its mounting rotation ``M = R_body_from_starcam``; solved as if ``M = I``, the attitude the
stars fix is off by ``M`` and every body-frame Earth row turns with it: 60 arcsec (1 sigma
per axis) moved 2 h of geo-limb raw stars to orbit NEES 350-11,000 with the verdict ``ok``
(the integrity issue, item 9). The solve is repeated with the mounting as one more
variable (``--estimate camera-alignment``, Shuster & Pitone 1991) and the chi-squares
compared: without a mounting error their difference is chi-square with 3 degrees of freedom
(Wilks 1938; Kay 1998, vol. II, sec. 6.5), so a fall beyond its ``1 - 1e-3`` quantile says
the data prefer a mounting rotation. Where the orbit absorbs the rotation the chi-square
barely falls, and the data cannot tell (docs/integrity.md gives the measured rate).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from factors.constants import ARCSEC
from factors.errors import ModelDomainError
from fgnav.chi2 import chi2_isf
from fgnav.errors import NotObservableError, UserError
from fgnav.graph import block_values
from fgnav.measurements import Pass, with_estimates
from fgnav.models.registry import ATTITUDE_VARIABLE, CAMERA_ALIGNMENT

__all__ = ["camera_mounting_test", "MOUNTING_FALSE_ALARM", "MOUNTING_MAX_ITERATIONS"]

MOUNTING_FALSE_ALARM = 1e-3
"""False-alarm probability of the mounting test on a pass whose star rows are in the body
frame (threshold: the chi-square(3) quantile, 16.3)."""
MOUNTING_MAX_ITERATIONS = 10
"""Gauss-Newton iterations of each of the test's solves (from the solution)."""

STAR_KIND = "star_direction_body"


def applies(p: Pass) -> bool:
    """The pass has star rows on an estimated attitude and its mounting is not estimated."""
    fam = p.families.get(STAR_KIND)
    return (fam is not None and len(fam) > 0 and p.layout.has(ATTITUDE_VARIABLE.name)
            and not p.layout.has(CAMERA_ALIGNMENT.name))


def camera_mounting_test(p: Pass, sol, options, smooth_batch) -> dict | None:
    """The likelihood-ratio test of the star camera's mounting (module docstring), or None
    where it does not apply (:func:`applies`). ``smooth_batch(p, options, x_init=X)``: the
    batch smoother (:func:`fgnav.solvers.batch.smooth_batch`, given by the pipeline: the
    diagnostics sit below the solvers). ``status`` is ``suspect`` when the chi-square falls
    by more than the threshold; ``mounting_arcsec`` is the rotation the richer model finds."""
    if not applies(p):
        return None
    quick = replace(options, q_start_m2_s3=options.q_m2_s3,
                    max_iterations=MOUNTING_MAX_ITERATIONS)
    X = block_values(p, sol.x_eci, sol.variables)
    try:
        here = sol if sol.method == "batch" else smooth_batch(p, quick, x_init=X)
        names = tuple(v.name for v in p.layout.extra) + (CAMERA_ALIGNMENT.name,)
        p_alt = with_estimates(p, names)
        there = smooth_batch(p_alt, replace(quick, estimate=tuple(options.estimate)
                                            + (CAMERA_ALIGNMENT.name,)),
                             x_init=block_values(p_alt, here.x_eci, here.variables))
    except (ModelDomainError, NotObservableError, UserError, np.linalg.LinAlgError):
        return None
    drop = float(here.chi2) - float(there.chi2)
    threshold = chi2_isf(MOUNTING_FALSE_ALARM, 3)
    m = there.variables.get(CAMERA_ALIGNMENT.name)
    arcsec = (float(np.linalg.norm(np.asarray(m[0], float)[0])) / ARCSEC
              if m is not None else math.nan)
    return {"status": "suspect" if drop > threshold else "ok", "chi2": float(here.chi2),
            "chi2_with_mounting": float(there.chi2), "chi2_drop": drop,
            "threshold": float(threshold), "mounting_arcsec": arcsec}
