"""Where and with what a result was made: one record per worker process, stored in every row.

Learner results are the same bits on the same machine only: the BLAS code path of the products
(MKL's on x86, chosen by CPU type unless ``MKL_CBWR`` pins it) and OpenBLAS's kernels for the FE
set-up (``OPENBLAS_CORETYPE``) change the last bits, and a learner's run diverges from there
(docs/reproducibility.md). A row therefore says which fixbench (version and source commit), which
libraries and BLAS builds, which CPU, how many threads and which environment switches made it;
``fixbench report`` lists the distinct hosts of a run. Standard library only, read once a process:
the versions come from the installed packages' metadata and the BLAS from numpy's build
configuration, without importing PyTorch (a worker that runs only ``greedy`` never does); where
PyTorch is already imported its BLAS and CPU capability are read too.
"""

from __future__ import annotations

import functools
import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path

#: environment switches that change results or speed (threads, BLAS code paths)
SWITCHES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS", "MKL_CBWR",
            "OPENBLAS_CORETYPE", "ATEN_CPU_CAPABILITY", "MKL_DEBUG_CPU_TYPE")
#: the libraries whose versions a result depends on
LIBRARIES = ("numpy", "scipy", "scikit-fem", "numba", "torch", "pymoo", "optuna", "cvxpy", "osqp", "highspy",
             "botorch", "gpytorch")


@functools.cache
def _static() -> dict:
    versions = {}
    for lib in LIBRARIES:
        try:
            versions[lib] = importlib.metadata.version(lib)
        except importlib.metadata.PackageNotFoundError:
            continue
    try:
        fixbench = importlib.metadata.version("fixbench")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        fixbench = "unknown"
    return {"fixbench": fixbench, "commit": _commit(), "python": platform.python_version(),
            "libraries": versions, "numpy_blas": _numpy_blas(), "cpu": _cpu_model(), "cores": os.cpu_count(),
            "machine": platform.machine(), "system": f"{platform.system()} {platform.release()}",
            "host": platform.node()}


def provenance() -> dict:
    """This process's record: the static part (read once) and what may change within a run (threads,
    environment switches, PyTorch's BLAS when it is imported)."""
    out = dict(_static())
    out["env"] = {k: os.environ[k] for k in SWITCHES if k in os.environ}
    torch = sys.modules.get("torch")
    if torch is not None:
        out["torch_threads"] = torch.get_num_threads()
        out["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
        out["torch_blas"] = "mkl" if torch.backends.mkl.is_available() else "other"
    numba = sys.modules.get("numba")
    if numba is not None:
        out["numba_threads"] = numba.get_num_threads()
    return out


def host_key(record: dict) -> str:
    """One line that tells hosts apart in a report: CPU, cores, BLAS and the switches set."""
    env = ", ".join(f"{k}={v}" for k, v in sorted(record.get("env", {}).items()))
    return (f"{record.get('cpu', '?')} ({record.get('cores', '?')} cores; numpy BLAS {record.get('numpy_blas', '?')}"
            + (f"; torch {record['torch_cpu_capability']}" if record.get("torch_cpu_capability") else "")
            + (f"; {env}" if env else "") + ")")


def _commit() -> str:
    """The source commit of the fixbench being run when it runs from a git checkout ('+dirty' with
    local changes), else ''."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return ""
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return head + ("+dirty" if head and dirty else "")


def _numpy_blas() -> str:
    try:
        import numpy as np

        blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name', '?')} {blas.get('version', '?')}"
    except Exception:  # noqa: BLE001 - a build without this record: say so, never fail a cell
        return "unknown"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"
