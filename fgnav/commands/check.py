"""``fgnav check LOG``: validate a measurement log (CSV v1 or CCSDS TDM) without solving.

Prints the rows per kind, the time span, the number of distinct epochs and any warnings;
exit 0 when the file is valid, 2 with the error (file, line, column, expected) otherwise.
"""

from __future__ import annotations

import sys

from fgnav.commands import _types as T


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "check", help="validate a measurement log (CSV v1 or CCSDS TDM) without solving",
        description="Validate a measurement log without solving: print rows per kind, time "
                    "span (s) and distinct epochs, and warnings. Exit 0 if valid, 2 with the "
                    "file, line, column and expectation of the first error otherwise.")
    p.add_argument("log", metavar="LOG", help="measurement log: CSV v1 (.csv) or CCSDS TDM "
                   "(KVN, starting with CCSDS_TDM_VERS)")
    p.add_argument("--drop-bad-rows", action="store_true",
                   help="drop invalid CSV rows (counted per reason) instead of failing")
    p.add_argument("--sigma-deg", type=T.number(0.0, 45.0, lo_open=True, unit="deg"),
                   default=None, metavar="DEG",
                   help="TDM only: 1-sigma angle noise, deg (default: the file's "
                        "'COMMENT sigma_deg=...')")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def _is_tdm(path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    for raw in head.split(b"\n"):
        s = raw.strip().lstrip(b"\xef\xbb\xbf")
        if s:
            return s.startswith(b"CCSDS_TDM_VERS")
    return False


def _report(log) -> dict:
    import numpy as np

    from fgnav.time import add_seconds, format_utc

    t = np.asarray(log.t_s, dtype=float)
    return {
        "valid": True,
        "path": str(log.path),
        "rows": int(len(t)),
        "counts": log.counts(),
        "epochs": int(len(np.unique(t))),
        "start_utc": format_utc(add_seconds(log.epoch0, float(t.min()))),
        "stop_utc": format_utc(add_seconds(log.epoch0, float(t.max()))),
        "span_s": float(t.max() - t.min()),
        "warnings": list(log.warnings),
        "dropped": dict(log.dropped),
        **({"spacecraft": _per_spacecraft(log)} if getattr(log, "n_spacecraft", 1) > 1 else {}),
    }


def _per_spacecraft(log) -> dict:
    """A formation's log: per spacecraft id its rows per kind (an inter-satellite row counts
    for its receiver) and its declared antennas."""
    import numpy as np

    from fgnav.io.log_spacecraft import spacecraft_index

    sc = spacecraft_index(log)
    kinds = np.asarray(log.kind).astype(str)
    out = {}
    for i, name in enumerate(log.spacecraft):
        k, n = np.unique(kinds[sc == i], return_counts=True)
        out[name] = {"counts": {str(a): int(b) for a, b in zip(k, n)},
                     "antennas": sorted(ant for s, ant in log.antennas if s == name)}
    return out


def _no_prior(log) -> dict:
    """Whether ``fgnav smooth`` can start this log from its measurements alone (no prior
    rows, or --ignore-prior): the structural test of :func:`fgnav.iod.initial.iod_support`
    (the fit itself runs only in smooth)."""
    from fgnav.errors import UserError
    from fgnav.iod.geometric import check_centre_scale, first_fixes, geometric_support
    from fgnav.iod.initial import iod_support
    from fgnav.iod.prior import has_prior
    from fgnav.measurements import build_pass

    try:
        from fgnav.sun_earth_moon import preprocess_log, uses_scheme

        if uses_scheme(log):
            log = preprocess_log(log)[0]
        p = build_pass(log)
    except UserError as exc:
        return {"possible": False, "has_prior": False, "reason": str(exc)}
    if p.spacecraft:   # a formation: each spacecraft's own rows must start its orbit
        from fgnav.measurements import spacecraft_pass

        subs = [spacecraft_pass(p, s) for s in range(len(p.spacecraft))]
        each = [(name, iod_support(q), has_prior(q)) for name, q in zip(p.spacecraft, subs)]
        return {"possible": all(ok for _, (ok, _), _ in each),
                "has_prior": all(pr for _, _, pr in each),
                "reason": "; ".join(f"{name}: {why}" for name, (_, why), _ in each)}
    ok, why = iod_support(p)
    if ok and geometric_support(p)[0]:
        try:   # the fixes of the first epochs against the log's centre (a missing '# centre')
            check_centre_scale(p, first_fixes(p), p.centre)
        except UserError as exc:
            ok, why = False, str(exc)
    return {"possible": bool(ok), "has_prior": has_prior(p), "reason": why}


def run(args) -> int:
    import json

    from fgnav.errors import InputFormatError, UserError

    try:
        if _is_tdm(args.log):
            from fgnav.io.tdm import read_tdm

            sigma_rad = None
            if args.sigma_deg is not None:
                import math

                sigma_rad = math.radians(args.sigma_deg)
            log = read_tdm(args.log, sigma_rad=sigma_rad)
        else:
            from fgnav.io.log_csv import read_log
            from fgnav.models.registry import LOG_SCHEMA

            log = read_log(args.log, on_bad_row="drop" if args.drop_bad_rows else "error",
                           schema=LOG_SCHEMA)
    except UserError as exc:
        if not args.json:
            raise
        out = {"valid": False, "path": str(args.log), "error": str(exc)}
        if isinstance(exc, InputFormatError):
            out.update(line=exc.line, column=exc.column, expected=exc.expected,
                       found=None if exc.found is None else str(exc.found))
        print(json.dumps(out, sort_keys=True))
        print(f"fgnav: error: {exc}", file=sys.stderr)
        return 2

    rep = _report(log)
    rep["no_prior"] = _no_prior(log)
    if args.json:
        print(json.dumps(rep, sort_keys=True))
        return 0
    print(f"{rep['path']}: valid, {rep['rows']} measurements at {rep['epochs']} epochs")
    print(f"  span: {rep['start_utc']} .. {rep['stop_utc']} ({rep['span_s']:.3f} s)")
    for kind, n in sorted(rep["counts"].items()):
        print(f"  {kind:<22s} {n:>8d}")
    for name, d in rep.get("spacecraft", {}).items():
        rows = ", ".join(f"{k} {n}" for k, n in sorted(d["counts"].items()))
        ants = f"; antennas {', '.join(d['antennas'])}" if d["antennas"] else ""
        print(f"  spacecraft {name}: {rows}{ants}")
    for reason, n in sorted(rep["dropped"].items()):
        print(f"  dropped ({reason}): {n}")
    for w in rep["warnings"]:
        print(f"  warning: {w}")
    np_ = rep["no_prior"]
    print(f"  without a prior: {'can be smoothed' if np_['possible'] else 'cannot be smoothed'} "
          f"({np_['reason']})" + (" -- the log has prior rows" if np_["has_prior"] else ""))
    return 0
