"""Run the compiled kernels' Python bodies instead of loading them from numba's cache.

Loading the first ``@njit(cache=True)`` kernel in a process costs ~0.5 s of numba set-up
(its type registries, and ``scipy.linalg`` for the BLAS check) and each further kernel
10-40 ms: more than a short pass takes to solve. Inside :func:`interpreted`, the wrappers that
call a kernel through :func:`run` execute the kernel's own Python source instead (the same
statements, so the same equations and numbers to rounding), with every kernel it calls
replaced by its Python body too; the batch hot path (``factors.dynamics.propagate_many``)
has a vectorized numpy form there. Compiled code stays the route for long passes.
"""

from __future__ import annotations

import math
import sys
import threading
import types
from contextlib import contextmanager

import numpy as np

__all__ = ["interpreted", "active", "run", "python_body"]

_state = threading.local()
_bodies: dict = {}

# ``math`` for array arguments: a kernel's body applied to arrays element-wise.
_ARRAY_MATH = types.SimpleNamespace(**{n: getattr(np, n) for n in ("sqrt", "sin", "cos", "floor", "ceil")},
                                    pi=math.pi)


def active() -> bool:
    """True inside :func:`interpreted` (in this thread)."""
    return getattr(_state, "on", False)


@contextmanager
def interpreted(on: bool = True):
    """Within the block, :func:`run` executes kernels as Python (``on=False``: compiled)."""
    before = active()
    _state.on = bool(on)
    try:
        yield
    finally:
        _state.on = before


def _is_kernel(obj) -> bool:
    return hasattr(obj, "py_func") and hasattr(obj, "signatures")


def python_body(kernel, arrays: bool = False):
    """The kernel's Python function with every kernel it calls (its globals that are numba
    dispatchers) replaced by their Python bodies, and ``prange`` by ``range``. ``arrays``:
    ``math`` functions replaced by numpy's, for kernels written component by component
    (``a[0] = s * rx``) applied to a whole array of epochs at once (components first)."""
    body = _bodies.get((kernel, arrays))
    if body is not None:
        return body
    py = kernel.py_func
    g = dict(py.__globals__)
    body = types.FunctionType(py.__code__, g, py.__name__, py.__defaults__, py.__closure__)
    _bodies[(kernel, arrays)] = body  # before recursing: kernels that call each other
    numba = sys.modules.get("numba")
    for name in py.__code__.co_names:
        value = g.get(name)
        if _is_kernel(value):
            g[name] = python_body(value, arrays)
        elif numba is not None and value is getattr(numba, "prange", None):
            g[name] = range
        elif arrays and value is math:
            g[name] = _ARRAY_MATH
    return body


def run(kernel, *args):
    """``kernel(*args)``, or its Python body inside :func:`interpreted`."""
    return python_body(kernel)(*args) if active() else kernel(*args)
