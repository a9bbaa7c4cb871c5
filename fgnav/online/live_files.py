"""The files a live run grows, in whole flushed records, and its checkpoint.

``online.oem``: CCSDS OEM 2.0 (KVN), one segment per block of epochs, each with its
covariances (ODM 502.0-B-3 sec. 5.2: an OEM may hold several segments, each its own
metadata, ephemeris lines and covariance), so the file is a valid OEM after every block.
``latency.csv``: ``t_s,latency_s,cpu_s`` (the update's wall time and the CPU time of it),
one line per epoch. Both are written with one
``write`` per record and flushed; a checkpoint records their sizes, so a resumed run cuts
away what was written after it and no epoch appears twice.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from fgnav.errors import UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.oem import write_oem

CHECKPOINT_FORMAT = "fgnav-follow-checkpoint-1"
BLOCK_EPOCHS = 60
"""Epochs per online.oem segment (also written after ``BLOCK_S`` of wall time)."""
BLOCK_S = 5.0


class LiveFiles:
    """``DIR/online.oem`` and ``DIR/latency.csv`` grown as epochs complete."""

    def __init__(self, out: Path, centre: str = "earth", method: str = "isam2",
                 sizes: tuple[int, int] | None = None):
        self.out = Path(out)
        self.oem_path, self.lat_path = self.out / "online.oem", self.out / "latency.csv"
        self.centre, self.method = centre, method
        if sizes is None:   # a new run: new files
            for path in (self.oem_path, self.lat_path):
                if path.exists():
                    path.unlink()
        else:               # resume: what was written after the checkpoint goes
            for path, size in zip((self.oem_path, self.lat_path), sizes):
                if path.exists():
                    with open(path, "r+b") as f:
                        f.truncate(min(size, path.stat().st_size))
        self.oem = open(self.oem_path, "ab")
        self.lat = open(self.lat_path, "ab")
        if self.lat.tell() == 0:
            self._write(self.lat, b"t_s,latency_s,cpu_s\n")
        self.block: list = []
        self.block_t = time.monotonic()
        self.epoch0 = None

    @staticmethod
    def _write(f, data: bytes) -> None:
        f.write(data)
        f.flush()

    def add(self, state) -> None:
        """One epoch's :class:`fgnav.online.navigator.State`."""
        self._write(self.lat, f"{state.t_s:.6f},{state.latency_s:.9f},{state.cpu_s:.9f}\n"
                    .encode())
        self.block.append(state)
        if len(self.block) >= BLOCK_EPOCHS or time.monotonic() - self.block_t > BLOCK_S:
            self.flush()

    def flush(self) -> None:
        """Write the epochs held as one OEM segment."""
        self.block_t = time.monotonic()
        if not self.block:
            return
        b, self.block = self.block, []
        epoch0 = np.datetime64(b[0].ns, "ns")
        t = np.array([(s.ns - b[0].ns) / 1e9 for s in b])
        fd, tmp = tempfile.mkstemp(prefix=".fgnav-online-", suffix=".oem", dir=self.out)
        os.close(fd)
        try:
            write_oem(tmp, epoch0, t, np.array([s.x for s in b]), np.array([s.P for s in b]),
                      center_name=self.centre.upper(),
                      comments=(f"fgnav follow ({self.method}): each epoch's state as "
                                "estimated when it arrived", "one segment per block of epochs"))
            text = Path(tmp).read_bytes()
        finally:
            os.unlink(tmp)
        if self.oem.tell() > 0:   # a further segment: its metadata, data, covariance
            text = b"\n" + text[text.index(b"META_START"):]
        self._write(self.oem, text)

    def sizes(self) -> tuple[int, int]:
        if self.oem.closed:
            return self.final_sizes
        return self.oem.tell(), self.lat.tell()

    def close(self) -> None:
        self.flush()
        self.final_sizes = self.oem.tell(), self.lat.tell()
        self.oem.close()
        self.lat.close()


def save_checkpoint(path, fingerprint: str, nav_state: dict, sizes, done_epochs: int) -> None:
    """The online state (:meth:`fgnav.online.navigator.Navigator.checkpoint_state`), the
    live files' sizes and the run's fingerprint, written atomically (.npz)."""
    with atomic_writer(path, "wb") as f:
        np.savez(f, format=np.array(CHECKPOINT_FORMAT), fingerprint=np.array(fingerprint),
                 sizes=np.array(sizes, np.int64), done=np.array(done_epochs), **nav_state)


def load_checkpoint(path, fingerprint: str) -> tuple[dict, tuple[int, int]]:
    """``(navigator state, live files' sizes)`` of a checkpoint of the same run, else a
    :class:`UserError` naming the file and what differs."""
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise UserError(f"--checkpoint {path}: cannot read it as a checkpoint ({exc})") from None
    if str(d.get("format", "")) != CHECKPOINT_FORMAT:
        raise UserError(f"--checkpoint {path}: expected a checkpoint of fgnav follow "
                        f"({CHECKPOINT_FORMAT}), found {str(d.get('format', 'none'))!r}")
    if str(d["fingerprint"]) != fingerprint:
        raise UserError(f"--checkpoint {path}: written by a run with other options or another "
                        "stream header; resume with the same command")
    needed = ("x", "P", "last_ns", "k")
    if not all(k in d for k in needed) or not (np.all(np.isfinite(d["x"]))
                                             and np.all(np.isfinite(d["P"]))):
        raise UserError(f"--checkpoint {path}: expected a finite online state "
                        f"({', '.join(needed)})")
    return d, tuple(int(s) for s in d["sizes"])


def fingerprint(**what) -> str:
    """The run's identity for a checkpoint: its options as JSON."""
    return json.dumps(what, sort_keys=True, default=str)
