"""Progress for long commands (simulate, smooth, campaign): a thin ``tqdm`` wrapper.

On a terminal, a bar on stderr. When stderr is not a terminal (redirected, piped, CI logs,
batch jobs) a bar's carriage returns would be noise, so a long task reports as periodic log
lines instead, one every :data:`LOG_INTERVAL_S` seconds at most (``fgnav: smooth batch:
3/? iter, 41 s``); a task shorter than that prints nothing. ``quiet=True`` (the commands'
``--quiet``) silences both. stdout is never written (``--json`` consumers see nothing).
"""

from __future__ import annotations

import math
import sys
import time

LOG_INTERVAL_S = 10.0
"""Seconds between two progress lines when stderr is not a terminal."""


def stderr_is_tty() -> bool:
    """True when ``sys.stderr`` is an interactive terminal."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # closed or replaced stream
        return False


def log_line(text: str, quiet: bool = False) -> None:
    """One ``fgnav: ...`` progress line on stderr (a stage begun or ended), unless ``quiet``."""
    if not quiet:
        print(f"fgnav: {text}", file=sys.stderr, flush=True)


class LogProgress:
    """The ``tqdm`` calls fgnav uses (iteration, ``update``, ``set_postfix_str``, ``close``,
    context manager), reported as a log line at most every ``interval_s`` seconds, and a
    last line at ``close`` once any was printed."""

    def __init__(self, iterable=None, total=None, desc="", unit="it", interval_s=None):
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc, unit
        self.interval_s = LOG_INTERVAL_S if interval_s is None else float(interval_s)
        self.n = 0
        self.postfix = ""
        self.t0 = self.last = time.monotonic()
        self.printed = False
        self.closed = False

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update(1)
        self.close()

    def __len__(self):
        return self.total if self.total is not None else len(self.iterable)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _line(self, now: float, final=False) -> str:
        total = "?" if self.total is None else f"{self.total}"
        pct = f" ({100.0 * self.n / self.total:.0f}%)" if self.total else ""
        post = f", {self.postfix}" if self.postfix else ""
        end = ", done" if final else ""
        return (f"{self.desc + ': ' if self.desc else ''}{self.n}/{total} {self.unit}{pct}, "
                f"{now - self.t0:.0f} s{post}{end}")

    def update(self, n=1):
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.interval_s:
            self.last = now
            self.printed = True
            log_line(self._line(now))

    def set_postfix_str(self, s="", refresh=True):
        self.postfix = str(s)

    def set_postfix(self, ordered_dict=None, refresh=True, **kwargs):
        items = dict(ordered_dict or {}, **kwargs)
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_description(self, desc=None, refresh=True):
        self.desc = desc or ""

    def refresh(self):
        pass

    def close(self):
        if not self.closed and self.printed:
            log_line(self._line(time.monotonic(), final=True))
        self.closed = True


def progress(iterable=None, total=None, desc="", unit="it", quiet=False, **kwargs):
    """A progress report over ``iterable`` (or a manual one: ``total`` + ``.update(n)``).

    A ``tqdm`` bar when stderr is a terminal; periodic log lines (:class:`LogProgress`)
    when it is not; nothing (it still iterates and accepts ``update``/``set_postfix``/
    ``close``) when ``quiet``. Usable as a context manager. Extra keyword arguments go to
    ``tqdm`` (e.g. ``leave=False``).
    """
    if total is None and iterable is not None:
        try:
            total = len(iterable)
        except TypeError:
            total = None
    if quiet:  # never prints; without importing tqdm (~25 ms of a short run)
        return LogProgress(iterable, total=total, desc=desc, unit=unit, interval_s=math.inf)
    if not stderr_is_tty():
        return LogProgress(iterable, total=total, desc=desc, unit=unit)
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc or None, unit=unit, disable=bool(quiet),
                file=sys.stderr, dynamic_ncols=True, **kwargs)


class stage:
    """A context manager reporting a long step without iterations (reading a big log,
    writing the outputs): ``fgnav: <what>...`` when it begins and ``fgnav: <what>: done in
    T s`` when it ends, on stderr, when ``show`` (the caller judges the step long) and not
    ``quiet``."""

    def __init__(self, what: str, quiet: bool = False, show: bool = True):
        self.what, self.on = what, show and not quiet

    def __enter__(self):
        self.t0 = time.monotonic()
        if self.on:
            log_line(f"{self.what}...")
        return self

    def __exit__(self, exc_type, *exc):
        if self.on and exc_type is None:
            log_line(f"{self.what}: done in {time.monotonic() - self.t0:.1f} s")
        return False
