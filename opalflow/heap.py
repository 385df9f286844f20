"""How a process started as ``python -m opalflow`` gets its memory: glibc's malloc told to keep what it frees
for the arrays it allocates next, and numpy's large arrays not advised into huge pages where the kernel
would compact memory to fault one in.

A vector of the paper's sample (9.7 M dofs) is 78 MB, far above glibc's mmap threshold (32 MB at most):
each such temporary is mapped fresh and unmapped when freed, and its pages fault in again on first
touch.  On this machine (a VM) that costs up to 0.6-0.7 s per 78 MB (measured: ``m * x`` of two
9.7 M vectors, 0.63-0.76 s fresh, 0.01 s into memory used before), and CG, the V-cycle and the
quasi-static events make such temporaries at every iteration.  With the threshold at 1 GiB and the
heap not trimmed below 2 GiB, freed memory is reused: the paper's static command on one cached structure
took 4 min 37 s without (solve 134 s, set-up 87 s), 3 min 21 s with the thresholds set by GLIBC_TUNABLES
(95 s, 68 s) and 3 min 29 s by this module; peak resident memory 9.04 -> 9.1-9.5 GB.  The paper's
quasi-static run (its rule): 21 min 56 s -> 14 min 38 s.  The threshold is now mallopt's largest (2 GiB - 1,
an int): the block-amg set-up of the paper's sample makes temporaries of K_uu's 1.3 GB of blocks (pyamg's
``abs(S)``, ``omega * D^-1 S``), which above 1 GiB were mapped afresh (``np.abs`` of 1.4 GB: 0.63-0.75 s
each time, 0.1 s into reused memory); the paper's static set-up 71 -> 54-55 s (44 s where the structure was
built in the same process, its pages already faulted in), peak resident memory 8.7 -> 8.4-8.9 GB
(bench/results/static_opal_fcc_command.json).

Huge pages: numpy advises every array of 4 MB or more into transparent huge pages (``madvise(MADV_HUGEPAGE)``).
Where the kernel's THP ``defrag`` setting is ``always``, ``madvise`` or ``defer+madvise`` (the kernel default is
``madvise``), a fault in such an array waits while the kernel compacts memory for a 2 MB page.  On this machine
that made first touches 4-10x slower (``np.ones``: 80 MB 0.22 s with the advice, 0.06 s without; 240 MB 1.35 s
against 0.13 s) and the set-up of a static solve twice as long: d = 30 nm, the whole command 3.5-3.8 s -> 2.8-3.0 s
(set-up 1.6-1.8 s -> 0.85-0.93 s, the solve the same: 0.99 -> 1.05 s); the paper's sample 3 min 29 s -> 3 min 12 s
(set-up 80 -> 67 s, solve 103 -> 106 s).  Where ``defrag`` is ``defer`` or ``never`` no fault waits, and numpy's
advice is kept; so is a user's own ``NUMPY_MADVISE_HUGEPAGE``.

Set by ``python -m opalflow`` (:mod:`opalflow.__main__`: every command, job and SLURM task); a program
that imports opalflow keeps its own allocator's settings.
"""
from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

#: mallopt's parameters (malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD = (1 << 31) - 1
TRIM_THRESHOLD = (1 << 31) - 1
#: the kernel's setting for what a fault in a huge-page region does when no 2 MB page is free
THP_DEFRAG = Path("/sys/kernel/mm/transparent_hugepage/defrag")
#: the settings under which a fault in a region advised into huge pages waits for compaction
COMPACTING = ("always", "madvise", "defer+madvise")


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


def faults_compact(defrag: Path = THP_DEFRAG) -> bool:
    """Whether a fault in memory advised into huge pages waits for the kernel to compact memory (the selected
    word of ``defrag``, in brackets, is one of COMPACTING); False where the file is absent (not Linux, no THP)."""
    try:
        text = defrag.read_text()
    except OSError:
        return False
    chosen = text[text.find("[") + 1:text.find("]")] if "[" in text else ""
    return chosen in COMPACTING


def no_huge_page_advice() -> bool:
    """Switch numpy's huge-page advice off where faults in advised memory wait for compaction and the user has
    not set ``NUMPY_MADVISE_HUGEPAGE`` (module docstring); True where it was switched off."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ or not faults_compact():
        return False
    import numpy as np

    try:
        multiarray = np._core.multiarray
    except AttributeError:              # numpy < 2
        multiarray = np.core.multiarray
    multiarray._set_madvise_hugepage(False)
    return True
