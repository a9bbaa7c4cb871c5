"""Evaluate the PyPI CCSDS libraries `oem` and `ccsds-ndm` against fgnav's own readers
(fgnav/io/oem.py, tdm.py, aem.py): what they read, how fast, and what they say about a
broken file. The findings and the decision are in docs/ccsds.md.

Run in a throwaway environment (neither library is a dependency of fgnav)::

    python -m venv --system-site-packages /tmp/ccsds-venv
    /tmp/ccsds-venv/bin/pip install oem ccsds-ndm
    python -m fgnav simulate gto-transfer --step-s 1 --out /tmp/c14/pass --quiet
    python -m fgnav smooth /tmp/c14/pass/measurements.csv --out /tmp/c14/res --quiet
    python -m fgnav simulate gto-transfer --step-s 60 --duration-h 1 --out /tmp/cs/pass --quiet
    python -m fgnav smooth /tmp/cs/pass/measurements.csv --out /tmp/cs/res --quiet
    python -m fgnav simulate geo-limb --raw-stars --duration-h 0.2 --out /tmp/cs/geo --quiet
    python -m fgnav smooth /tmp/cs/geo/measurements.csv --out /tmp/cs/att --estimate attitude \\
        --third-body --quiet
    PYTHONPATH=$PWD /tmp/ccsds-venv/bin/python scripts/eval_ccsds_libraries.py \\
        /tmp/c14/res/trajectory.oem /tmp/cs/res/trajectory.oem /tmp/cs/att/attitude.aem

Prints the timings (median of 3; ccsds-ndm once: it takes a minute), the agreement of the
states and covariances with fgnav's reader, and one line per reader and broken file.
"""

from __future__ import annotations

import re
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


def _median_time(f, n=3):
    ts, r = [], None
    for _ in range(n):
        t = time.perf_counter()
        r = f()
        ts.append(time.perf_counter() - t)
    return r, statistics.median(ts)


def speed(big_oem: Path) -> None:
    import oem as oemlib
    from ccsds_ndm.ndm_io import NdmIo

    from fgnav.io.oem import read_oem, write_oem

    ours, t_ours = _median_time(lambda: read_oem(big_oem))
    theirs, t_oem = _median_time(lambda: oemlib.OrbitEphemerisMessage.open(str(big_oem)))
    x = np.array([np.concatenate([s.position, s.velocity]) for s in theirs.states]) * 1e3
    p = np.array([c.matrix for c in theirs.covariances]) * 1e6
    print(f"read {big_oem.name} ({len(ours.t_s)} states + covariances): fgnav {t_ours:.2f} s, "
          f"oem {t_oem:.2f} s; oem vs fgnav max |dx| {np.abs(x - ours.x_eci).max():.3g} (m, m/s), "
          f"max |dP| / max |P| {np.abs(p - ours.P_eci).max() / np.abs(ours.P_eci).max():.3g}")
    with tempfile.TemporaryDirectory() as tmp:
        _, t_w = _median_time(lambda: write_oem(Path(tmp) / "a.oem", ours.epoch0, ours.t_s,
                                                ours.x_eci, ours.P_eci))
        _, t_wo = _median_time(lambda: theirs.save_as(str(Path(tmp) / "b.oem"), file_format="kvn"))
        back = read_oem(Path(tmp) / "b.oem")
    print(f"write: fgnav {t_w:.2f} s, oem {t_wo:.2f} s; oem's file read back by fgnav: max |dx| "
          f"{np.abs(back.x_eci - ours.x_eci).max():.3g}")
    ndm, t_ndm = _median_time(lambda: NdmIo().from_path(big_oem), n=1)
    seg = ndm.body.segment[0].data
    print(f"read with ccsds-ndm: {len(seg.state_vector)} states, {len(seg.covariance_matrix)} "
          f"covariances, {t_ndm:.1f} s")


def _attempt(fn) -> str:
    try:
        fn()
    except Exception as exc:  # every reader's own exception type is the point here
        return f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
    return "accepted (no error)"


def _broken(kind: str, src: str) -> dict[str, str]:
    lines = src.splitlines()

    def sub(i, new):
        return "\n".join(lines[:i] + [new] + lines[i + 1:]) + "\n"

    def drop(i):
        return "\n".join(lines[:i] + lines[i + 1:]) + "\n"

    def idx(prefix):
        return next(i for i, line in enumerate(lines) if re.match(prefix, line))

    if kind == "oem":
        i, c = idx(r"\d{4}-") + 3, idx("EPOCH")
        f = lines[i].split()
        return {"bad number in a state line": sub(i, " ".join(f[:2] + ["6509.2x"] + f[3:])),
                "state line with 5 numbers": sub(i, " ".join(f[:-1])),
                "bad epoch (month 13)": sub(i, " ".join(["2025-13-01T00:03:00"] + f[1:])),
                "missing REF_FRAME": drop(idx("REF_FRAME")),
                "unknown metadata keyword": sub(idx("OBJECT_ID"), "OBJECT_IDENT = X"),
                "covariance row missing": drop(c + 4),
                "covariance value not a number": sub(c + 3, lines[c + 3].replace("e-", "q-", 1)),
                "CCSDS_OEM_VERS = 9.0": sub(0, "CCSDS_OEM_VERS = 9.0")}
    if kind == "tdm":
        i = idx("ANGLE_1")
        return {"bad number in ANGLE_1": sub(i, lines[i].replace("123.456", "12x.456")),
                "bad epoch (day 41)": sub(i, lines[i].replace("2024-03-01", "2024-03-41")),
                "missing TIME_SYSTEM": drop(idx("TIME_SYSTEM")),
                "unknown metadata keyword": sub(idx("PATH"), "PATHS = 1,2")}
    i = idx(r"\d{4}-") + 2
    f = lines[i].split()
    return {"valid file": src,
            "bad number in a quaternion": sub(i, " ".join(f[:2] + ["0.7x"] + f[3:])),
            "quaternion line with 3 numbers": sub(i, " ".join(f[:-1])),
            "missing ATTITUDE_TYPE": drop(idx("ATTITUDE_TYPE")),
            "bad epoch (hour 25)": sub(i, " ".join(["2025-03-01T25:00:00"] + f[1:]))}


def errors(small_oem: Path, aem: Path) -> None:
    import oem as oemlib
    from ccsds_ndm.ndm_io import NdmIo
    from test_io_tdm import TDM

    from fgnav.io.aem import read_aem
    from fgnav.io.oem import read_oem
    from fgnav.io.tdm import read_tdm

    ndm = {"ccsds-ndm": lambda p: NdmIo().from_path(p)}
    readers = {
        "oem": {"fgnav": read_oem, "oem": lambda p: oemlib.OrbitEphemerisMessage.open(str(p)),
                **ndm},
        "tdm": {"fgnav": lambda p: read_tdm(p, sigma_rad=1e-4), **ndm},
        "aem": {"fgnav": read_aem, **ndm},
    }
    sources = {"oem": small_oem.read_text(), "tdm": TDM, "aem": aem.read_text()}
    with tempfile.TemporaryDirectory() as tmp:
        for kind, src in sources.items():
            for case, text in _broken(kind, src).items():
                path = Path(tmp) / f"{re.sub(r'[^a-z0-9]+', '-', case.lower())}.{kind}"
                path.write_text(text)
                print(f"\n{kind.upper()}: {case}")
                for name, read in readers[kind].items():
                    print(f"  {name:9s} {_attempt(lambda: read(path))}")


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    speed(Path(sys.argv[1]))
    errors(Path(sys.argv[2]), Path(sys.argv[3]))
