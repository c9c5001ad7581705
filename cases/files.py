"""Atomic file writes: a temporary file beside the target, renamed onto it.

Every file a reader may open while it is being written, or after a crash (rows, traces, matrix
copies, references, case libraries), is written here: a reader sees the old file or the new one,
never half of one, and the temporary file never outlives a failure. The file gets the permissions a
plain ``open()`` gives (0666 less the umask), not ``mkstemp``'s private 0600, so a run directory
shared by a group stays readable by it. An OS error that does not name a file (pyarrow's "Error
writing bytes to file" on a full disk) is raised again naming the target.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np


def _file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_MODE = _file_mode()


def write_atomic(path: str | Path, write: Callable[[str], None], suffix: str = ".tmp") -> Path:
    """``write(tmp)`` fills a temporary file in ``path``'s folder (created), then it replaces ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=suffix)
    except OSError as exc:
        raise _named(exc, path) from None
    os.close(fd)
    try:
        os.chmod(tmp, _MODE)
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _named(exc, path) from None
        raise
    return path


def write_text_atomic(path: str | Path, text: str, suffix: str = ".tmp") -> Path:
    """Write ``text`` (UTF-8) atomically, synced to disk before the rename."""

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    return write_atomic(path, write, suffix)


def _named(exc: OSError, path: Path) -> OSError:
    """``exc`` itself when it names a file, else the same error naming ``path``."""
    if exc.filename:
        return exc
    return OSError(exc.errno, exc.strerror or str(exc), str(path))


def strict_value(obj):
    """``obj`` as strict JSON (RFC 8259) can hold it: every non-finite float as None (null), numpy
    scalars and arrays as plain values, keys as text, anything else as its text."""
    if isinstance(obj, dict):
        return {str(k): strict_value(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict_value(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict_value(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if obj is None or isinstance(obj, (str, int, float, bool)):
        return obj
    return str(obj)
