"""The orbital-element state parameterization of the solvers (``--state elements``).

The solvers keep one Cartesian orbit state per epoch and linearize in its components (the
default, ``--state cartesian``). With ``--state elements`` the orbit's coordinates become the
modified equinoctial elements ``E = (p, f, g, h, k, L)`` (:mod:`factors.elements`; Walker,
Ireland & Owens 1985): every Cartesian row, measurement and motion alike, is evaluated at
``x = c(E)`` and its orbit columns are chained with the analytic ``dc/dE``,

    A_E = A_x dc/dE,           (the motion rows: W [-Phi dc/dE_k,  dc/dE_{k+1}])

the update is applied to the elements, ``x <- c(e(x) + dE)``, and covariances are carried
in the elements and reported in Cartesian, ``P_x = (dc/dE) P_E (dc/dE)^T``. The elements are
a global chart, so a covariance in them needs no transport when the estimate moves.

The solvers store ``x = c(E)`` rather than ``E`` (the same point: ``c`` is a bijection away
from the retrograde equatorial orbit), so the measurement models, the first guesses and the
outputs are untouched. The motion model propagates the Cartesian state (RK4, the same flow);
the elements' transition matrix is the chain ``Phi_E = (dc/dE_{k+1})^-1 Phi (dc/dE_k)`` and
the white-acceleration process noise maps as ``Q_E = (dc/dE)^-1 Q (dc/dE)^-T`` at the step's
end, whose velocity block is the matrix of Gauss's variational equations
(:func:`factors.elements.gauss_variational_equations`, Battin 1999, "An Introduction to the
Mathematics and Methods of Astrodynamics", sec. 10.4): the white acceleration enters the
elements through Gauss's equations.

What changes: the Gauss-Newton steps and the EKF's measurement update are taken along
straight lines in the elements (curved in Cartesian space: an along-track correction follows
the orbit); the batch cost function is the same function of the trajectory, so its minimum
is the same (docs/elements.md).
"""

from __future__ import annotations

import math

import numpy as np

from factors.elements import cartesian_from_mee, mee_from_cartesian
from factors.errors import ModelDomainError
from fgnav.errors import UserError

STATES = ("cartesian", "elements")
"""The orbit state parameterizations (``--state``)."""

ELEMENT_METHODS = ("batch", "ekf")
"""The methods that offer ``--state elements``."""


def check_state(state: str, method: str | None = None) -> None:
    """``UserError`` for an unknown ``--state`` or a method without the element state."""
    if state not in STATES:
        raise UserError(f"state (--state): expected one of {', '.join(STATES)}, found {state!r}")
    if state == "elements" and method is not None and method not in ELEMENT_METHODS:
        raise UserError(f"--state elements is available for --method "
                        f"{' and '.join(ELEMENT_METHODS)}, not {method}; use --state cartesian "
                        f"with {method}")


def chart_of(options):
    """The element chart for ``options.state == "elements"``, else None (Cartesian)."""
    return ElementChart() if getattr(options, "state", "cartesian") == "elements" else None


FILTER_RETROGRADE_MARGIN_DEG = 2.0
"""The EKF refuses the element state for an orbit inclined within this many degrees of 180
deg (:meth:`ElementChart.check_filter_start`)."""


def inclination_deg(x: np.ndarray) -> float:
    """The inclination (deg) of the Cartesian state ``x`` (>= 6,), from ``h = r x v``."""
    h = np.cross(x[:3], x[3:6])
    return float(np.degrees(np.arccos(np.clip(h[2] / np.linalg.norm(h), -1.0, 1.0))))


class ElementChart:
    """Modified equinoctial elements as the coordinates of the orbit block (the first six
    columns of each epoch's block; further variables keep their own)."""

    name = "elements"

    @staticmethod
    def check_filter_start(x: np.ndarray) -> None:
        """``UserError`` when the filter would start within
        :data:`FILTER_RETROGRADE_MARGIN_DEG` of the retrograde equatorial orbit, where the
        elements are singular (``h, k`` grow as ``tan(i/2)``; Walker et al. 1985): the EKF's
        linearization in them fails there (gto-transfer's sensor on a LEO, prior 1 km: NEES
        15 at 1 deg from it, 186 at 0.5 deg, 494 at 0.1 deg, against 7.3-7.4 in Cartesian,
        with the verdict ok; 7.45 at 2 deg). The batch, whose minimum is the same in either
        chart, is not refused."""
        inc = inclination_deg(x)
        if 180.0 - inc < FILTER_RETROGRADE_MARGIN_DEG:
            raise UserError(
                f"--state elements with --method ekf: the orbit is inclined {inc:.2f} deg, "
                f"within {FILTER_RETROGRADE_MARGIN_DEG:g} deg of the retrograde equatorial "
                f"orbit, where the equinoctial elements are singular (tan(i/2) = "
                f"{math.tan(math.radians(inc) / 2):.3g}) and the filter's covariance stops "
                f"telling the truth; use --state cartesian, or --method batch (the same "
                f"solution in both)")

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """``dc/dE`` (..., 6, 6) at the block values ``X`` (..., n) (Cartesian orbit first)."""
        return self._eval(X)[1]

    @staticmethod
    def _eval(X):
        E = _elements(X[..., :6])
        return E, cartesian_from_mee(E)[1]

    def chain(self, A: np.ndarray, J: np.ndarray) -> np.ndarray:
        """Rows ``A`` (..., m, n) in Cartesian orbit columns -> element columns
        (``A[..., :6] @ J``, ``J`` (..., 6, 6) broadcast against the rows)."""
        out = np.array(A, dtype=float, copy=True)
        out[..., :6] = A[..., :6] @ J
        return out

    def retract(self, lay, X: np.ndarray, dX: np.ndarray) -> np.ndarray:
        """``X (+) dX`` with the orbit updated in the elements, ``c(e(x) + dE)``; the further
        variables by the layout's retraction."""
        out = lay.retract(X, dX)
        E = _elements(X[..., :6]) + dX[..., :6]
        p, f, g, L = E[..., 0], E[..., 1], E[..., 2], E[..., 5]
        w = 1.0 + f * np.cos(L) + g * np.sin(L)   # p/|r| (Walker et al. 1985, eq. 3)
        bad = ~((p > 0.0) & (w > 0.0))
        if np.any(bad):
            i = np.unravel_index(np.argmax(bad), bad.shape)
            raise ModelDomainError(
                f"--state elements: the update leaves the conics (semi-latus rectum p = "
                f"{p[i]:.4g} m, 1 + f cos L + g sin L = {w[i]:.4g}; both must be > 0)")
        out[..., :6] = cartesian_from_mee(E, jacobian=False)
        return out

    def covariance_to_cartesian(self, X: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Block covariances (..., n, n) in the elements -> in Cartesian (``T P T^T``,
        ``T = diag(dc/dE, I)``)."""
        return _congruence(self.jacobian(X), P)

    def covariance_from_cartesian(self, X: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Block covariances in Cartesian -> in the elements (``T^-1 P T^-T``)."""
        return _congruence(np.linalg.inv(self.jacobian(X)), P)

    def transition(self, x0: np.ndarray, x1: np.ndarray, Phi: np.ndarray, Q: np.ndarray):
        """The Cartesian step ``x1 = f(x0)``, its STM ``Phi`` and process noise ``Q`` (6, 6)
        in the elements: ``Phi_E = J1^-1 Phi J0``, ``Q_E = J1^-1 Q J1^-T``."""
        J0, J1 = self.jacobian(x0), self.jacobian(x1)
        J1inv = np.linalg.inv(J1)
        return J1inv @ Phi @ J0, _sym(J1inv @ Q @ J1inv.T)


def _elements(x):
    try:
        return mee_from_cartesian(x)
    except ValueError as exc:
        raise UserError(f"--state elements: {exc}; use --state cartesian for this orbit") from exc


def _sym(P):
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def _congruence(J, P):
    """``T P T^T`` with ``T = diag(J, I)`` on the block's orbit columns."""
    P = np.array(P, dtype=float, copy=True)
    n = P.shape[-1]
    T = np.broadcast_to(np.eye(n), P.shape).copy()
    T[..., :6, :6] = J
    return _sym(T @ P @ np.swapaxes(T, -1, -2))
