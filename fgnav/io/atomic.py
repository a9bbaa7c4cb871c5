"""Atomic file writes: a reader sees either the old file or the complete new one, never half.

The text goes to a temporary file in the destination's directory (same file system), is
flushed and ``fsync``-ed, then ``os.replace``-d over the destination (atomic on POSIX and
Windows). On any exception -- including ``KeyboardInterrupt`` -- the temporary file is
removed and the old destination (if any) is left untouched.
"""

from __future__ import annotations

import contextlib
import os
import tempfile

__all__ = ["atomic_writer", "atomic_write_text"]


def _target_mode(path: str) -> int:
    """Permission bits for the new file: the old file's, else 0o666 minus the umask."""
    try:
        return os.stat(path).st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


@contextlib.contextmanager
def atomic_writer(path, mode: str = "w", *, encoding: str = "utf-8"):
    """Context manager yielding a file object whose content replaces ``path`` atomically.

    ``mode`` is ``"w"`` (text, UTF-8, ``\\n`` line endings written as given) or ``"wb"``.
    The destination is replaced only when the ``with`` block exits normally.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_writer: mode must be 'w' or 'wb', found {mode!r}")
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    base = os.path.basename(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=".tmp", dir=directory)
    try:
        if mode == "w":
            f = os.fdopen(fd, "w", encoding=encoding, newline="")
        else:
            f = os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise
    try:
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _target_mode(path))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    # Make the rename durable (best effort: not every platform can fsync a directory).
    with contextlib.suppress(OSError, AttributeError):
        dfd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def atomic_write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_writer`)."""
    with atomic_writer(path, "w", encoding=encoding) as f:
        f.write(text)
