"""The heliocentric cruise: geometric fixes, the smoother, the Cramér–Rao bound and the NEES.

    PYTHONPATH=$PWD python scripts/study_mars_cruise.py [--seeds 20] [--duration-h H]
                                                        [--out docs/mars_cruise.md]

Simulates the built-in ``mars-cruise`` scenario (three weeks of an Earth-Mars transfer, two
Sun-star angles and one Sun-Earth angle every 4 h, no prior) for each seed and smooths it
from the orbit of its geometric fixes (``fgnav.analysis.cruise_study`` says what is measured
and how). Prints a Markdown table (and writes it to ``--out``) and the raw figures as JSON
beside it (``.json``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fgnav.analysis.cruise_study import format_cruise_study, run_cruise_study


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="number of seeds (0..N-1), default 20")
    ap.add_argument("--duration-h", type=float, default=None, help="override the pass length (h)")
    ap.add_argument("--out", default=None, help="write the Markdown table here (and .json beside)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    s = run_cruise_study(range(a.seeds), duration_h=a.duration_h)
    text = format_cruise_study(s) + f"\n({time.perf_counter() - t0:.0f} s on this machine)\n"
    print(text)
    if a.out:
        Path(a.out).write_text(text)
        Path(a.out).with_suffix(".json").write_text(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
