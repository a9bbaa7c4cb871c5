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


# The layer order, bottom first, in one place: a module may import modules of its own layer
# and of the layers below it, at module level or inside a function alike. A module belongs to
# the layer of the longest prefix that names it; every module must be placed.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("measurement models (independent of fgnav)", ("factors",)),
    ("base", ("fgnav", "fgnav.constants", "fgnav.errors", "fgnav.time", "fgnav.paths",
              "fgnav.defaults", "fgnav.progress", "fgnav.first_run", "fgnav.chi2",
              "fgnav.solution", "fgnav.robust", "fgnav.frames")),
    ("file formats, orbits, images", ("fgnav.io", "fgnav.orbit", "fgnav.vision")),
    ("measurement models", ("fgnav.models",)),
    ("pass and graph", ("fgnav.measurements", "fgnav.graph", "fgnav.sun_earth_moon",
                        "fgnav.loose_attitude", "fgnav.apparent", "fgnav.extract",
                        "fgnav.prior_sources")),
    ("simulation", ("fgnav.scenarios", "fgnav.simulate")),
    ("initial orbit", ("fgnav.iod",)),
    ("diagnostics", ("fgnav.diagnostics",)),
    ("solvers", ("fgnav.solvers",)),
    ("start policy", ("fgnav.start",)),
    ("pipeline", ("fgnav.pipeline", "fgnav.results")),
    ("online navigation", ("fgnav.online",)),
    ("studies", ("fgnav.analysis", "fgnav.formation")),
    ("reports, campaigns", ("fgnav.viz", "fgnav.campaign")),
    ("interfaces", ("fgnav.api", "fgnav.commands", "fgnav.cli", "fgnav.__main__")),
)
# Modules that may import project modules inside functions: the interfaces on the top layer.
# The command line loads a verb's libraries only when it runs (`fgnav --help` loads no numpy,
# GTSAM or OpenCV), and `import fgnav.api` stays cheap (0.14 s, against 1.9 s for the
# pipeline with GTSAM): each of its calls loads what it runs, as docs/api.md promises.
LAZY_ALLOWED = ("fgnav.commands", "fgnav.cli", "fgnav.__main__", "fgnav.api")
# What is still to be undone (the one-pipeline issue), one line each; the test fails when an
# entry is added and when one is paid off without deleting its line, so the list only shrinks.
# Rewrite it after paying debt off with: python tests/test_imports.py --write-debt
DEBT_FILE = ROOT / "tests" / "import_debt.txt"


def _module_files() -> dict[str, Path]:
    files = sorted((ROOT / "fgnav").rglob("*.py")) + sorted((ROOT / "factors").glob("*.py"))
    names = {}
    for p in files:
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return names


def _imports(name: str, path: Path, known) -> list[tuple[str, bool, int]]:
    """Project modules that module `name` imports: (module, inside a function, line).

    ``from a.b import c`` names module ``a.b.c`` when that is a module, else ``a.b``; relative
    imports are resolved against the module's package."""
    out: list[tuple[str, bool, int]] = []
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]

    def owner(mod: str) -> str | None:
        while mod and mod not in known:
            mod = mod.rpartition(".")[0]
        return mod or None

    def walk(node, inside: bool):
        for c in ast.iter_child_nodes(node):
            fn = inside or isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(c, ast.Import):
                out.extend((m, fn, c.lineno) for a in c.names if (m := owner(a.name)))
            elif isinstance(c, ast.ImportFrom):
                mod = c.module or ""
                if c.level:
                    base = package.split(".")[: len(package.split(".")) - (c.level - 1)]
                    mod = ".".join(base + ([mod] if mod else []))
                for a in c.names:
                    if m := owner(f"{mod}.{a.name}") if f"{mod}.{a.name}" in known else owner(mod):
                        out.append((m, fn, c.lineno))
            walk(c, fn)

    walk(ast.parse(path.read_text(encoding="utf-8")), False)
    return [(m, fn, line) for m, fn, line in out if m != name]


def _layer_of(name: str) -> int:
    best, layer = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for pre in prefixes:
            if (name == pre or name.startswith(pre + ".")) and len(pre) > best:
                best, layer = len(pre), i
    if layer is None:
        raise AssertionError(f"{name} is in no layer: place it in LAYERS (tests/test_imports.py)")
    return layer


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan 1972)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(u):
        index[u] = low[u] = len(index)
        stack.append(u)
        on.add(u)
        for v in sorted(edges[u]):
            if v not in index:
                visit(v)
                low[u] = min(low[u], low[v])
            elif v in on:
                low[u] = min(low[u], index[v])
        if low[u] == index[u]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == u:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for m in sorted(edges):
        if m not in index:
            visit(m)
    return sorted(out)


def import_debt() -> list[str]:
    """Every import that breaks the layering, as the lines of DEBT_FILE."""
    files = _module_files()
    known = set(files)
    edges = {m: set() for m in files}
    inside, upward = set(), set()
    for m, p in files.items():
        for t, fn, _ in _imports(m, p, known):
            edges[m].add(t)
            if fn and not any(m == a or m.startswith(a + ".") for a in LAZY_ALLOWED):
                inside.add(f"inside {m} -> {t}")
            if _layer_of(t) > _layer_of(m):
                upward.add(f"upward {m} -> {t}")
    cycles = [f"cycle {' '.join(c)}" for c in _cycles(edges)]
    return sorted(inside) + sorted(upward) + cycles


def _read_debt() -> list[str]:
    lines = DEBT_FILE.read_text(encoding="utf-8").splitlines() if DEBT_FILE.exists() else []
    return [ln.strip() for ln in lines if ln.strip() and not ln.startswith("#")]


def test_every_module_is_in_a_layer():
    for m in _module_files():
        _layer_of(m)


def test_import_debt_only_shrinks():
    """Imports inside functions, upward imports and import cycles, all imports counted: each is
    a line of tests/import_debt.txt, and the file holds exactly those still there."""
    now, listed = set(import_debt()), set(_read_debt())
    new, paid = sorted(now - listed), sorted(listed - now)
    assert not new, "new imports against the layering (move the import or the code):\n" + \
        "\n".join(new)
    assert not paid, "paid off: delete these lines from tests/import_debt.txt " \
        "(python tests/test_imports.py --write-debt):\n" + "\n".join(paid)


def test_layer_check_sees_what_it_claims():
    """The checker itself: an import inside a function, an upward import and a cycle are found
    in a synthetic tree (so an empty debt list means something)."""
    files = {"fgnav.time": Path("t.py"), "fgnav.pipeline": Path("p.py")}
    src = {"t.py": "def f():\n    from fgnav import pipeline\n",
           "p.py": "from fgnav.time import x\n"}
    found = {}
    for m, p in files.items():
        tree_path = ROOT / "tests" / f"_layer_probe_{p.name}"
        tree_path.write_text(src[p.name], encoding="utf-8")
        try:
            found[m] = _imports(m, tree_path, set(files))
        finally:
            tree_path.unlink()
    assert found["fgnav.time"] == [("fgnav.pipeline", True, 2)]
    assert found["fgnav.pipeline"] == [("fgnav.time", False, 1)]
    assert _layer_of("fgnav.pipeline") > _layer_of("fgnav.time")
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]


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


def _imports_of(prefixes: tuple[str, ...]) -> dict[str, list[str]]:
    """Every project module each module under ``prefixes`` imports (inside functions too)."""
    files = _module_files()
    return {m: sorted({t for t, _, _ in _imports(m, p, set(files))}) for m, p in files.items()
            if any(m == pre or m.startswith(pre + ".") for pre in prefixes)}


def test_models_and_the_pass_builder_never_import_the_formation_package():
    """A formation is a property of the pass: the models (the links' among them) and the pass
    builder sit below ``fgnav.formation`` and import nothing of it, not even in a function."""
    imports = _imports_of(("fgnav.models", "fgnav.measurements"))
    assert len(imports) >= 5
    up = {m: [t for t in ts if t.startswith("fgnav.formation")] for m, ts in imports.items()}
    assert not any(up.values()), up


def test_nothing_below_the_studies_imports_the_formation_package():
    """The pipeline runs a formation's pass through its own stages (links' start, relative
    states, verdict): no module below the studies' layer imports ``fgnav.formation``, not
    even in a function, so the circle pipeline <-> formation is gone. The formation package
    is a study on top of the pipeline (``formation track`` solves with it, imports inside
    functions counted)."""
    studies = next(i for i, (_, pre) in enumerate(LAYERS) if "fgnav.formation" in pre)
    below = tuple(pre for _, pres in LAYERS[:studies] for pre in pres if pre != "fgnav")
    imports = _imports_of(below)
    assert "fgnav.pipeline" in imports and "fgnav.measurements" in imports
    up = {m: [t for t in ts if t.startswith("fgnav.formation")] for m, ts in imports.items()}
    assert not any(up.values()), up
    assert "fgnav.pipeline" in _imports_of(("fgnav.formation.study",))["fgnav.formation.study"]


if __name__ == "__main__":
    if sys.argv[1:] == ["--write-debt"]:
        head = [ln for ln in (DEBT_FILE.read_text(encoding="utf-8").splitlines()
                              if DEBT_FILE.exists() else []) if ln.startswith("#")]
        DEBT_FILE.write_text("\n".join(head + import_debt()) + "\n", encoding="utf-8")
        print(f"{DEBT_FILE}: {len(import_debt())} entries")
    else:
        print("\n".join(import_debt()))
