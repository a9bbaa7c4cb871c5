"""The package structure: no import loops, ``factors`` independent of ``fgnav``, the EKF
baseline independent of GTSAM, and a command line that starts without the heavy libraries.

Every check runs in a fresh interpreter (``subprocess``), so what the test process has
already imported cannot hide a loop or a dependency.
"""

from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import factors
import fgnav

ROOT = Path(__file__).resolve().parents[1]
# importing fgnav.__main__ runs the command line
NOT_IMPORTABLE = {"fgnav.__main__"}


def _modules() -> list[str]:
    names = ["fgnav", "factors"]
    for pkg in (fgnav, factors):
        names += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]
    return [n for n in names if n not in NOT_IMPORTABLE]


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


# Each module is imported first: fgnav.* and factors.* are dropped from sys.modules before
# each import, so a loop between any two of them fails whichever side is entered first
# (third-party libraries stay loaded: they cannot be part of our loops).
_EACH_FIRST = """
import importlib, json, sys, traceback
failed = {}
for name in json.loads(sys.argv[1]):
    for m in [m for m in sys.modules if m.split('.')[0] in ('fgnav', 'factors')]:
        del sys.modules[m]
    try:
        importlib.import_module(name)
    except Exception:
        failed[name] = traceback.format_exc(limit=-3)
print(json.dumps(failed))
"""


def test_every_module_imports_first_without_a_loop():
    mods = _modules()
    assert len(mods) > 80 and "fgnav.solvers.batch" in mods and "factors.direction" in mods
    r = subprocess.run([sys.executable, "-c", _EACH_FIRST, json.dumps(mods)], cwd=ROOT,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    failed = json.loads(r.stdout.strip().splitlines()[-1])
    assert not failed, "\n".join(f"{k}:\n{v}" for k, v in failed.items())


def _top_level_imports(path: Path) -> set[str]:
    """Modules imported at module level (also under top-level if/try), by absolute name."""
    out = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        for n in ast.walk(node) if isinstance(node, (ast.If, ast.Try)) else [node]:
            if isinstance(n, ast.Import):
                out.update(a.name for a in n.names)
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                out.add(n.module)
                out.update(f"{n.module}.{a.name}" for a in n.names)
    return out


def test_module_level_import_graph_has_no_cycle():
    """Stricter than importing: no cycle among the module-level imports at all."""
    files = sorted((ROOT / "fgnav").rglob("*.py")) + sorted((ROOT / "factors").glob("*.py"))
    names = {}
    for p in files:
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    edges = {m: {d for d in _top_level_imports(p) if d in names and d != m} for m, p in names.items()}
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(edges[u]):
            if state.get(v) == 1:
                cycles.append(stack[stack.index(v):] + [v])
            elif v not in state:
                visit(v)
        stack.pop()
        state[u] = 2

    for m in sorted(names):
        if m not in state:
            visit(m)
    assert not cycles, [" -> ".join(c) for c in cycles]


def test_factors_source_never_imports_fgnav():
    offenders = []
    for p in sorted((ROOT / "factors").glob("*.py")):
        for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            mods = []
            if isinstance(n, ast.Import):
                mods = [a.name for a in n.names]
            elif isinstance(n, ast.ImportFrom):
                mods = [n.module or ""] if n.level == 0 else []
            offenders += [f"{p.name}:{n.lineno}: {m}" for m in mods if m.split(".")[0] == "fgnav"]
    assert not offenders, offenders


def test_factors_import_with_fgnav_blocked():
    mods = [m for m in _modules() if m.split(".")[0] == "factors"]
    assert "factors.adapters" in mods
    code = ("import importlib, sys\nsys.modules['fgnav'] = None\n"
            f"for m in {mods!r}:\n    importlib.import_module(m)\n"
            "import factors.adapters, factors.direction\n"
            # the GTSAM adapters run with fgnav blocked too
            "import numpy as np\n"
            "f = factors.direction.make_earth_direction_factor(1, np.array([1.0, 0, 0]), 1e-3)\n"
            "print(type(f).__name__)\n")
    r = _run(code)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "CustomFactor"


def test_ekf_baseline_imports_no_gtsam():
    r = _run("import sys\nimport fgnav.solvers.ekf, fgnav.solvers.ekf_numba\n"
             "print('gtsam' in sys.modules)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"
    # the check can fail: the iSAM2 smoother does import GTSAM
    r = _run("import sys\nimport fgnav.solvers.incremental\nprint('gtsam' in sys.modules)")
    assert r.stdout.strip() == "True", r.stderr


def test_help_imports_no_heavy_library():
    heavy = ["numpy", "gtsam", "numba", "cv2", "scipy", "rerun", "matplotlib", "dask"]
    code = ("import sys, contextlib, io\nfrom fgnav.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(['--help'])\n    except SystemExit:\n        pass\n"
            f"print([m for m in {heavy!r} if m in sys.modules])")
    r = _run(code)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def _every_import(path: Path) -> set[str]:
    """Modules imported anywhere in a file (inside functions too), by absolute name."""
    out = set()
    for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(n, ast.Import):
            out.update(a.name for a in n.names)
        elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
            out.add(n.module)
    return out


def test_models_and_the_pass_builder_never_import_the_formation_package():
    """A formation is a property of the pass: the models (the links' among them) and the pass
    builder sit below ``fgnav.formation`` and import nothing of it, not even in a function."""
    files = sorted((ROOT / "fgnav" / "models").glob("*.py")) + [ROOT / "fgnav" / "measurements.py"]
    assert len(files) >= 5
    up = {p.name: sorted(m for m in _every_import(p) if m.startswith("fgnav.formation"))
          for p in files}
    assert not any(up.values()), up


def test_the_formation_package_never_imports_the_pipeline():
    """The pipeline runs a formation's pass through its own stages and calls the formation
    package's pieces (links' start, relative states, verdict): they import nothing of it, so
    the circle pipeline <-> formation/outputs is gone (imports inside functions counted)."""
    files = sorted((ROOT / "fgnav" / "formation").glob("*.py"))
    assert any(p.name == "outputs.py" for p in files)
    up = {p.name: sorted(m for m in _every_import(p)
                         if m.split(".")[:2] in (["fgnav", "pipeline"], ["fgnav", "viz"],
                                                 ["fgnav", "commands"], ["fgnav", "api"]))
          for p in files}
    assert not any(up.values()), up
