"""``njit`` that imports numba when a kernel is first called, not when its module is imported.

Importing numba takes ~0.3 s of CPU, a third of a short pass's whole run; the short passes
(:mod:`factors.interpret`) and the commands that compute nothing never call a compiled
kernel, so they need not pay it. ``@njit(cache=True)`` here returns a :class:`LazyKernel`
that keeps the function (``py_func``) and, on its first call, makes the numba dispatchers of
every lazy kernel at once (``numba.njit(**options)``, with numba's on-disk cache exactly as
before), and puts them in place of the lazy kernels in the loaded modules' globals, so that
compiled kernels calling each other see dispatchers. ``prange`` is ``range`` until numba is
loaded and ``numba.prange`` in compiled code.
"""

from __future__ import annotations

import sys

__all__ = ["njit", "prange", "LazyKernel", "load_numba", "numba_loaded", "when_numba_loads"]

prange = range
"""Placeholder for ``numba.prange`` (a parallel loop in compiled code, ``range`` in Python)."""

_kernels: list = []
_on_load: list = []
_loaded = False


class LazyKernel:
    """A kernel to compile with ``numba.njit(**options)`` at its first call."""

    def __init__(self, py_func, options):
        self.py_func = py_func
        self.options = options
        self.dispatcher = None
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__module__ = py_func.__module__
        self.__doc__ = py_func.__doc__
        _kernels.append(self)

    @property
    def signatures(self):
        return self.dispatcher.signatures if self.dispatcher is not None else []

    def __call__(self, *args):
        if self.dispatcher is None:
            load_numba()
        return self.dispatcher(*args)

    def __getattr__(self, name):  # dispatcher attributes (stats, inspect_types, ...)
        if name.startswith("__"):
            raise AttributeError(name)
        load_numba()
        return getattr(self.__dict__["dispatcher"], name)

    def __repr__(self):
        return f"<lazy numba kernel {self.__module__}.{self.__qualname__}>"


def njit(*args, **options):
    """``numba.njit`` deferred to the kernel's first call (``@njit`` or ``@njit(cache=True)``)."""
    def make(f):
        if _loaded:  # a module imported after numba was loaded
            import numba

            return numba.njit(**options)(f)
        return LazyKernel(f, options)

    if args and callable(args[0]) and not options:
        return make(args[0])
    return make


def when_numba_loads(callback) -> None:
    """Call ``callback()`` once numba is loaded for the kernels (now if it already is)."""
    if _loaded:
        callback()
    else:
        _on_load.append(callback)


def numba_loaded() -> bool:
    """Whether numba is loaded for the kernels (a compiled call then costs no start-up)."""
    return _loaded


def load_numba() -> None:
    """Import numba and give every lazy kernel its dispatcher (idempotent)."""
    global _loaded
    if _loaded:
        return
    import numba

    _loaded = True
    for callback in _on_load:
        callback()
    for k in _kernels:
        k.dispatcher = numba.njit(**k.options)(k.py_func)
    swap = {id(k): k.dispatcher for k in _kernels}
    for mod in list(sys.modules.values()):
        g = getattr(mod, "__dict__", None)
        if not isinstance(g, dict) or not (g.get("__name__") or "").startswith(("factors", "fgnav", "tests", "test_")):
            continue
        for name, value in list(g.items()):
            if isinstance(value, LazyKernel):
                g[name] = swap[id(value)]
            elif name == "prange" and value is range:
                g[name] = numba.prange
