"""A measurement stream read as it arrives: CSV log format v1 (:mod:`fgnav.io.log_csv`), one
line at a time, from standard input or from a file another process appends to (read as
``tail -f`` does, from its start).

What a live stream brings is handled and counted, never fatal after the header: a malformed
or invalid line is reported (naming the input line, by the offline reader's row rules,
:func:`fgnav.io.log_csv.parse_line`) and skipped; an exact duplicate of a row is ignored; a
row that arrives up to ``reorder_window_s`` behind the newest epoch is kept for its epoch
(an epoch already completed gets it as a late row), a row later than that is reported and
dropped; a last line without its newline at the end of input (a torn write) is reported
and dropped. An epoch is complete when a row of a later epoch arrives, or at the end of
input.
"""

from __future__ import annotations

import math
import os
import select
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import CENTRE_LINE, CENTRES, check_header, parse_line
from fgnav.models.registry import LOG_SCHEMA, MOTION_KINDS
from fgnav.time import format_utc

MAX_REPORTS = 100
"""Problem lines reported one by one per reason; further ones are counted only."""


@dataclass
class Row:
    """One accepted row: epoch (ns since 1970, UTC), kind, values (x, y, z, sigma, extra
    columns: :data:`fgnav.io.log_csv.VALUE_COLUMNS`) and its input line (1-based)."""

    ns: int
    kind: str
    values: np.ndarray
    line: int


@dataclass
class StreamCounts:
    """What the stream brought (summary.json ``stream``)."""

    lines: int = 0
    rows: int = 0
    skipped: dict = field(default_factory=dict)   # reason -> lines
    duplicates: int = 0
    late_kept: int = 0
    late_dropped: int = 0
    torn_last_line: bool = False

    def as_dict(self) -> dict:
        return {"lines": self.lines, "rows": self.rows, "skipped": dict(self.skipped),
                "duplicates": self.duplicates, "late_kept": self.late_kept,
                "late_dropped": self.late_dropped, "torn_last_line": self.torn_last_line}


class LineSource:
    """Lines (bytes, newline kept) of stdin (``"-"``) or a growing file.

    ``idle_timeout_s``: end after this long without new bytes (default: never for a file,
    the end of input for stdin). ``stop()`` (e.g. from a signal handler) ends it at the next
    poll. The last piece without a newline is returned as it is at the end."""

    POLL_S = 0.05

    def __init__(self, source: str, idle_timeout_s: float | None = None):
        self.name = "<stdin>" if source == "-" else str(source)
        self.stdin = source == "-"
        if self.stdin:
            self.fd = sys.stdin.buffer.fileno()
        else:
            try:
                self.fd = os.open(source, os.O_RDONLY)
            except OSError as exc:
                raise UserError(f"{source}: cannot read the stream: {exc.strerror or exc}") \
                    from None
        self.idle = idle_timeout_s
        self.stopped = False

    def stop(self) -> None:
        self.stopped = True

    def lines(self):
        buf = b""
        last_data = time.monotonic()
        while not self.stopped:
            if self.stdin:
                wait = self.POLL_S * 4
                try:
                    ready = select.select([self.fd], [], [], wait)[0]
                except (OSError, ValueError):
                    ready = [self.fd]
                if not ready:
                    if self.idle is not None and time.monotonic() - last_data > self.idle:
                        break
                    continue
            chunk = os.read(self.fd, 1 << 16)
            if not chunk:
                if self.stdin:
                    break   # end of input
                if self.idle is not None and time.monotonic() - last_data > self.idle:
                    break
                time.sleep(self.POLL_S)
                continue
            last_data = time.monotonic()
            buf += chunk
            if b"\n" in buf:
                *whole, buf = buf.split(b"\n")
                for line in whole:
                    yield line + b"\n"
        if buf:
            yield buf
        if not self.stdin:
            os.close(self.fd)


class StreamReader:
    """Rows of a CSV v1 stream grouped into completed epochs.

    :meth:`feed` takes one line (bytes) and returns the events it completes: ``("epoch",
    ns, rows)`` for an epoch that is complete, ``("late", ns, rows)`` for a late row within
    ``reorder_window_s`` of the newest epoch whose epoch was already completed; :meth:`end`
    completes the last epoch. Problems are counted in :attr:`counts` and reported through
    ``report(message)`` (default: stderr), each naming the input line."""

    def __init__(self, name: str = "<stdin>", *, reorder_window_s: float = 0.0, report=None):
        if not (reorder_window_s >= 0 and np.isfinite(reorder_window_s)):
            raise UserError(f"--reorder-window-s must be a finite number >= 0 (s), got "
                            f"{reorder_window_s}")
        self.name = name
        self.window_ns = int(round(reorder_window_s * 1e9))
        self.report = report or (lambda msg: print(f"fgnav: {msg}", file=sys.stderr))
        self.header: list[str] | None = None
        self.centre = "earth"
        self.preamble: list[bytes] = []   # the comment lines above the header
        self.counts = StreamCounts()
        self.lineno = 0
        self.pending: dict[int, list[Row]] = {}   # epochs not yet completed
        self.newest: int | None = None            # newest epoch seen
        self.completed: int | None = None         # newest epoch completed
        self.seen: dict[int, set] = {}            # epoch -> row keys (duplicates), recent only
        self._reported: dict[str, int] = {}

    def _skip(self, reason: str, message: str) -> None:
        self.counts.skipped[reason] = self.counts.skipped.get(reason, 0) + 1
        self._say(reason, f"{message} (skipped)")

    def _say(self, reason: str, message: str) -> None:
        n = self._reported.get(reason, 0) + 1
        self._reported[reason] = n
        if n <= MAX_REPORTS:
            self.report(message)
        elif n == MAX_REPORTS + 1:
            self.report(f"{self.name}: further '{reason}' lines are counted, not shown")

    def feed(self, raw: bytes) -> list:
        """One input line (with its newline; without: the torn end of the input)."""
        self.lineno += 1
        self.counts.lines += 1
        terminated = raw.endswith(b"\n")
        text = raw.rstrip(b"\n")
        if self.header is None:
            return self._preamble(text, terminated)
        if not terminated:
            self.counts.torn_last_line = True
            self._skip("truncated", f"{self.name}, line {self.lineno}: the last line ends "
                       "without a newline (a torn write)")
            return []
        try:
            row = parse_line(self.name, self.lineno, text, self.header, schema=LOG_SCHEMA)
        except InputFormatError as exc:
            self._skip(getattr(exc, "reason", "invalid"), str(exc))
            return []
        if row is None:
            return []
        ns, kind, v = row
        if kind in MOTION_KINDS:   # a declared manoeuvre: offline only in this version
            self._skip("manoeuvre", f"{self.name}, line {self.lineno}: a declared {kind} is not "
                       "yet applied live (fgnav smooth estimates it)")
            return []
        return self._accept(Row(ns, kind, v, self.lineno))

    def _preamble(self, text: bytes, terminated: bool) -> list:
        try:
            s = text.decode("utf-8")
        except UnicodeDecodeError:
            raise InputFormatError(self.name, self.lineno, None, "UTF-8 text before the header",
                                   repr(text[:40])) from None
        if self.lineno == 1 and s.startswith("\ufeff"):
            s = s[1:]
        stripped = s.strip()
        if not stripped or stripped.startswith("#"):
            m = CENTRE_LINE.fullmatch(stripped)
            if m:
                name = m.group(1).lower()
                if name not in CENTRES:
                    raise InputFormatError(self.name, self.lineno, "centre",
                                           f"one of {', '.join(CENTRES)}", m.group(1))
                self.centre = name
            self.preamble.append(text)
            return []
        header = check_header(self.name, self.lineno, s.rstrip("\r"))
        ids = [c for c in header if c in ("spacecraft", "tx_spacecraft", "rx_antenna",
                                          "tx_antenna")]
        if ids:
            raise InputFormatError(self.name, self.lineno, ids[0], "the columns of one "
                                   "spacecraft's log (a formation is not yet followed live)",
                                   ids[0])
        self.header = header
        return []

    def _accept(self, row: Row) -> list:
        key = (row.kind, row.values.tobytes())
        if self.completed is not None and row.ns <= self.completed:
            if self.newest - row.ns > self.window_ns:
                self.counts.late_dropped += 1
                self._say("late", f"{self.name}, line {self.lineno}: a row of "
                          f"{format_utc(np.datetime64(row.ns, 'ns'))}, "
                          f"{(self.newest - row.ns) / 1e9:g} s behind the newest epoch "
                          f"(more than the reorder window): dropped")
                return []
            if key in self.seen.get(row.ns, ()):
                return self._duplicate(row)
            self.seen.setdefault(row.ns, set()).add(key)
            self.counts.late_kept += 1
            self.counts.rows += 1
            return [("late", row.ns, [row])]
        if key in self.seen.get(row.ns, ()):
            return self._duplicate(row)
        self.seen.setdefault(row.ns, set()).add(key)
        self.counts.rows += 1
        self.pending.setdefault(row.ns, []).append(row)
        out = []
        if self.newest is None or row.ns > self.newest:
            self.newest = row.ns
            for ns in sorted(e for e in self.pending if e < row.ns):
                out.append(("epoch", ns, self.pending.pop(ns)))
                self.completed = ns
            self._forget()
        return out

    def _duplicate(self, row: Row) -> list:
        self.counts.duplicates += 1
        self._say("duplicate", f"{self.name}, line {self.lineno}: repeats an earlier row "
                  "(ignored)")
        return []

    def _forget(self) -> None:
        """Drop the duplicate keys of epochs beyond the reorder window (bounded memory)."""
        if len(self.seen) > 64:
            old = [ns for ns in self.seen if self.newest - ns > self.window_ns]
            for ns in old:
                del self.seen[ns]

    def end(self) -> list:
        """The epochs still open at the end of input."""
        if self.header is None:
            raise InputFormatError(self.name, max(self.lineno, 1), None,
                                   "the header line (epoch,kind,x,y,z,sigma...) then rows",
                                   "no header" if self.lineno else "no input")
        out = [("epoch", ns, self.pending.pop(ns)) for ns in sorted(self.pending)]
        if out:
            self.completed = out[-1][1]
        return out


def pace_log(path, speed: float, out=None, sleep=time.sleep) -> int:
    """Copy the log ``path`` to ``out`` (default stdout) line by line, each row when its
    epoch is due at ``speed`` times real time from the first row (``speed`` 0: at once);
    comment lines and the header at once. Each line is one flushed write. Returns the rows
    written."""
    if not (speed >= 0 and math.isfinite(speed)):
        raise UserError(f"--speed must be a finite number >= 0 (0: as fast as possible), got "
                        f"{speed}")
    out = out or sys.stdout.buffer
    t_wall0 = ns0 = None
    n = 0
    with open(path, "rb") as f:
        header = False
        for line in f:
            s = line.strip()
            if not header or not s or s.startswith(b"#"):
                header = header or bool(s and not s.startswith(b"#"))
                out.write(line)
                out.flush()
                continue
            if speed > 0:
                try:
                    ns = int(np.datetime64(s.split(b",", 1)[0].decode().rstrip("Z"), "ns")
                             .astype(np.int64))
                except ValueError:
                    ns = None
                if ns is not None:
                    if ns0 is None:
                        ns0, t_wall0 = ns, time.monotonic()
                    wait = (ns - ns0) / 1e9 / speed - (time.monotonic() - t_wall0)
                    if wait > 0:
                        sleep(wait)
            out.write(line)
            out.flush()
            n += 1
    return n
