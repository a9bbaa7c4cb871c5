"""Graph variables: what one epoch's block of the state holds, and how to update it.

Every epoch ``k`` carries one block of variables, the orbit state ``x_k = [r_eci_m; v_eci_mps]``
first, then the variables the measurement models of the pass declare and the user asks to
estimate (a slowly varying bias, an attitude, ...). The solvers work on the stacked tangent
vector of the block (``Layout.n`` numbers per epoch) and store the block's values in one
float array ``(N, n)``: a vector variable by its components, a ``Rot3`` by its rotation
vector (``R = Exp(w)``). An update ``dx`` is applied per variable by the variable's retraction
(``x + dx`` for vectors, ``Exp(w) Exp(dw)`` for rotations: the right perturbation GTSAM's
``Rot3.retract`` uses; Sola, Deray & Atchuthan 2018, "A micro Lie theory for state estimation
in robotics", eq. 25).

Between consecutive epochs each variable has a process model: the orbit its motion model
(``factors.motion``); a bias a random walk ``b_{k+1} = b_k + w``, ``w ~ N(0, psd dt)``
(``factors.random_walk``), with a prior ``N(prior_mean, prior_sigma^2)`` at the first epoch
(Maybeck 1979, "Stochastic Models, Estimation and Control", vol. 1, sec. 4.10: random
constants and random walks as shaping filters). ``psd = 0`` holds the variable constant over
the pass (implemented as a random walk of negligible ``psd``, see :data:`CONSTANT_PSD_FLOOR`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from factors.geometry import so3_exp, so3_log

__all__ = ["Variable", "Layout", "ORBIT", "CONSTANT_PSD_FLOOR", "orbit_variable", "clock_variable",
           "ambiguity_variable", "CLOCK_PSD_M2_S", "CLOCK_PRIOR_SIGMA_M", "AMBIGUITY_PRIOR_SIGMA_M"]

CONSTANT_PSD_FLOOR = 1e-18
"""A random walk's spectral density (unit^2/s) never goes below this: a "constant" variable is
a random walk whose per-step sigma is ~1e-9 units over an hour, which leaves the chain's
conditionals invertible (an exact equality would give GTSAM's QR a zero-noise row)."""


@dataclass(frozen=True)
class Variable:
    """A type of per-epoch graph variable.

    name : identifier (``orbit``, ``refraction_bias``; the CLI writes it with dashes).
    symbol : GTSAM symbol character of its keys (``x``: ``X(k)``).
    dim : tangent-space dimension.
    unit : unit of its components.
    manifold : ``"vector"`` or ``"rot3"``.
    components : names of the components (messages, CSV columns).
    psd : random-walk spectral density (unit^2/s) between epochs (not used by the orbit).
    prior_sigma : 1-sigma of its prior at the first epoch (unit); prior_mean its mean.
    description : one line for help texts and outputs.
    orbit : an orbit state ``[r_eci_m; v_eci_mps]`` (its process model is the motion model,
        its priors the log's prior rows): :data:`ORBIT`, and in a formation's graph one per
        further spacecraft (:func:`orbit_variable`).
    index : told apart from the other variables of its symbol in the key (a formation's
        orbits share ``x``).
    """

    name: str
    symbol: str
    dim: int
    unit: str
    manifold: str = "vector"
    components: tuple[str, ...] = ()
    psd: float = 0.0
    prior_sigma: float = 1.0
    prior_mean: float = 0.0
    description: str = ""
    orbit: bool = False
    index: int = 0

    @property
    def cli_name(self) -> str:
        return self.name.replace("_", "-")

    def key(self, k: int) -> int:
        """The GTSAM key of this variable at epoch ``k`` (``gtsam.Symbol(symbol, k)``; with an
        ``index`` the symbol's index carries it above bit 40: epochs below 2^40)."""
        return (ord(self.symbol) << 56) | (self.index << 40) | int(k)

    def step_sigma(self, dt_s):
        """1-sigma (unit) of the random-walk step over ``dt_s`` (s): ``sqrt(psd |dt|)``."""
        return np.sqrt(max(self.psd, CONSTANT_PSD_FLOOR) * np.abs(np.asarray(dt_s, dtype=float)))


ORBIT = Variable("orbit", "x", 6, "m, m/s", components=("x", "y", "z", "vx", "vy", "vz"),
                 description="orbit state [r_eci_m; v_eci_mps], EME2000", orbit=True)


def orbit_variable(i: int, spacecraft_id: str) -> Variable:
    """The orbit state of a formation's spacecraft ``i`` (0-based, in the log's order), named
    ``orbit_<id>``; spacecraft 0's is :data:`ORBIT` itself, so a one-spacecraft graph is
    unchanged."""
    if i == 0:
        return ORBIT
    return Variable(f"orbit_{spacecraft_id}", "x", 6, "m, m/s",
                    components=tuple(f"{c}_{spacecraft_id}" for c in ORBIT.components),
                    description=f"orbit state of spacecraft {spacecraft_id}, EME2000",
                    orbit=True, index=i)


CLOCK_PSD_M2_S = 1e-4
"""Spectral density (m^2/s) of the pair's relative clock bias c (dt_A - dt_B), a random walk:
1 cm per 1 s step, 0.6 m in an hour (two free-running oscillators of ~1e-11 Allan deviation)."""
CLOCK_PRIOR_SIGMA_M = 1e5
"""Prior 1-sigma of the relative clock bias at the first epoch (m): unknown (0.3 ms)."""
AMBIGUITY_PRIOR_SIGMA_M = 1e3
"""Prior 1-sigma of a carrier link's float ambiguity (m): unknown."""


def clock_variable(a: str, b: str, index: int) -> Variable:
    """The relative clock bias ``c (dt_a - dt_b)`` (m) of the spacecraft pair (a, b), a random
    walk of :data:`CLOCK_PSD_M2_S` (Xing et al.'s relative clock, per pair)."""
    return Variable(f"clock_{a}_{b}", "c", 1, "m", components=(f"clock_{a}_{b}_m",),
                    psd=CLOCK_PSD_M2_S, prior_sigma=CLOCK_PRIOR_SIGMA_M, index=index,
                    description=f"relative clock bias c (dt_{a} - dt_{b}), m (random walk)")


def ambiguity_variable(name: str, index: int) -> Variable:
    """The float carrier-phase ambiguity (m) of one link, constant while the link stays
    locked (as :mod:`fgnav.formation.smoother` treats it; a constant is a random walk of
    zero ``psd``, Maybeck 1979, sec. 4.10)."""
    return Variable(f"ambiguity_{name}", "n", 1, "m", components=(f"ambiguity_{name}_m",),
                    psd=0.0, prior_sigma=AMBIGUITY_PRIOR_SIGMA_M, index=index,
                    description=f"carrier-phase ambiguity of link {name}, m (constant)")


@dataclass(frozen=True)
class Layout:
    """The variables of one epoch's block, in order (the orbit first), and their columns."""

    variables: tuple[Variable, ...] = (ORBIT,)
    slices: dict = field(init=False, compare=False, repr=False)
    n: int = field(init=False, compare=False)

    def __post_init__(self):
        if not self.variables or self.variables[0] != ORBIT:
            raise ValueError("a layout starts with the orbit state")
        sl, i = {}, 0
        for v in self.variables:
            sl[v.name] = slice(i, i + v.dim)
            i += v.dim
        object.__setattr__(self, "slices", sl)
        object.__setattr__(self, "n", i)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.variables)

    @property
    def extra(self) -> tuple[Variable, ...]:
        """The variables after the orbit state."""
        return self.variables[1:]

    @property
    def orbits(self) -> tuple[Variable, ...]:
        """The orbit states of the block (one per spacecraft; :data:`ORBIT` first)."""
        return tuple(v for v in self.variables if v.orbit)

    @property
    def parameters(self) -> tuple[Variable, ...]:
        """The variables that are not orbit states (a bias, an attitude, a clock)."""
        return tuple(v for v in self.variables if not v.orbit)

    def with_prior_sigma(self, name: str, sigma: float) -> "Layout":
        """This layout with the variable ``name``'s prior 1-sigma replaced by ``sigma``."""
        return Layout(tuple(replace(v, prior_sigma=float(sigma)) if v.name == name else v
                            for v in self.variables))

    def has(self, name: str) -> bool:
        return name in self.slices

    def component_names(self) -> list[str]:
        out = []
        for v in self.variables:
            comps = v.components or tuple(f"{v.name}[{i}]" for i in range(v.dim))
            out += list(comps)
        return out

    def initial(self, x_orbit: np.ndarray) -> np.ndarray:
        """The block values (N, n) from orbit states (N, 6): other variables at their prior mean."""
        x_orbit = np.asarray(x_orbit, dtype=float)
        X = np.empty(x_orbit.shape[:-1] + (self.n,))
        X[..., :6] = x_orbit
        for v in self.extra:
            X[..., self.slices[v.name]] = v.prior_mean
        return X

    def retract(self, X: np.ndarray, dX: np.ndarray) -> np.ndarray:
        """``X (+) dX`` per variable (vectors add, rotations compose on the right)."""
        out = X + dX
        for v in self.variables:
            if v.manifold == "rot3":
                sl = self.slices[v.name]
                out[..., sl] = so3_log(so3_exp(X[..., sl]) @ so3_exp(dX[..., sl]))
        return out

    def values_at(self, X: np.ndarray, k: np.ndarray) -> dict[str, np.ndarray]:
        """Each variable's values at the epochs ``k``: name -> (M, dim) (rotations as (M, 3, 3))."""
        out = {}
        for v in self.variables:
            vals = X[k, self.slices[v.name]]
            if v.manifold == "rot3":
                vals = so3_exp(vals)
            out[v.name] = vals
        return out
