"""The initial orbit of a pass from its measurements alone: which method applies, the entry
point, and the orbit carried to other epochs.

The geocentric directions (with ranges, if any) go to the angles method
(:mod:`fgnav.iod.angles`); a pass with too few of them but with attitude-free angles (cones,
tori, limb-star angles) to the geometric fixes (:mod:`fgnav.iod.geometric`). Both end with
the same 6-state fit on the rows (:func:`fgnav.iod.fit.fit_orbit`) and give an
:class:`fgnav.iod.fit.InitialOrbit`.
"""

from __future__ import annotations

import numpy as np

from factors.dynamics import MotionModel, propagate, propagate_through
from fgnav.errors import UserError
from fgnav.iod.angles import (BODY_DIRECTION_KINDS, DIRECTION_KINDS, MIN_DIRECTION_EPOCHS,
                              PRIOR_ROWS, RANGE_KINDS, angles_initial_orbit,
                              geocentric_directions)
from fgnav.iod.fit import InitialOrbit
from fgnav.iod.geometric import geometric_initial_orbit, geometric_support
from fgnav.measurements import Pass, directions_in_eci
from fgnav.models.registry import ATTITUDE, prior_kinds

__all__ = ["iod_support", "initial_orbit", "propagate_orbit", "trajectory"]


def iod_support(p: Pass) -> tuple[bool, str]:
    """Whether :func:`initial_orbit` can start from this pass, and a sentence saying why."""
    p = directions_in_eci(p)
    n_dir = len(np.unique(geocentric_directions(p)[0]))
    if n_dir >= MIN_DIRECTION_EPOCHS:
        ranges = [k for k in RANGE_KINDS if p.count(k)]
        return True, (f"an initial orbit can be computed from {n_dir} direction epochs"
                      + (f" and the {'/'.join(ranges)} rows" if ranges else ""))
    ok, why = geometric_support(p)   # cones and tori (the cruise)
    if ok:
        return ok, why
    others = sorted(k for k in p.families if k not in prior_kinds())
    return False, (f"no initial orbit from {', '.join(others) or 'no measurements'}"
                   f"{f' ({n_dir} direction epochs)' if n_dir else ''}: it needs "
                   f"{'/'.join(DIRECTION_KINDS)} (or {'/'.join(BODY_DIRECTION_KINDS)} + "
                   f"{ATTITUDE.kind}) rows at {MIN_DIRECTION_EPOCHS} or more epochs, optionally "
                   f"with {'/'.join(RANGE_KINDS)} rows; otherwise add {PRIOR_ROWS}")


def initial_orbit(p: Pass, model: MotionModel, t0_j2000_s: float,
                  near_k: int | None = None) -> InitialOrbit:
    """The orbit from the pass's directions (and ranges), without its prior rows.

    ``t0_j2000_s``: seconds since J2000 of the pass epoch (``fgnav.time.j2000_seconds``).
    ``near_k``: fit the session (see :mod:`fgnav.iod.angles`) nearest epoch ``near_k``
    rather than the longest one. Raises :class:`UserError` when the log cannot start an
    orbit (see :func:`iod_support`) or the fit does not converge.
    """
    ok, why = iod_support(p)
    if not ok:
        raise UserError(f"{p.source}: {why}")
    if len(np.unique(geocentric_directions(directions_in_eci(p))[0])) < MIN_DIRECTION_EPOCHS:
        try:   # angles without directions
            return geometric_initial_orbit(p, model, t0_j2000_s, near_k)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            raise UserError(f"{p.source}: the initial orbit fit failed ({exc}); add "
                            f"{PRIOR_ROWS}") from exc
    try:   # body-frame directions (--estimate attitude) rotated with the attitude rows
        return angles_initial_orbit(directions_in_eci(p), model, t0_j2000_s, near_k)
    except UserError:
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        raise UserError(f"{p.source}: the initial orbit fit failed ({exc}); add "
                        f"{PRIOR_ROWS}") from exc


def propagate_orbit(iod: InitialOrbit, p: Pass, model: MotionModel, t0_j2000_s: float,
                    k: int) -> tuple[np.ndarray, np.ndarray]:
    """The initial orbit's state (6,) and covariance (6,6) at epoch ``k`` (linear mapping
    ``Phi P Phi^T`` through the propagator's state-transition matrix)."""
    t_ref = float(p.t_s[iod.k_ref])
    x, Phi = propagate(iod.x_eci, float(p.t_s[k]) - t_ref, model, t0_j2000_s + t_ref)
    return x, Phi @ iod.P_eci @ Phi.T


def trajectory(iod: InitialOrbit, p: Pass, model: MotionModel, t0_j2000_s: float) -> np.ndarray:
    """The initial orbit propagated to every epoch of the pass (N, 6): a first guess."""
    return propagate_through(iod.x_eci, p.t_s, iod.k_ref, model, t0_j2000_s)
