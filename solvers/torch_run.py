"""The settings every PyTorch planner runs under, set for one run and restored after it.

Deterministic algorithms (same seed, same bits on the same machine), ``threads`` torch intra-op
threads (0: torch's own setting) and one numba thread: the learners evaluate one or a few layouts
at a time, and the oracle's threads would only spin beside torch's (measured: a step 5-10x slower).
"""

from __future__ import annotations

import contextlib

import numba
import torch


@contextlib.contextmanager
def torch_run(threads: int):
    """Run the block with deterministic algorithms, ``threads`` torch threads and one numba thread;
    restore the three settings afterwards, however the block ends."""
    saved = torch.get_num_threads(), numba.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        if threads:
            torch.set_num_threads(threads)
        numba.set_num_threads(1)
        yield
    finally:
        torch.set_num_threads(saved[0])
        numba.set_num_threads(saved[1])
        torch.use_deterministic_algorithms(saved[2])
