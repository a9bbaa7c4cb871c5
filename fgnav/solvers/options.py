"""Options of the smoothers and filters (SI units): plain frozen dataclasses, no solver code.

They live apart from the solvers so that every solver (batch, iSAM2/fixed-lag, the EKFs) and
every caller can import them without importing another solver (and GTSAM with it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from factors.dynamics import MotionModel
from fgnav.defaults import DEFAULT_Q_M2_S3
from fgnav.errors import UserError
from fgnav.solvers.state_elements import check_state
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.io.log_csv import CENTRES  # "earth" (geocentric) | "sun" (heliocentric: Sun + planets)

GRAVITY_MODELS = ("j2", "point-mass")
"""Earth gravity fields of the motion model: ``j2`` (central term + J2, Vallado 2013,
*Fundamentals of Astrodynamics and Applications*, eq. 8-30) or ``point-mass`` (the central
term alone, -mu r/|r|^3: Keplerian motion, for test data simulated without J2)."""


@dataclass(frozen=True)
class SmootherOptions:
    """Options of the smoothers (SI units)."""

    q_m2_s3: float = DEFAULT_Q_M2_S3
    third_body: bool = False
    max_iterations: int = 60
    q_start_m2_s3: float = 1e-6
    continuation_factor: float = 1e3
    tol_position_m: float = 1e-3
    tol_velocity_mps: float = 1e-6
    tol_sigma: float = 1e-4  # ... or every update below this fraction of its marginal sigma
    tol_chi2_relative: float | None = None  # ... or chi2 changed by at most this fraction (None: not used)
    max_step_s: float | None = None
    robust: str | None = None          # None | "huber" | "cauchy" (measurements, not priors)
    robust_k: float | None = None      # kernel threshold in sigmas (default: 95% efficiency)
    reject_probability: float = 1.0 - 1e-6  # after a robust solve: chi2 gate for rejection
    gate_probability: float | None = None  # EKF / iSAM2: reject innovations beyond this chi2 quantile
    init: str = "auto"  # batch first guess: "auto" (numba EKF, else prior) | "prior" (continuation)
    estimate: tuple[str, ...] = ()  # graph variables beyond the orbit state, e.g. ("refraction-bias",)
    prior_sigma: tuple = ()  # ((variable name, 1-sigma in its unit), ...): its prior instead of the registry's
    gravity: str = "j2"  # Earth's field in the motion model, one of GRAVITY_MODELS
    state: str = "cartesian"  # the orbit's coordinates: "cartesian" | "elements" (state_elements)
    centre: str = "earth"  # the pass's central body (the log's "# centre:" line), one of CENTRES

    def __post_init__(self):
        if self.gravity not in GRAVITY_MODELS:
            raise UserError(f"gravity (--gravity): expected one of {', '.join(GRAVITY_MODELS)}, "
                            f"found {self.gravity!r}")
        check_state(self.state)
        if self.centre not in CENTRES:
            raise UserError(f"centre: expected one of {', '.join(CENTRES)}, found {self.centre!r}")

    def motion_model(self) -> MotionModel:
        if self.centre == "sun":  # a cruise: the Sun and the planets, whatever the options
            kw = {} if self.max_step_s is None else {"max_step_s": self.max_step_s}
            return MotionModel.heliocentric(**kw)
        kw = {"third_body": self.third_body}
        if self.gravity == "point-mass":
            kw["j2"] = 0.0  # the kernels' J2 term vanishes: -mu r/|r|^3 alone
        if self.max_step_s is not None:
            kw["max_step_s"] = self.max_step_s
        return MotionModel(**kw)


@dataclass(frozen=True)
class IncrementalOptions:
    relinearize_position_m: float = 1000.0
    relinearize_velocity_mps: float = 1.0
    relinearize_rotation_rad: float = 0.01  # a further Rot3 variable (the attitude)
    partial_relinearization_check: bool = True  # check only the states the update touched
    relinearize_skip: int = 1
    lag_s: float = 300.0
    harvest_s: float = 60.0  # fixed-lag: smoothed states are read out in blocks this long
    wildfire_threshold: float = 100.0  # back-substitution stops below this update (SI units)
    relinearize_window_s: float | None = None  # iSAM2: states older than this are held
    # at their linearization point (None: every state may be relinearized); see
    # relinearizing_links

    def __post_init__(self):
        if not (self.lag_s > 0 and self.harvest_s >= 0):
            raise UserError(f"fixed-lag smoother: the lag must be > 0 s and the harvest block "
                            f">= 0 s, got lag {self.lag_s} s, harvest {self.harvest_s} s")


# ------------------------------------------------------- tolerances for inter-satellite links

def relinearizing_links(p, inc: IncrementalOptions | None = None) -> IncrementalOptions:
    """``inc`` (default :class:`IncrementalOptions`) with a position threshold that keeps a
    link's linearization error below a tenth of its sigma: moving an end by ``d`` across the
    line of sight changes the range by ``d^2 / (2 rho)``, so ``d <= sqrt(0.2 rho sigma)``
    (45 mm for 10 um carrier phase over 1 km; 1.4 m for 1 cm code), and the
    back-substitution's wildfire threshold no coarser; unchanged for a pass ``p`` without
    links. At the defaults (1 km, 100 m) a carrier pass's online estimates jumped to errors
    of 16 km - 1,700 km at some epochs (120 m RMS with these, as without the carrier).

    A threshold that fine is crossed by the absolute orbits' updates (metres at every epoch
    while the celestial rows refine km-sigma orbits), although a shift common to both ends
    leaves a link's linearization exact: every state was relinearized at every update, and
    iSAM2 cost O(N^2) (a 2 h formation-gto pass at 10 s: 72x batch's time). So the states
    more than :data:`RELINEARIZE_WINDOW_EPOCHS` median steps old are held at their
    linearization point (``relinearize_window_s``; by then their own epoch's links have
    fixed the relative state); the final trajectory is polished by Gauss-Newton over the
    whole chain regardless (:func:`fgnav.solvers.incremental.polish_chain`)."""
    inc = IncrementalOptions() if inc is None else inc
    d = [float(np.min(np.sqrt(0.2 * np.abs(p.families[k].values["rho_m"]) * p.families[k].sigma)))
         for k in ISL_KINDS if k in p.families]
    if not d or min(d) >= inc.relinearize_position_m:
        return inc
    scale = min(d) / inc.relinearize_position_m
    return replace(inc, relinearize_position_m=inc.relinearize_position_m * scale,
                   relinearize_velocity_mps=inc.relinearize_velocity_mps * scale,
                   wildfire_threshold=min(inc.wildfire_threshold, min(d)),
                   relinearize_window_s=RELINEARIZE_WINDOW_EPOCHS * float(np.median(np.diff(p.t_s)))
                   if p.n_epochs > 1 else None)


RELINEARIZE_WINDOW_EPOCHS = 5
"""iSAM2 with inter-satellite links: for how many (median) steps a state may still be
relinearized (:func:`relinearizing_links`). Measured on a 2 h formation-gto pass at 10 s:
30 steps cost 8.9x batch's CPU time, 6 steps 5.1x; on a carrier-phase pass at 60 s, one
step let the online estimates jump by 460 km, 5 steps kept them within 115 m (as 300 s
did)."""


CHI2_TOLERANCE = 1e-8
"""A formation's Gauss-Newton also stops when the cost changed by at most this fraction in an
iteration (its steps on km-sigma absolute orbits keep a jitter above a carrier's microns:
with the step tests alone every carrier pass of 2 h or more ran to the iteration limit)."""


def converging_to_links(p, options: SmootherOptions) -> SmootherOptions:
    """``options`` with the Gauss-Newton step tolerances below a tenth of the finest link's
    sigma in pass ``p`` (and the relative one on the marginal sigmas scaled alike: the
    absolute sigmas are metres where the relative state is known to microns); unchanged
    without links. The defaults would stop a carrier-phase pass (10 um) with its residuals
    4x their sigma (measured: chi2/dof 14 on the carrier rows)."""
    sig = [float(np.min(p.families[k].sigma)) for k in ISL_KINDS if k in p.families]
    if not sig or 0.1 * min(sig) >= options.tol_position_m:
        return options
    scale = 0.1 * min(sig) / options.tol_position_m
    return replace(options, tol_position_m=options.tol_position_m * scale,
                   tol_velocity_mps=options.tol_velocity_mps * scale,
                   tol_sigma=options.tol_sigma * scale, tol_chi2_relative=CHI2_TOLERANCE)
