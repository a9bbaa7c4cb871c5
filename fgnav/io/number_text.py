"""Decimal text of float arrays, character for character what Python's ``%`` writes, fast.

A 1,000,000-epoch solution is 27 million numbers of text (states and covariances), and
Python formats one in ~0.7 us: ~15 s, a sixth of the whole run. Here a compiled kernel
writes whole lines into a byte buffer at ~0.1 us a number.

Each number is rounded correctly (Steele & White 1990), as Python rounds it (the exact
binary value, ties to even): the nearest integer to ``|x| 10**s`` comes from an error-free
product. ``|x| * hi`` is split exactly into ``p + e`` (Dekker 1971, TwoProduct), with
``10**s = hi + lo`` held to ~2**-106 (a double-double table made from exact integers), so
``|x| 10**s`` is known to ~1e-14 absolute. Where that cannot decide the rounding (within
1e-9 of a half: exact ties, once in ~1e9 otherwise) or the number is outside the range the
table covers, the number is written by Python's ``%`` instead. So the text is always Python's; tests compare the two on
millions of values, ties and edges included.

Styles: ``("f", n)`` is ``"%.nf"``, ``("e", n)`` is ``"%.ne"`` and ``("g", n)`` is ``"%.ng"``.
A row is texts and numbers in turn: ``text_0 v_0 text_1 v_1 ... v_{K-1} text_K``, every text
a constant, one string per row, or an index into a few strings (:func:`render_rows`).
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from factors.jit import njit, numba_loaded

__all__ = ["render_rows", "format_numbers"]

_STYLES = {"f": 0, "e": 1, "g": 2}
_S_MIN, _S_MAX = -300, 300   # the double-double table of 10**s
_TABLE = None
_AMBIGUOUS = 1e-9            # a fraction this close to 1/2 is left to Python
_FIXED_MAX = 2.0 ** 62       # |x| 10**n beyond this: Python (int64 digits)
_SPLIT = 134217729.0         # 2**27 + 1 (Dekker's split of a double into two 26-bit halves)
_PYTHON_BELOW = 1_000_000    # numbers: fewer are written by Python unless numba is loaded
                             # (loading it costs ~0.7 s, Python's time for ~1e6 numbers)


def _pow10_table() -> np.ndarray:
    """(2, S) hi and lo of ``10**s`` for s in [_S_MIN, _S_MAX]: hi the nearest double, lo the
    nearest double to the rest (exact rational arithmetic)."""
    global _TABLE
    if _TABLE is None:
        hi = np.empty(_S_MAX - _S_MIN + 1)
        lo = np.empty_like(hi)
        for i, s in enumerate(range(_S_MIN, _S_MAX + 1)):
            exact = Fraction(10) ** s
            hi[i] = float(exact)
            lo[i] = float(exact - Fraction(hi[i]))
        _TABLE = np.stack([hi, lo])
    return _TABLE


@njit(cache=True)
def _two_product(a, b):
    """``a * b = p + e`` exactly (Dekker 1971): p the rounded product, e its error."""
    p = a * b
    t = _SPLIT * a
    ah = t - (t - a)
    al = a - ah
    t = _SPLIT * b
    bh = t - (t - b)
    bl = b - bh
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, e


@njit(cache=True)
def _round_scaled(a, s, table):
    """The integer nearest to ``a 10**s`` (a > 0) and whether that is certain (False: too near
    a half, or out of range)."""
    i = s - _S_MIN
    if i < 0 or i >= table.shape[1]:
        return 0, False
    p, e = _two_product(a, table[0, i])
    e += a * table[1, i]
    if not p < _FIXED_MAX:
        return 0, False
    f = np.floor(p)
    r = (p - f) + e            # the part of a 10**s beyond the integer f, to ~1e-14
    n = np.floor(r + 0.5)
    if abs(r - np.floor(r) - 0.5) < _AMBIGUOUS:
        return 0, False
    return np.int64(f) + np.int64(n), True


@njit(cache=True)
def _at_least_pow10(a, k, table):
    """Whether ``a >= 10**k`` exactly (10**k = hi + lo; no double lies strictly between hi
    and hi + lo, as |lo| is at most half the spacing of doubles at hi)."""
    hi = table[0, k - _S_MIN]
    return a > hi or (a == hi and table[1, k - _S_MIN] <= 0.0)


@njit(cache=True)
def _parts(values, kind, prec, table):
    """Per number: D (the digits as an integer), X (the decimal exponent of "e"/"g"), and
    whether the kernel can write it (False: Python writes it)."""
    N, K = values.shape
    D = np.zeros((N, K), np.int64)
    X = np.zeros((N, K), np.int32)
    ok = np.ones((N, K), np.bool_)
    for j in range(K):
        pj = prec[j]
        digits = pj + 1 if kind[j] == 1 else max(pj, 1)   # significant digits of "e"/"g"
        for i in range(N):
            x = values[i, j]
            a = abs(x)
            if not np.isfinite(x):
                ok[i, j] = False
            elif kind[j] == 0:
                D[i, j], ok[i, j] = _round_scaled(a, pj, table)
            elif a == 0.0:
                D[i, j] = 0
            elif a < 1e-280 or a > 1e280:
                ok[i, j] = False
            else:
                k = np.int64(np.floor(np.log10(a)))   # the exact value's exponent:
                while k > -300 and not _at_least_pow10(a, k, table):   # log10 may be one off
                    k -= 1
                while k < 299 and _at_least_pow10(a, k + 1, table):
                    k += 1
                d, good = _round_scaled(a, digits - 1 - k, table)
                if d == np.int64(10) ** digits:   # rounded up to the next power of ten
                    d //= 10
                    k += 1
                D[i, j] = d
                X[i, j] = k
                ok[i, j] = good
    return D, X, ok


@njit(cache=True)
def _put_int(out, n, v, width):
    """Write the non-negative ``v`` at out[n:] with at least ``width`` digits; the new n."""
    m = 0
    t = v
    while True:
        m += 1
        t //= 10
        if t == 0:
            break
    if m < width:
        m = width
    for q in range(m - 1, -1, -1):
        out[n + q] = 48 + v % 10
        v //= 10
    return n + m


@njit(cache=True)
def _put_digits(out, n, digits, count):
    """Write ``digits`` (an int with ``count`` digits, leading zeros written) at out[n:]."""
    for q in range(count - 1, -1, -1):
        out[n + q] = 48 + digits % 10
        digits //= 10
    return n + count


@njit(cache=True)
def _put_exponent(out, n, x):
    out[n] = 101   # e
    out[n + 1] = 45 if x < 0 else 43
    return _put_int(out, n + 2, abs(x), 2)


@njit(cache=True)
def _put_number(out, n, negative, d, x, kind, prec):
    """Write one number (its sign, digits D and exponent X) in its style at out[n:]."""
    if negative:
        out[n] = 45
        n += 1
    if kind == 0:   # %.nf
        scale = np.int64(10) ** prec
        n = _put_int(out, n, d // scale, 1)
        if prec > 0:
            out[n] = 46
            n = _put_digits(out, n + 1, d % scale, prec)
        return n
    if kind == 1:   # %.ne
        scale = np.int64(10) ** prec
        out[n] = 48 + d // scale
        n += 1
        if prec > 0:
            out[n] = 46
            n = _put_digits(out, n + 1, d % scale, prec)
        return _put_exponent(out, n, x)
    # %.ng: P significant digits, fixed when -4 <= X < P, trailing zeros removed
    P = max(prec, 1)
    if d == 0:
        out[n] = 48
        return n + 1
    while d % 10 == 0 and P > 1:   # the significant digits without trailing zeros
        d //= 10
        P -= 1
    if -4 <= x < max(prec, 1):
        if x < 0:
            out[n] = 48
            out[n + 1] = 46
            n += 2
            for _ in range(-x - 1):
                out[n] = 48
                n += 1
            return _put_digits(out, n, d, P)
        if P <= x + 1:   # an integer: pad with zeros, no point
            n = _put_digits(out, n, d, P)
            for _ in range(x + 1 - P):
                out[n] = 48
                n += 1
            return n
        scale = np.int64(10) ** (P - x - 1)
        n = _put_int(out, n, d // scale, 1)
        out[n] = 46
        return _put_digits(out, n + 1, d % scale, P - x - 1)
    scale = np.int64(10) ** (P - 1)
    out[n] = 48 + d // scale
    n += 1
    if P > 1:
        out[n] = 46
        n = _put_digits(out, n + 1, d % scale, P - 1)
    return _put_exponent(out, n, x)


@njit(cache=True)
def _render(values, D, X, fallback, kind, prec, slot, text, text_start, size):
    """The rows' bytes: per row, text slot 0, number 0, slot 1, ..., number K-1, slot K;
    slot[k, i] indexes the text table (``text[text_start[t]:text_start[t + 1]]``);
    fallback[i, j] >= 0: the number's own text is that table entry."""
    N, K = values.shape
    out = np.empty(size, np.uint8)
    n = 0
    for i in range(N):
        for j in range(K + 1):
            t = slot[j, i]
            for b in range(text_start[t], text_start[t + 1]):
                out[n] = text[b]
                n += 1
            if j == K:
                break
            f = fallback[i, j]
            if f >= 0:
                for b in range(text_start[f], text_start[f + 1]):
                    out[n] = text[b]
                    n += 1
            else:
                n = _put_number(out, n, np.signbit(values[i, j]), D[i, j], X[i, j], kind[j],
                                prec[j])
    return out[:n]


def render_rows(texts: list, values: np.ndarray, styles: list, *,
                compiled: bool | None = None) -> bytes:
    """Rows of text: ``texts[0] values[:, 0] texts[1] ... values[:, K-1] texts[K]``.

    ``texts`` (K + 1): each a ``str`` (the same in every row), a sequence of N strings, or a
    pair ``(strings, index)`` (row i has ``strings[index[i]]``); ``values`` (N, K) floats;
    ``styles`` (K) pairs ``(style, precision)``, style one of "f", "e", "g" as in
    ``%.{precision}{style}``. The result equals joining
    ``text_0 + ("%.nf" % v_0) + text_1 + ...`` over the rows (Python's rounding, ties to even,
    "-" of a negative zero), non-finite numbers included (written by Python).
    ``compiled``: the kernel (True) or Python's ``%`` (False); default the kernel when numba is
    loaded or the numbers are many.
    """
    values = np.ascontiguousarray(values, dtype=float)
    N, K = values.shape
    if len(texts) != K + 1 or len(styles) != K:
        raise ValueError(f"render_rows: {K} columns need {K + 1} texts and {K} styles")
    texts = [_as_table(t, N, j) for j, t in enumerate(texts)]
    if compiled is None:
        compiled = N * K >= _PYTHON_BELOW or numba_loaded()
    if not compiled:
        return _render_python(texts, values, styles)
    kind = np.array([_STYLES[s] for s, _ in styles], np.int8)
    prec = np.array([p for _, p in styles], np.int64)
    if np.any(prec < 0) or np.any(prec > 17):
        raise ValueError("render_rows: precision must be in 0..17")
    D, X, ok = _parts(values, kind, prec, _pow10_table())
    pieces, slot = [], np.empty((K + 1, N), np.int64)
    longest = 0
    for j, (table, index) in enumerate(texts):
        slot[j] = len(pieces) + index
        enc = [t.encode("utf-8") for t in table]
        pieces += enc
        longest += max(map(len, enc), default=0)
    fallback = np.full((N, K), -1, np.int64)
    extra = 0
    for i, j in zip(*np.nonzero(~ok)):
        fallback[i, j] = len(pieces)
        s, p = styles[j]
        pieces.append((f"%.{p}{s}" % values[i, j]).encode("ascii"))
        extra += len(pieces[-1])
    text_start = np.zeros(len(pieces) + 1, np.int64)
    np.cumsum([len(b) for b in pieces], out=text_start[1:])
    text = np.frombuffer(b"".join(pieces), np.uint8)
    size = N * (longest + int(np.sum(prec)) + 26 * K) + extra
    return _render(values, D, X, fallback, kind, prec, slot, text, text_start, size).tobytes()


def _as_table(text, N: int, j: int) -> tuple[list, np.ndarray]:
    """A text slot as (strings, (N,) index into them)."""
    if isinstance(text, str):
        return [text], np.zeros(N, np.int64)
    if isinstance(text, tuple):
        table, index = text
        index = np.asarray(index, dtype=np.int64)
        if index.shape != (N,) or (N and (index.min() < 0 or index.max() >= len(table))):
            raise ValueError(f"render_rows: text {j} needs {N} indices into its {len(table)} "
                             "strings")
        return list(table), index
    if len(text) != N:
        raise ValueError(f"render_rows: text {j} has {len(text)} rows, the values {N}")
    return list(text), np.arange(N)


def _render_python(texts: list, values: np.ndarray, styles: list) -> bytes:
    """:func:`render_rows` by Python's ``%`` (the reference the kernel equals); ``texts`` as
    (strings, index) pairs."""
    fmt = "%s" + "".join(f"%.{p}{s}%s" for s, p in styles)
    cols = [list(map(table.__getitem__, index.tolist())) for table, index in texts]
    row = []
    for j in range(len(styles)):
        row += [cols[j], values[:, j].tolist()]
    row.append(cols[-1])
    return "".join(map(fmt.__mod__, zip(*row))).encode("utf-8")


def format_numbers(values, style: str, precision: int, *, compiled: bool | None = None
                   ) -> list[str]:
    """Each of ``values`` as ``"%.{precision}{style}" % v`` (one string per number)."""
    values = np.asarray(values, dtype=float).reshape(-1, 1)
    text = render_rows(["", "\n"], values, [(style, precision)],
                       compiled=compiled).decode("ascii")
    return text.split("\n")[:-1]
