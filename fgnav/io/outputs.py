"""An output directory holds one run's set of files and no others of ours.

``fgnav smooth --out DIR`` writes a set of files (trajectory.oem, summary.json,
residuals.csv, for online methods online.oem and latency.csv, with an estimated attitude
attitude.aem and attitude_covariance.csv) and ``fgnav report``
adds its plots and report.md/html. A later run must not leave files of an earlier one
behind (an ``online.oem`` of an iSAM2 run beside a batch ``trajectory.oem`` would be
plotted as if it belonged to it), and must never touch a file the user put there.

So every set written is recorded in ``DIR/.fgnav-outputs.json`` (the manifest: group name
-> file names). A new smooth set replaces every group (a report of the previous solution is
stale too); a new report replaces the previous report group only. A file is removed only
when a manifest lists it, or -- for a directory written before manifests existed -- when it
carries our signature (see :func:`_legacy_ours`). Staging folders left by a killed run
(``.fgnav-staging-<pid>-*`` of a process no longer alive, or without a pid) are removed by
the next run into the directory.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from pathlib import Path

from fgnav.errors import UserError
from fgnav.io.atomic import atomic_write_text

__all__ = ["MANIFEST", "STAGING_PREFIX", "SMOOTH_OUTPUTS", "REPORT_OUTPUTS", "make_staging",
           "remove_stale_staging", "read_manifest", "commit_outputs", "check_writable_dir",
           "check_readable_file", "check_output_paths"]

MANIFEST = ".fgnav-outputs.json"
STAGING_PREFIX = ".fgnav-staging-"
SMOOTH_OUTPUTS = ("trajectory.oem", "online.oem", "residuals.csv", "latency.csv", "variables.csv",
                  "attitude.aem", "attitude_covariance.csv", "summary.json")
REPORT_OUTPUTS = ("errors_rtn.png", "sigma_rtn.png", "online_errors_rtn.png", "online_sigma_rtn.png",
                  "residuals_time.png", "residuals_hist.png", "attitude_errors.png",
                  "attitude_sigma.png", "orbit_3d.png", "latency.png", "report.md", "report.html")
_STAGING_RE = re.compile(re.escape(STAGING_PREFIX) + r"(\d+)-")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def remove_stale_staging(out: Path) -> list[Path]:
    """Remove staging folders in ``out`` left by runs that are no longer alive."""
    removed = []
    for d in sorted(Path(out).glob(STAGING_PREFIX + "*")):
        if not d.is_dir() or d.is_symlink():
            continue
        m = _STAGING_RE.match(d.name)
        if m and int(m.group(1)) != os.getpid() and _alive(int(m.group(1))):
            continue  # another run writing into the same directory right now
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d)
    return removed


def make_staging(out: Path) -> Path:
    """A new staging folder in ``out`` named after this process (see the module docstring)."""
    return Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", dir=out))


@contextlib.contextmanager
def staged(out_dir):
    """``with staged(out_dir) as (out, stage):`` the output folder (created) and a fresh
    staging folder inside it (stale ones of killed runs removed first), removed on exit;
    files written into ``stage`` are committed with :func:`commit_outputs`."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(out)
    stage = make_staging(out)
    try:
        yield out, stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def read_manifest(out: Path) -> dict[str, list[str]] | None:
    """group -> file names of the manifest in ``out``; None when there is none (or it is not
    ours: unreadable, or not of the documented form)."""
    try:
        data = json.loads((Path(out) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != "fgnav-outputs-1":
        return None
    groups = data.get("groups")
    if not isinstance(groups, dict):
        return None
    return {str(g): [n for n in names if isinstance(n, str)] for g, names in groups.items()
            if isinstance(names, list)}


def _head(path: Path, n: int = 2048) -> str:
    try:
        with open(path, "rb") as f:
            return f.read(n).decode("utf-8", "replace")
    except OSError:
        return ""


def _legacy_ours(out: Path) -> set[str]:
    """Files of ours in a directory written before manifests existed: an OEM or CSV with
    fgnav's header, and the report set when report.md is fgnav's."""
    found = set()
    if "fgnav" in _head(out / "online.oem"):
        found.add("online.oem")
    if _head(out / "latency.csv").startswith("t_s,latency_s\n"):
        found.add("latency.csv")
    if _head(out / "report.md").startswith("# fgnav report"):
        found.update(n for n in REPORT_OUTPUTS if (out / n).is_file())
    return found


def commit_outputs(out: Path, stage: Path | None, names: list[str], group: str,
                   replaces: tuple[str, ...]) -> list[Path]:
    """Move ``names`` from ``stage`` into ``out`` (``os.replace`` each; ``stage=None`` when
    they are already in place), then remove the files of the groups ``replaces`` of the
    previous manifest that this set did not rewrite, and record the new manifest."""
    out = Path(out)
    previous = read_manifest(out)
    stale = set()
    if previous is None:
        stale |= _legacy_ours(out)
    else:
        for g in replaces:
            stale.update(previous.get(g, []))
    for name in names:
        if stage is not None:
            os.replace(stage / name, out / name)
    for name in sorted(stale - set(names)):
        target = out / name
        # only plain names of files directly in out (a manifest is data, never a path to follow)
        if name != Path(name).name or name in (MANIFEST, "") or not target.is_file():
            continue
        with contextlib.suppress(OSError):
            target.unlink()
    groups = {g: v for g, v in (previous or {}).items() if g not in replaces}
    groups[group] = list(names)

    atomic_write_text(out / MANIFEST, json.dumps({"format": "fgnav-outputs-1", "groups": groups},
                                                 indent=1) + "\n")
    return [out / n for n in names]


def check_writable_dir(d: Path, what: str) -> None:
    """``UserError`` naming ``what`` unless a file can be created in the directory ``d``
    (tried for real: permission bits do not tell for root, read-only mounts, ...)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".fgnav-probe-", dir=d)
    except OSError as exc:
        raise UserError(f"{what}: cannot write in {d}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(tmp)


def check_output_paths(out_dir, *, rerun=None, checkpoint=None, resume: bool = False) -> None:
    """Check every output path of a run before it starts (``UserError`` naming the option).

    ``out_dir`` (``--out``): a directory, or a path that can be created (its nearest existing
    ancestor is a writable directory). ``rerun`` (``--rerun``) and ``checkpoint``
    (``--checkpoint``): a file name in a writable existing folder, or inside ``out_dir``;
    with ``resume`` the checkpoint must exist and be readable.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory (expected an output "
                        f"directory)")
    base = out
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise UserError(f"--out {out}: cannot create the directory, {base} is not a directory")
    check_writable_dir(base, f"--out {out}")
    for option, path, form in (("--rerun", rerun, "FILE.rrd"), ("--checkpoint", checkpoint,
                                                                 "FILE.npz")):
        if path is None:
            continue
        f = Path(path)
        if f.is_dir():
            raise UserError(f"{option} {f}: is a directory (expected a file name, {form})")
        parent = f.parent.resolve()
        # a folder inside --out is created with it; any other folder must exist
        if not (parent == out.resolve() or out.resolve() in parent.parents):
            if not parent.is_dir():
                raise UserError(f"{option} {f}: the folder {f.parent} does not exist")
            check_writable_dir(parent, f"{option} {f}")
    if checkpoint is not None and resume:
        check_readable_file(checkpoint, "--checkpoint", "no checkpoint to resume from (--resume)")


def check_readable_file(path, option: str, missing: str = "no such file") -> None:
    """``UserError`` naming ``option`` and ``path`` unless ``path`` is a readable file."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{option} {path}: {missing}")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise UserError(f"{option} {path}: cannot read: {exc.strerror or exc}") from None
