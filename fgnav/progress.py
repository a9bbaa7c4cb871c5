"""Progress bars for long commands (simulate, smooth, campaign): a thin ``tqdm`` wrapper.

Bars go to stderr and only when stderr is a terminal: redirected or piped runs, CI logs and
``--json`` consumers see nothing. ``quiet=True`` (the commands' ``--quiet``) silences them
on a terminal too.
"""

from __future__ import annotations

import sys


def stderr_is_tty() -> bool:
    """True when ``sys.stderr`` is an interactive terminal."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # closed or replaced stream
        return False


def progress(iterable=None, total=None, desc="", unit="it", quiet=False, **kwargs):
    """A ``tqdm`` progress bar over ``iterable`` (or a manual one: ``total`` + ``.update(n)``).

    Disabled (it still iterates and accepts ``update``/``set_postfix``/``close``) when
    ``quiet`` is true or stderr is not a terminal. Usable as a context manager.
    Extra keyword arguments go to ``tqdm`` (e.g. ``leave=False``).
    """
    from tqdm import tqdm

    if total is None and iterable is not None:
        try:
            total = len(iterable)
        except TypeError:
            total = None
    disable = bool(quiet) or not stderr_is_tty()
    return tqdm(iterable, total=total, desc=desc or None, unit=unit, disable=disable,
                file=sys.stderr, dynamic_ncols=True, **kwargs)
