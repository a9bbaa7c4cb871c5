"""Single-epoch relative position + clock from six inter-satellite pseudoranges.

Gauss–Newton least squares for the 4 unknowns ``(r, c dt)`` with ``r`` Cartesian
``(x, y, z)`` m or spherical ``(R m, az rad, el rad)`` (Xing et al. sections 1.4 and 2, its
``L = A X + V``). Reported with the normal matrix ``A^T A`` of the *unwhitened* design
matrix ``A`` (rows ``de/dx``; unit m/m for x, y, z, R, c dt and m/rad for az, el, exactly the
Xing et al.'s A and A'), its condition numbers, the cofactor ``(A^T A)^-1`` and the covariance
``sigma^2 (A^T A)^-1`` (m^2, rad^2, m rad).

Note on units: ``rcond(A^T A)`` depends on the units of the unknowns. Here metres for
positions, range and clock, radians for angles (Xing et al.'s choice, reproducing its
numbers). With angles in degrees the spherical columns shrink by pi/180 and rcond changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.pseudorange import (
    N_LINKS, cartesian_to_spherical, offset_range_residual, pseudorange_residual,
    pseudorange_residual_spherical, spherical_to_cartesian,
)
from fgnav.errors import UserError

__all__ = ["SingleEpochSolution", "LinkGeometry", "PARAMS", "design_matrix", "conditioning", "solve_single_epoch",
           "solve_single_epoch_many", "to_param", "from_param"]

PARAMS = ("cartesian", "spherical")


def _check_param(param):
    if param not in PARAMS:
        raise UserError(f"parameterization must be one of {PARAMS}, got {param!r}")


def to_param(r_m, param):
    """Cartesian ``r`` (..., 3) m -> the parameterization's position coordinates."""
    _check_param(param)
    r = np.asarray(r_m, dtype=float)
    return r.copy() if param == "cartesian" else cartesian_to_spherical(r)


def from_param(p, param):
    """Position coordinates of ``param`` (..., 3) -> Cartesian ``r`` (..., 3) m."""
    _check_param(param)
    p = np.asarray(p, dtype=float)
    if param == "cartesian":
        return p.copy()
    shp = p.shape
    return spherical_to_cartesian(p.reshape(-1, 3))[0].reshape(shp)


@dataclass(frozen=True)
class LinkGeometry:
    """The links of one epoch for any antennas (a logged epoch): ``offsets_m`` (L, 3) the
    antenna offsets ``d_l`` in the sat-1 body frame (range ``|r + d_l|``) and ``signs`` (L,)
    the clock signs ``s_l`` (:func:`factors.pseudorange.offset_range_residual`). Without
    it, the functions here use Xing et al.'s six links through ``M21``."""

    offsets_m: np.ndarray
    signs: np.ndarray


def _model(param, M21, links):
    """``f(p (K, 3), cdt (K,), z (K, L)) -> (e, H_p, H_c)`` in ``param`` coordinates."""
    _check_param(param)
    if links is None:
        f = pseudorange_residual if param == "cartesian" else pseudorange_residual_spherical
        return lambda p, c, z: f(p, c, z, M21)

    def g(p, c, z):
        if param == "cartesian":
            return offset_range_residual(p, c, z, links.offsets_m, links.signs)
        r, J = spherical_to_cartesian(p)
        e, H_r, H_c = offset_range_residual(r, c, z, links.offsets_m, links.signs)
        return e, H_r @ J, H_c

    return g


def design_matrix(x, M21, param, links: LinkGeometry | None = None):
    """Design matrix ``A = de/dx`` (L, 4) at ``x = [position coords (3), c dt m]`` (Xing et
    al.'s six links through ``M21``, or ``links``)."""
    x = np.asarray(x, dtype=float)
    n = N_LINKS if links is None else len(links.signs)
    _, H_p, H_c = _model(param, M21, links)(x[None, :3], x[None, 3], np.zeros((1, n)))
    return np.hstack([H_p[0], H_c[0]])


def conditioning(A):
    """Condition figures of the normal matrix ``N = A^T A``.

    Returns a dict: ``rcond`` = lambda_min / lambda_max of N (reciprocal 2-norm condition
    number), ``cond`` = 1 / rcond, ``rcond_1norm`` = 1 / (||N||_1 ||N^-1||_1) (what MATLAB's
    ``rcond`` estimates).
    """
    N = A.T @ A
    ev = np.linalg.eigvalsh(N)
    rcond = float(ev[0] / ev[-1])
    rc1 = float(1.0 / (np.linalg.norm(N, 1) * np.linalg.norm(np.linalg.inv(N), 1)))
    return {"rcond": rcond, "cond": 1.0 / rcond, "rcond_1norm": rc1}


@dataclass
class SingleEpochSolution:
    """One epoch's least-squares solution (all SI: m, rad)."""

    param: str
    x: np.ndarray            # (4,) position coordinates of `param` + c dt (m)
    r_m: np.ndarray          # (3,) Cartesian position of sat 2 in sat-1 body frame
    spherical: np.ndarray    # (3,) (R m, az rad, el rad)
    cdt_m: float
    A: np.ndarray            # (6, 4) unwhitened design matrix at the solution
    normal: np.ndarray       # (4, 4) A^T A
    cofactor: np.ndarray     # (4, 4) (A^T A)^-1 (covariance per unit variance)
    covariance: np.ndarray   # (4, 4) sigma^2 (A^T A)^-1
    rcond: float
    cond: float
    rcond_1norm: float
    iterations: int
    converged: bool

    @property
    def sigmas(self):
        """1-sigma of the 4 unknowns (m or rad)."""
        return np.sqrt(np.diag(self.covariance))


def solve_single_epoch(rho_meas_m, M21, param="spherical", x0=None, sigma_m=0.01,
                       max_iter=30, tol=1e-10, links: LinkGeometry | None = None):
    """Gauss–Newton for ``(r, c dt)`` from six pseudoranges of one epoch.

    Parameters
    ----------
    rho_meas_m : (6,) pseudoranges, m (link order of ``factors.pseudorange.link_offsets``).
    M21 : (3, 3) sat-2 body -> sat-1 body (known relative attitude).
    param : "cartesian" or "spherical".
    x0 : (4,) initial Cartesian ``[x, y, z, c dt]`` m; default Xing et al.'s ``R = 1992 m,
        az = el = 0, c dt = 0``.
    sigma_m : pseudorange noise (1 sigma, m) scaling the covariance.
    links : the links of a logged epoch (any antennas; ``M21`` is then unused).

    Returns
    -------
    SingleEpochSolution
    """
    x0 = np.array([1992.0, 0.0, 0.0, 0.0]) if x0 is None else np.asarray(x0, dtype=float)
    sol = solve_single_epoch_many(np.asarray(rho_meas_m, dtype=float)[None], M21, param,
                                  x0[None], max_iter=max_iter, tol=tol, links=links)
    x, it, conv = sol[0][0], int(sol[1]), bool(sol[2][0])
    A = design_matrix(x, M21, param, links)
    N = A.T @ A
    Qc = np.linalg.inv(N)
    cd = conditioning(A)
    r = from_param(x[:3], param)
    return SingleEpochSolution(param=param, x=x, r_m=r, spherical=cartesian_to_spherical(r),
                               cdt_m=float(x[3]), A=A, normal=N, cofactor=Qc,
                               covariance=sigma_m ** 2 * Qc, rcond=cd["rcond"], cond=cd["cond"],
                               rcond_1norm=cd["rcond_1norm"], iterations=it, converged=conv)


def solve_single_epoch_many(rho_meas_m, M21, param, x0_cart, max_iter=30, tol=1e-10,
                            links: LinkGeometry | None = None):
    """Vectorized Gauss–Newton over K independent epochs / Monte Carlo runs.

    ``rho_meas_m`` (K, 6); ``M21`` (3, 3) or (K, 3, 3); ``x0_cart`` (K, 4) Cartesian initial
    ``[r m, c dt m]``. Each step solves the 6x4 least squares by QR (not the normal
    equations). Returns ``(x (K, 4) in param coordinates, iterations, converged (K,))``.
    ``links``: the links of a logged epoch (:class:`LinkGeometry`; ``M21`` unused).
    """
    f = _model(param, M21, links)
    z = np.asarray(rho_meas_m, dtype=float)
    K = z.shape[0]
    x0 = np.asarray(x0_cart, dtype=float)
    x = np.concatenate([to_param(x0[:, :3], param), x0[:, 3:4]], axis=1)
    conv = np.zeros(K, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        e, H_p, H_c = f(x[:, :3], x[:, 3], z)
        A = np.concatenate([H_p, H_c], axis=2)
        Q, R = np.linalg.qr(A)
        dx = np.linalg.solve(R, -np.einsum("kji,kj->ki", Q, e)[..., None])[..., 0]
        x = x + dx
        scale = np.maximum(1.0, np.abs(x))
        conv = np.all(np.abs(dx) <= tol * scale, axis=1)
        if np.all(conv):
            break
    if param == "spherical":
        x[:, 1] = np.angle(np.exp(1j * x[:, 1]))
    return x, it, conv
