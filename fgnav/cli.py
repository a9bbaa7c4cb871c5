"""The ``fgnav`` command line: a thin layer over the library (``build_parser`` + ``main``)."""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

import fgnav.commands as commands
from fgnav import __version__
from fgnav.errors import UserError


KERNEL_COMMANDS = ("smooth", "demo", "campaign", "schemes", "formation", "check", "simulate")
"""Commands that run numba kernels: a one-line notice while these compile the first time
(:mod:`fgnav.first_run`)."""


def build_parser() -> argparse.ArgumentParser:
    """Build the parser; every module in ``fgnav.commands`` registers one subcommand."""
    parser = argparse.ArgumentParser(
        prog="fgnav",
        description="Spacecraft celestial navigation by factor-graph smoothing (GTSAM).",
    )
    parser.add_argument("--version", action="version", version=f"fgnav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        importlib.import_module(f"fgnav.commands.{info.name}").register(sub)
    return parser


REQUIRED_MODULES = ("gtsam", "numpy", "scipy", "cv2", "rerun", "numba", "matplotlib", "tqdm",
                    "pyarrow", "dask", "distributed", "erfa", "sgp4", "jplephem", "de421")
"""The import names of pyproject.toml's dependencies: a command that finds one missing (the
commands load their libraries lazily) ends with a message naming it, not a traceback."""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if args.command in KERNEL_COMMANDS and not getattr(args, "quiet", False):
        from fgnav.first_run import announce_first_compile
        announce_first_compile()
    try:
        rc = args.func(args)
    except UserError as exc:
        print(f"fgnav: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] not in REQUIRED_MODULES:
            raise
        print(f"fgnav: error: the package fgnav needs for this command, '{exc.name}', is not "
              f"installed in this Python ({sys.executable}): install fgnav with its "
              f"dependencies (pip install fgnav, or pip install -e . in a checkout)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgnav: interrupted; outputs already written are complete, none is half-written",
              file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of stdout went away (``fgnav campaign --list | head``): stop quietly, as
        # Unix tools do; stdout goes to /dev/null so that the interpreter's final flush is silent
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    return int(rc or 0)


def run() -> None:
    """The ``fgnav`` program (console script and ``python -m fgnav``): :func:`main`, then the
    process ends at once.

    A normal interpreter exit tears down every module and object one by one (numba's type
    registries and LLVM objects, GTSAM's factors, the pass's arrays): ~0.3 s of CPU after a
    4 h pass that the operating system would reclaim in one step. Here the output streams
    are flushed and the ``atexit`` handlers run (a recording library's final flush, logging),
    then ``os._exit``. With another thread still running (a worker pool shutting down), the
    normal exit, which joins it, is kept.

    The cyclic garbage collector runs after 100,000 new container objects instead of 700:
    the imports (numba's type registries) and a pass's per-epoch objects made it collect
    thousands of times, ~0.1 s of CPU of a 4 h pass (4 %); memory is freed by reference
    counting as before, only reference cycles wait a little longer.
    """
    import gc

    gc.set_threshold(100_000, 10, 10)
    rc = main()
    import atexit
    import threading

    if threading.active_count() > 1:
        sys.exit(rc)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe or stream: nothing more to deliver
            pass
    atexit._run_exitfuncs()
    os._exit(rc)


if __name__ == "__main__":  # pragma: no cover
    run()
