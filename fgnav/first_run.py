"""The one-line notice printed while numba compiles fgnav's kernels for the first time.

fgnav's numerical kernels are ``@njit(cache=True)``: the first run on a machine (or after
an upgrade) compiles them, ~20 s, and later runs load them from numba's on-disk cache in a
fraction of a second. A numba event listener (``numba.core.event.register``, "numba:compile") is
told of a compilation only when the cache had no valid entry, so the notice appears exactly
on a cold cache, once per process, and never on a warm run.
"""

from __future__ import annotations

import sys

from factors.jit import when_numba_loads

MESSAGE = "fgnav: compiling numerical kernels (first run only, ~20 s)..."

_installed = False


PACKAGES = ("fgnav", "factors")


def _ours(dispatcher, packages) -> bool:
    """A cached kernel (``cache=True``) of one of ``packages`` (not numba's own helpers)."""
    mod = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    cache = type(getattr(dispatcher, "_cache", None)).__name__
    return mod.split(".")[0] in packages and cache != "NullCache"


def announce_first_compile(stream=None, packages=PACKAGES) -> None:
    """Print :data:`MESSAGE` on ``stream`` (default stderr) when, and the first time that, a
    cached kernel of ``packages`` (fgnav's) is compiled in this process. Idempotent."""
    global _installed
    if _installed:
        return
    _installed = True

    # numba is imported at the first compiled call (factors.jit), not before: listen from then
    when_numba_loads(lambda: _listen(stream, packages))


def _listen(stream, packages) -> None:
    from numba.core import event

    class _Notice(event.Listener):
        done = False

        def on_start(self, ev):
            if not self.done and _ours(ev.data.get("dispatcher"), packages):
                self.done = True
                out = stream if stream is not None else sys.stderr
                print(MESSAGE, file=out, flush=True)

        def on_end(self, ev):
            pass

    event.register("numba:compile", _Notice())
