"""Options of the smoothers and filters (SI units): plain frozen dataclasses, no solver code.

They live apart from the solvers so that every solver (batch, iSAM2/fixed-lag, the EKFs) and
every caller can import them without importing another solver (and GTSAM with it).
"""

from __future__ import annotations

from dataclasses import dataclass

from factors.dynamics import MotionModel
from fgnav.defaults import DEFAULT_Q_M2_S3
from fgnav.errors import UserError
from fgnav.solvers.state_elements import check_state
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

    def __post_init__(self):
        if not (self.lag_s > 0 and self.harvest_s >= 0):
            raise UserError(f"fixed-lag smoother: the lag must be > 0 s and the harvest block "
                            f">= 0 s, got lag {self.lag_s} s, harvest {self.harvest_s} s")
