"""On-disk cache of the oracle's compliance data: paid once, memory-mapped by every later process.

(Other data derived from catalog cases may share the store under keys of their own: a planner's
case library, for one; everything below holds for them too.)

Building the deformation oracle of a full part means one sparse back-solve per compliance column
(the wing panel: 9,999 columns, 20-70 s) and every process that builds the problem pays it again:
each matrix worker, each ``fixbench solve``. :meth:`fixbench.cases.oracle.Oracle.prepare` computes every
column once and stores the result here; a later process with the same model opens the files
memory-mapped (read-only, shared through the OS page cache) in about a second.

Key: a content hash of everything the data depends on: the case's model content (part, mesh,
material, supports, fixture candidates, measurement points, loads: :meth:`fixbench.cases.problem.Problem._key`),
the source of the code that computes it (``cases/fem.py``, ``oracle.py``, ``geometry.py``,
``spec.py``, ``units.py``) and the versions of numpy, scipy, scikit-fem and triangle. Any change
gives a new key; an entry nobody uses any more is evicted when the cache outgrows its size limit.

Integrity: every entry has a ``meta.json`` with each array's shape, dtype and CRC-32, checked on
every open; a damaged or incomplete entry is reported on stderr, removed and rebuilt, never trusted.
Entries are written into a temporary directory beside the cache and renamed into place (atomic), so
two processes building the same entry at once cannot leave a half-written one.

Where: only where the user or the run says; fixbench writes nothing outside a run directory or a
path the user names. ``$FIXBENCH_CACHE_DIR`` names the folder (``off`` or unset: no disk cache);
``fixbench run ... --out DIR`` gives its workers ``DIR/oracle-cache`` unless ``$FIXBENCH_CACHE_DIR``
names another (one folder shared by several runs saves their set-up and disk). Size limit:
``$FIXBENCH_CACHE_MAX_GB`` (default 8); least recently used entries are evicted first.
``fixbench cache info [--dir D]`` lists the entries, ``fixbench cache clear [--dir D]`` removes them.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil
import sys
import time
import zlib
from pathlib import Path

import numpy as np

FORMAT = 1
#: the modules whose code decides the compliance data (their source is part of every key)
CODE = ("fem.py", "oracle.py", "geometry.py", "spec.py", "units.py")
LIBRARIES = ("numpy", "scipy", "scikit-fem", "triangle")
DEFAULT_MAX_GB = 8.0


#: the environment variable that names the cache folder (read by every process, workers included)
ENV = "FIXBENCH_CACHE_DIR"


def root() -> Path | None:
    """The cache folder ``$FIXBENCH_CACHE_DIR`` names, or None (no disk cache: unset or ``off``)."""
    env = os.environ.get(ENV, "")
    return None if env.strip().lower() in ("", "off", "0", "none") else Path(env).expanduser()


def max_bytes() -> float:
    try:
        return float(os.environ.get("FIXBENCH_CACHE_MAX_GB", DEFAULT_MAX_GB)) * 2**30
    except ValueError:
        return DEFAULT_MAX_GB * 2**30


def _code_version() -> str:
    h = hashlib.sha1()
    here = Path(__file__).parent
    for name in CODE:
        h.update((here / name).read_bytes())
    for lib in LIBRARIES:
        try:
            h.update(f"{lib}={importlib.metadata.version(lib)}".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{lib}=?".encode())
    return h.hexdigest()


def key(model_key: str) -> str:
    """The cache key of a model's compliance data (model content + code + library versions)."""
    return hashlib.sha1(f"{FORMAT}:{model_key}:{_code_version()}".encode()).hexdigest()[:24]


def _crc(a: np.ndarray) -> int:
    return zlib.crc32(memoryview(np.ascontiguousarray(a)).cast("B"))


def _warn(msg: str) -> None:
    print(f"fixbench: oracle cache: {msg}", file=sys.stderr)


def load(k: str) -> dict[str, np.ndarray] | None:
    """The arrays of entry ``k`` (memory-mapped, read-only), or None if absent, off or damaged."""
    base = root()
    if base is None:
        return None
    d = base / k
    if not d.is_dir():
        return None
    try:
        meta = json.loads((d / "meta.json").read_text())
        if meta.get("format") != FORMAT or meta.get("key") != k:
            raise ValueError("foreign meta.json")
        arrays = {}
        for name, m in meta["arrays"].items():
            a = np.load(d / f"{name}.npy", mmap_mode="r", allow_pickle=False)
            if list(a.shape) != m["shape"] or str(a.dtype) != m["dtype"] or _crc(a) != m["crc32"]:
                raise ValueError(f"{name}.npy does not match its checksum")
            arrays[name] = np.asarray(a)  # a plain ndarray on the mapping (memmap runs Python on every slice)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        _warn(f"{d}: damaged ({exc}); removed, it will be rebuilt")
        shutil.rmtree(d, ignore_errors=True)
        return None
    os.utime(d / "meta.json")  # last use, for eviction
    return arrays


def store(k: str, arrays: dict[str, np.ndarray], description: str = "") -> Path | None:
    """Write entry ``k`` atomically; evict least recently used entries beyond the size limit.

    Returns the entry's directory, or None when the cache is off or cannot be written (a read-only
    or full disk is reported on stderr and costs only the cache: the run goes on).
    """
    base = root()
    if base is None:
        return None
    size = sum(a.nbytes for a in arrays.values())
    if size > max_bytes():
        _warn(f"entry of {size / 2**30:.2f} GB exceeds the limit of {max_bytes() / 2**30:.2f} GB "
              "(FIXBENCH_CACHE_MAX_GB); not stored")
        return None
    final = base / k
    tmp = base / f".tmp-{k}-{os.getpid()}"
    try:
        base.mkdir(parents=True, exist_ok=True)
        evict(size)
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        meta = {"format": FORMAT, "key": k, "description": description, "created": time.time(),
                "bytes": size, "arrays": {}}
        for name, a in arrays.items():
            a = np.ascontiguousarray(a)
            with open(tmp / f"{name}.npy", "wb") as f:
                np.save(f, a, allow_pickle=False)
                f.flush()
                os.fsync(f.fileno())
            meta["arrays"][name] = {"shape": list(a.shape), "dtype": str(a.dtype), "crc32": _crc(a)}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        try:
            os.rename(tmp, final)
        except OSError:  # another process stored the same entry first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
        return final
    except OSError as exc:
        _warn(f"{base}: cannot store ({exc.strerror or exc}); going on without it")
        shutil.rmtree(tmp, ignore_errors=True)
        return None


def entries(base: Path | None = None) -> list[dict]:
    """Every entry of folder ``base`` (default: :func:`root`): key, description, bytes, created and
    last used (epoch seconds), newest use first."""
    base = base or root()
    if base is None or not base.is_dir():
        return []
    out = []
    for d in base.iterdir():
        if not d.is_dir() or d.name.startswith("."):
            continue
        try:
            meta = json.loads((d / "meta.json").read_text())
            used = (d / "meta.json").stat().st_mtime
        except (OSError, ValueError):
            meta, used = {}, d.stat().st_mtime
        size = sum(f.stat().st_size for f in d.iterdir() if f.is_file())
        out.append({"key": d.name, "description": meta.get("description", "(damaged)"), "bytes": size,
                    "created": meta.get("created"), "last_used": used, "path": str(d)})
    return sorted(out, key=lambda e: -e["last_used"])


def evict(incoming: int = 0) -> int:
    """Remove least recently used entries until ``incoming`` more bytes fit; returns how many."""
    es = entries()
    total, removed = sum(e["bytes"] for e in es) + incoming, 0
    for e in reversed(es):  # oldest use first
        if total <= max_bytes():
            break
        shutil.rmtree(e["path"], ignore_errors=True)
        total -= e["bytes"]
        removed += 1
    return removed


def clear(base: Path | None = None) -> int:
    """Remove every entry of folder ``base`` (default: :func:`root`) and stray temporary directories;
    returns how many entries."""
    base = base or root()
    if base is None or not base.is_dir():
        return 0
    n = 0
    for d in base.iterdir():
        if d.is_dir():
            shutil.rmtree(d, ignore_errors=True)
            n += not d.name.startswith(".")
    return n
