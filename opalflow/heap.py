"""glibc's malloc told to keep the memory a process frees, for the arrays it allocates next.

A vector of the paper's sample (9.7 M dofs) is 78 MB, far above glibc's mmap threshold (32 MB at most):
each such temporary is mapped fresh and unmapped when freed, and its pages fault in again on first
touch.  On this machine (a VM) that costs up to 0.6-0.7 s per 78 MB (measured: ``m * x`` of two
9.7 M vectors, 0.63-0.76 s fresh, 0.01 s into memory used before), and CG, the V-cycle and the
quasi-static events make such temporaries at every iteration.  With the threshold at 1 GiB and the
heap not trimmed below 2 GiB, freed memory is reused: the paper's static command on one cached structure
took 4 min 37 s without (solve 134 s, set-up 87 s), 3 min 21 s with the thresholds set by GLIBC_TUNABLES
(95 s, 68 s) and 3 min 29 s by this module (bench/results/static_opal_fcc_command.json); peak resident
memory 9.04 -> 9.1-9.5 GB.  The paper's quasi-static run (its rule): 21 min 56 s -> 14 min 38 s.

Set by ``python -m opalflow`` (:mod:`opalflow.__main__`: every command, job and SLURM task); a program
that imports opalflow keeps its own allocator's settings.
"""
from __future__ import annotations

import ctypes
import sys

#: mallopt's parameters (malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD = 1 << 30
TRIM_THRESHOLD = (1 << 31) - 1


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds (module docstring); False where the C library is not glibc."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(libc.mallopt(M_TRIM_THRESHOLD,
                                                                                         TRIM_THRESHOLD))
    except (OSError, AttributeError):       # musl and others: their allocator as it is
        return False
