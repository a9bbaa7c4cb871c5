"""Test-run settings shared by every module.

The default run spreads the tests over every core (pytest-xdist, ``-n auto`` in
pyproject.toml). A benchmark times itself and a ``-s`` printout is read by a person, so a run
that selects benchmarks (``-m bench``) or turns capture off (``-s``) runs in one process.
"""
import re


def pytest_xdist_auto_num_workers(config):
    """0 workers (one process) for benchmarks and ``-s`` runs; otherwise xdist's own count."""
    expr = config.getoption("markexpr") or ""
    selects_bench = re.search(r"(?<!not )\bbench\b", expr) is not None
    if selects_bench or config.getoption("capture") == "no":
        return 0
    return None
