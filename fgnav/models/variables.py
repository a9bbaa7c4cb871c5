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

A variable carries both as objects, so that the graph's builders (:mod:`fgnav.graph`) and the
solvers never test a manifold's name or a variable's identity: ``Variable.manifold``
(:data:`VECTOR`, :data:`ROT3`: retraction, GTSAM value, prior residual, random-walk residual
and factor) and ``Variable.process`` (:data:`MOTION` for an orbit, :data:`RANDOM_WALK`, or
:class:`ConstantRate` for a rate that turns a rotation: ``factors.attitude_motion``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from factors.attitude import attitude_residual
from factors.attitude_motion import constant_rate_residual, constant_rate_sqrt_information
from factors.attitude_motion import make_constant_rate_factor
from factors.geometry import so3_exp, so3_log
from factors.random_walk import (make_random_walk_factor, make_rot3_prior_factor,
                                 make_rot3_random_walk_factor, make_vector_prior_factor,
                                 random_walk_residual, rot3_random_walk_residual)

__all__ = ["Variable", "Layout", "ORBIT", "CONSTANT_PSD_FLOOR", "orbit_variable", "clock_variable",
           "ambiguity_variable", "spacecraft_variable", "CLOCK_PSD_M2_S", "CLOCK_PRIOR_SIGMA_M",
           "AMBIGUITY_PRIOR_SIGMA_M",
           "Manifold", "VECTOR", "ROT3", "MANIFOLDS", "Process", "MOTION", "RANDOM_WALK",
           "ConstantRate"]

CONSTANT_PSD_FLOOR = 1e-18
"""A random walk's spectral density (unit^2/s) never goes below this: a "constant" variable is
a random walk whose per-step sigma is ~1e-9 units over an hour, which leaves the chain's
conditionals invertible (an exact equality would give GTSAM's QR a zero-noise row)."""



class Manifold:
    """Where a variable's values live; stored in a block as ``dim`` floats (tangent
    coordinates). Compares equal to its name (``"vector"``, ``"rot3"``), as the string it
    replaces did."""

    name = ""
    additive = True      # retract(x, dx) is x + dx
    gtsam_type = "Vector"   # gtsam.Values.at<type> / calculateEstimate<type>

    def __eq__(self, other):
        if isinstance(other, str):
            return other == self.name
        return isinstance(other, Manifold) and other.name == self.name

    def __hash__(self):
        return hash(self.name)

    def __repr__(self):
        return repr(self.name)

    def __str__(self):
        return self.name


class VectorSpace(Manifold):
    """R^d: ``x (+) dx = x + dx``."""

    name = "vector"

    def retract(self, x, dx):
        return x + dx

    def exp(self, x):
        """The values as a measurement model receives them: the vector itself."""
        return x

    def local(self, x_ref, x):
        """The tangent vector from ``x_ref`` to ``x`` (an error): ``x - x_ref``."""
        return x - x_ref

    def to_gtsam(self, x):
        return np.asarray(x, dtype=float)

    def from_gtsam(self, value):
        return np.asarray(value, dtype=float)

    def prior_residual(self, x, mean):
        """``e = x - mean`` (M, d), ``H = I`` (M, d, d) of a prior ``x ~ N(mean, sigma^2 I)``."""
        x = np.asarray(x, dtype=float)
        return x - mean, np.broadcast_to(np.eye(x.shape[-1]), x.shape + (x.shape[-1],))

    def prior_factor(self, key, dim, mean, sigma):
        return make_vector_prior_factor(key, np.full(dim, mean), sigma)

    def random_walk_residual(self, x0, x1):
        """``b_{k+1} = b_k + w``: ``e = b_1 - b_0``, ``H0 = -I``, ``H1 = I``
        (``factors.random_walk``)."""
        return random_walk_residual(x0, x1)

    def random_walk_factor(self, key0, key1, sigma, dim):
        return make_random_walk_factor(key0, key1, sigma, dim)


class Rot3Manifold(Manifold):
    """SO(3), stored as the rotation vector ``w`` of ``R = Exp(w)``; ``R (+) dw = R Exp(dw)``,
    GTSAM's ``Rot3.retract`` (right perturbation; Sola, Deray & Atchuthan 2018, eq. 25)."""

    name = "rot3"
    additive = False
    gtsam_type = "Rot3"

    def retract(self, x, dx):
        return so3_log(so3_exp(x) @ so3_exp(dx))

    def exp(self, x):
        """The values as a measurement model receives them: rotation matrices (M, 3, 3)."""
        return so3_exp(x)

    def local(self, x_ref, x):
        """The tangent vector from ``x_ref`` to ``x``: ``Log(R_ref^T R)`` (the right
        perturbation ``R = R_ref Exp(e)``; not a difference of rotation vectors)."""
        return so3_log(np.swapaxes(so3_exp(x_ref), -1, -2) @ so3_exp(x))

    def to_gtsam(self, x):
        import gtsam
        return gtsam.Rot3.Expmap(np.asarray(x, dtype=float))

    def from_gtsam(self, value):
        import gtsam
        return gtsam.Rot3.Logmap(value)

    def prior_residual(self, x, mean):
        """A prior about the identity, ``Log(R) ~ N(0, sigma^2 I)``: ``e = Log(R)``,
        ``H = Jr^-1(e)`` (``factors.attitude.attitude_residual``; ``mean`` is not used)."""
        x = np.asarray(x, dtype=float)
        R = so3_exp(x)
        return attitude_residual(R, np.broadcast_to(np.eye(3), R.shape))

    def prior_factor(self, key, dim, mean, sigma):
        return make_rot3_prior_factor(key, np.eye(3), sigma)

    def random_walk_residual(self, x0, x1):
        """``R_{k+1} = R_k Exp(w)``: ``e = Log(R_0^T R_1)`` (``factors.random_walk``)."""
        return rot3_random_walk_residual(so3_exp(x0), so3_exp(x1))

    def random_walk_factor(self, key0, key1, sigma, dim):
        return make_rot3_random_walk_factor(key0, key1, sigma)


VECTOR = VectorSpace()
ROT3 = Rot3Manifold()
MANIFOLDS = {m.name: m for m in (VECTOR, ROT3)}


class Process:
    """A variable's process model between consecutive epochs.

    ``group(v, lay)``: the names of the variables whose rows (and GTSAM factor) this process
    writes jointly, ``()`` when another variable's process writes ``v``'s, None when ``v`` is
    not a parameter's (an orbit: the motion model's, :func:`fgnav.graph.motion_rows`)."""

    name = ""

    def __repr__(self):
        return self.name


class Motion(Process):
    """An orbit state's: the motion model (``factors.motion``), built by
    :func:`fgnav.graph.motion_rows` / :func:`fgnav.graph.motion_factors`."""

    name = "motion"

    def group(self, v, lay):
        return None


class RandomWalk(Process):
    """``b_{k+1} = b_k (+) w``, ``w ~ N(0, psd dt I)`` (Maybeck 1979, vol. 1, sec. 4.10) on the
    variable's manifold; the step's whitened residual ``e / sqrt(psd dt)``."""

    name = "random_walk"

    def group(self, v, lay):
        for u in lay.parameters:   # turned by another variable's process (a rate)
            if u is not v and v.name in u.process.turns_names(u, lay):
                return ()
        return (v.name,)

    def turns_names(self, v, lay):
        return ()

    def residual(self, lay, names, X0, X1, dt):
        """``(e (S, d), H0, H1 (S, d, d), W (S, d, d))`` of the step rows ``W (H0 d0 + H1 d1 +
        e)`` on the one variable ``names[0]``."""
        v = lay.variable(names[0])
        sl = lay.slices[v.name]
        e, H0, H1 = v.manifold.random_walk_residual(X0[:, sl], X1[:, sl])
        return e, H0, H1, 1.0 / v.step_sigma(dt)

    def factor(self, lay, names, k, dt):
        v = lay.variable(names[0])
        return v.manifold.random_walk_factor(v.key(k - 1), v.key(k), float(v.step_sigma(dt)),
                                             v.dim)

    def predict(self, lay, names, x_prev, guess, dt):
        """The mean at the next epoch: held (nothing to write)."""

    def step_covariance(self, v, dt):
        """The step's covariance (d, d): ``psd dt I``."""
        return np.eye(v.dim) * float(v.step_sigma(dt)) ** 2


class ConstantRate(RandomWalk):
    """A body rate ``omega`` that turns the rotation variable ``turns``: ``R_{k+1} = R_k
    Exp(omega_k dt)``, ``omega_{k+1} = omega_k + w`` with white angular acceleration of the
    rate's ``psd`` (``factors.attitude_motion``), one 6-row factor per step on (R, omega) of
    both epochs. Without the rotation variable in the layout, the rate is a random walk."""

    name = "constant_rate"

    def __init__(self, turns: str):
        self.turns = turns

    def __repr__(self):
        return f"constant_rate(turns={self.turns!r})"

    def __eq__(self, other):
        return isinstance(other, ConstantRate) and other.turns == self.turns

    def __hash__(self):
        return hash((self.name, self.turns))

    def turns_names(self, v, lay):
        return (self.turns,) if lay.has(self.turns) else ()

    def group(self, v, lay):
        return (self.turns, v.name) if lay.has(self.turns) else (v.name,)

    def _rate(self, lay, names):
        return lay.variable(names[1])

    def residual(self, lay, names, X0, X1, dt):
        """``(e (S, 6), H0, H1 (S, 6, 6), W (S, 6, 6))`` on [rotation; rate]
        (``constant_rate_residual``, ``constant_rate_sqrt_information``)."""
        if len(names) == 1:
            return super().residual(lay, names, X0, X1, dt)
        w = self._rate(lay, names)
        sa, sw = lay.slices[names[0]], lay.slices[names[1]]
        e, H_R0, H_w0, H_R1, H_w1 = constant_rate_residual(
            so3_exp(X0[:, sa]), X0[:, sw], so3_exp(X1[:, sa]), X1[:, sw], dt)
        W = constant_rate_sqrt_information(dt, max(w.psd, CONSTANT_PSD_FLOOR))
        return (e, np.concatenate([H_R0, H_w0], axis=-1), np.concatenate([H_R1, H_w1], axis=-1),
                W)

    def factor(self, lay, names, k, dt):
        if len(names) == 1:
            return super().factor(lay, names, k, dt)
        a, w = lay.variable(names[0]), self._rate(lay, names)
        return make_constant_rate_factor(a.key(k - 1), w.key(k - 1), a.key(k), w.key(k), dt,
                                         max(w.psd, CONSTANT_PSD_FLOOR))

    def predict(self, lay, names, x_prev, guess, dt):
        """The rotation turned at its rate since the last epoch: ``R Exp(omega dt)``."""
        if len(names) == 1:
            return
        sa, sw = lay.slices[names[0]], lay.slices[names[1]]
        guess[sa] = so3_log(so3_exp(x_prev[sa]) @ so3_exp(x_prev[sw] * dt))


MOTION = Motion()
RANDOM_WALK = RandomWalk()


@dataclass(frozen=True)
class Variable:
    """A type of per-epoch graph variable.

    name : identifier (``orbit``, ``refraction_bias``; the CLI writes it with dashes).
    symbol : GTSAM symbol character of its keys (``x``: ``X(k)``).
    dim : tangent-space dimension.
    unit : unit of its components.
    manifold : :data:`VECTOR` or :data:`ROT3` (or their names, ``"vector"``, ``"rot3"``).
    components : names of the components (messages, CSV columns).
    psd : random-walk spectral density (unit^2/s) between epochs (not used by the orbit).
    prior_sigma : 1-sigma of its prior at the first epoch (unit); prior_mean its mean.
    description : one line for help texts and outputs.
    orbit : an orbit state ``[r_eci_m; v_eci_mps]`` (its process model is the motion model,
        its priors the log's prior rows): :data:`ORBIT`, and in a formation's graph one per
        further spacecraft (:func:`orbit_variable`).
    index : told apart from the other variables of its symbol in the key (a formation's
        orbits share ``x``).
    process : its process model between epochs (:data:`MOTION` for an orbit,
        :data:`RANDOM_WALK` by default, :class:`ConstantRate`).
    """

    name: str
    symbol: str
    dim: int
    unit: str
    manifold: Manifold = VECTOR
    components: tuple[str, ...] = ()
    psd: float = 0.0
    prior_sigma: float = 1.0
    prior_mean: float = 0.0
    description: str = ""
    orbit: bool = False
    index: int = 0
    process: Process | None = None

    def __post_init__(self):
        if isinstance(self.manifold, str):
            if self.manifold not in MANIFOLDS:
                raise ValueError(f"variable {self.name}: manifold {self.manifold!r} is none of "
                                 f"{', '.join(MANIFOLDS)}")
            object.__setattr__(self, "manifold", MANIFOLDS[self.manifold])
        if self.process is None:
            object.__setattr__(self, "process", MOTION if self.orbit else RANDOM_WALK)

    def prior_rows(self, x0):
        """Whitened prior rows at the first epoch's value ``x0`` (d,): ``(A (d, d), b (d,))``,
        ``|A dx - b|^2`` with ``A = H / prior_sigma``, ``b = -e / prior_sigma`` of the
        manifold's prior residual (``b_0 ~ N(prior_mean, prior_sigma^2)``; a rotation about the
        identity, ``factors.random_walk.make_rot3_prior_factor``)."""
        e, H = self.manifold.prior_residual(np.asarray(x0, dtype=float)[None], self.prior_mean)
        return H[0] / self.prior_sigma, -e[0] / self.prior_sigma

    def prior_factor(self):
        """The GTSAM factor of the same prior on ``key(0)``."""
        return self.manifold.prior_factor(self.key(0), self.dim, self.prior_mean, self.prior_sigma)

    def prior_covariance(self) -> np.ndarray:
        """The prior's covariance (d, d) in the tangent space at its mean: ``prior_sigma^2 I``
        (a filter's initial covariance)."""
        return np.eye(self.dim) * self.prior_sigma ** 2

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


def spacecraft_variable(v: Variable, i: int, spacecraft_id: str) -> Variable:
    """A formation's spacecraft ``i``'s own copy of the per-spacecraft variable ``v`` (an
    attitude): ``v`` itself for spacecraft 0, as :func:`orbit_variable` keeps :data:`ORBIT`;
    else ``<name>_<id>``, its components suffixed, told apart by ``index``."""
    if i == 0:
        return v
    return replace(v, name=f"{v.name}_{spacecraft_id}",
                   components=tuple(f"{c}_{spacecraft_id}" for c in v.components),
                   description=f"{v.description} (spacecraft {spacecraft_id})", index=i)


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
    locked (Xing et al.'s float ambiguity; a constant is a random walk of zero ``psd``,
    Maybeck 1979, sec. 4.10)."""
    return Variable(f"ambiguity_{name}", "n", 1, "m", components=(f"ambiguity_{name}_m",),
                    psd=0.0, prior_sigma=AMBIGUITY_PRIOR_SIGMA_M, index=index,
                    description=f"carrier-phase ambiguity of link {name}, m (constant)")


@dataclass(frozen=True)
class Layout:
    """The variables of one epoch's block, in order (the orbit first), and their columns."""

    variables: tuple[Variable, ...] = (ORBIT,)
    slices: dict = field(init=False, compare=False, repr=False)
    n: int = field(init=False, compare=False)
    groups: tuple = field(init=False, compare=False, repr=False)

    def __post_init__(self):
        if not self.variables or self.variables[0] != ORBIT:
            raise ValueError("a layout starts with the orbit state")
        sl, i = {}, 0
        for v in self.variables:
            sl[v.name] = slice(i, i + v.dim)
            i += v.dim
        object.__setattr__(self, "slices", sl)
        object.__setattr__(self, "n", i)
        object.__setattr__(self, "groups", self._process_groups())

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

    def variable(self, name: str) -> Variable:
        """The variable ``name`` of the block."""
        for v in self.variables:
            if v.name == name:
                return v
        raise KeyError(name)

    def _process_groups(self) -> tuple[tuple[Variable, tuple[str, ...]], ...]:
        """``groups``: the processes of the parameters (not the orbits), each with the names of the
        variables it writes: ``(owner, names)``, the joint ones (a rate turning the attitude)
        first, then one per random walk in the block's order."""
        groups = []
        for v in self.parameters:
            names = v.process.group(v, self)
            if names:
                groups.append((v, names))
        return tuple(sorted(groups, key=lambda g: -len(g[1])))

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
            if not v.manifold.additive:
                sl = self.slices[v.name]
                out[..., sl] = v.manifold.retract(X[..., sl], dX[..., sl])
        return out

    def local(self, X_ref: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The tangent vector from ``X_ref`` to ``X`` per variable, the inverse of
        :meth:`retract` (vectors subtract, rotations ``Log(R_ref^T R)``)."""
        out = X - X_ref
        for v in self.variables:
            if not v.manifold.additive:
                sl = self.slices[v.name]
                out[..., sl] = v.manifold.local(X_ref[..., sl], X[..., sl])
        return out

    def values_at(self, X: np.ndarray, k: np.ndarray) -> dict[str, np.ndarray]:
        """Each variable's values at the epochs ``k``: name -> (M, dim) (rotations as (M, 3, 3))."""
        out = {}
        for v in self.variables:
            out[v.name] = v.manifold.exp(X[k, self.slices[v.name]])
        return out
