"""The sparse direct factor (MKL PARDISO), the threads each solver runs on, and opalflow's own kernels run
in parts on threads (:func:`in_parts`).

Used by the static method's ``direct`` solver and the quasi-static method's direct re-solves
(:mod:`opalflow.bpm.static`, :mod:`opalflow.bpm.quasistatic`).
"""
from __future__ import annotations

import os

import numpy as np


def thread_budget() -> int:
    """The threads this process may use: the smallest thread count of its loaded BLAS and OpenMP libraries
    (the CPUs it may run on, or less where a job set a limit: opalflow.runs.jobs.run_job)."""
    return _smallest_thread_count(("blas", "openmp"))


def kernel_threads() -> int:
    """The threads of opalflow's own kernels (:func:`in_parts`): the smallest thread count of the loaded BLAS
    libraries (the CPUs, ``OMP_NUM_THREADS`` where set, or a job's limit), not OpenMP's.  LAMMPS sets OpenMP's
    threads to 1 when it starts without ``OMP_NUM_THREADS``: a quasi-static run that built its structure
    through LAMMPS ran its kernels on one thread where the same run from the structure cache had two.  The
    factor keeps :func:`thread_budget`, OpenMP's count included: MKL's PARDISO on more threads than LAMMPS
    left to OpenMP stalled (measured: a factor of 30 000 dofs that takes a fraction of a second did not end in
    minutes, and failed with PARDISO's error -2 in the tests)."""
    return _smallest_thread_count(("blas",))


def _smallest_thread_count(apis: tuple[str, ...]) -> int:
    """The smallest thread count of the loaded libraries of threadpoolctl's ``apis`` (the CPUs where none)."""
    import scipy.linalg  # noqa: F401 - numpy's and scipy's BLAS loaded: their limit is the job's
    from threadpoolctl import threadpool_info

    counts = [lib["num_threads"] for lib in threadpool_info() if lib.get("num_threads") and lib.get("user_api") in apis]
    return max(1, min(counts, default=len(os.sched_getaffinity(0))))


def solver_threads(solver: str) -> int:
    """BLAS/OpenMP threads for ``solver``: the iterative ones run sparse products and vector sums that are
    bound by memory, not arithmetic, and lose 3-6x to thread contention on a loaded machine (measured,
    bench/results/static_threads.json): one thread; the direct factor (dense supernodes, BLAS 3) gains
    from every thread it is given (x1.8 at 140 k dofs on 2 cores): the whole budget."""
    return thread_budget() if solver == "direct" else 1


_POOL: dict = {}


def in_parts(work, parts: int, threads: int | None = None) -> None:
    """``work(k)`` for k = 0 .. ``parts`` - 1, on ``threads`` threads at once (default: one a part) where both are
    > 1, each thread taking parts in turn.  For numba kernels that release the GIL (``nogil``), each on its own
    part of the data: the bond operator over its share of the bonds, the V-cycle's products and sweeps over their
    share of the rows (:mod:`opalflow.bpm.stiffness`, :mod:`opalflow.linalg.multigrid`).  The caller chooses
    ``parts`` and ``threads``: :func:`kernel_threads`."""
    threads = parts if threads is None else min(threads, parts)
    if threads <= 1:
        for k in range(parts):
            work(k)
        return
    from concurrent.futures import ThreadPoolExecutor

    pool = _POOL.get(threads) or _POOL.setdefault(threads, ThreadPoolExecutor(threads, thread_name_prefix="opalflow"))
    for done in [pool.submit(work, k) for k in range(parts)]:
        done.result()


#: PARDISO's fill-reducing ordering: minimum degree up to this many dofs, METIS nested dissection above.
#: Analysis + factor, quickstart networks on 2 cores: 15 k dofs 0.10 + 0.15 s against METIS's 0.18 + 0.16;
#: 39 k dofs 0.39 + 1.73 s against 0.59 + 0.95; 141 k dofs 1.5 + 11.7 s against 2.5 + 8.5
AMD_MAX_DOFS = 20_000


class Factor:
    """A sparse Cholesky (LL^T) factor of a symmetric positive definite K: MKL PARDISO (pypardiso; METIS
    nested-dissection ordering, minimum degree up to AMD_MAX_DOFS; supernodes with BLAS 3, the threads of
    :func:`thread_budget`).  Measured on the quickstart's network at 140 k dofs: factor 4.1 s on 2 cores where
    CHOLMOD through cholespy (no METIS, simplicial) took 96 s (bench/results/static_quickstart.json).
    ``solve`` takes one right-hand side (n,) or several (n, k).  ``free`` (bool, (n,)): the factor of K's
    free-dof block, each prescribed dof decoupled with a unit diagonal (b zero there gives x zero there), so
    that K itself can stay whole for products."""

    def __init__(self, K, free: np.ndarray | None = None):
        import scipy.sparse as sp
        from threadpoolctl import threadpool_limits

        pypardiso = _pardiso()
        K = K.tocsr()
        K.sum_duplicates()
        rows = np.repeat(np.arange(K.shape[0], dtype=np.int32), np.diff(K.indptr))
        # the upper triangle without the zeros (decoupled prescribed dofs, the blocks' structural zeros: half
        # of the stored entries), straight from the sorted rows (scipy's triu goes through coordinates: 10x)
        data, keep = K.data, K.indices >= rows
        if free is not None:
            diagonal = K.indices == rows
            data = np.where(diagonal & ~free[rows], 1.0, data)
            keep &= (free[rows] & free[K.indices]) | diagonal
        keep &= data != 0
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep], minlength=K.shape[0]))])
        self.U = sp.csr_matrix((data[keep], K.indices[keep], indptr), shape=K.shape)
        self.U.has_sorted_indices = True
        self.size = self.U.shape[0]
        self.pardiso = pypardiso.PyPardisoSolver(mtype=2)          # real symmetric positive definite
        self.pardiso.size_limit_storage = 0                          # remember the matrix by its hash
        if self.size <= AMD_MAX_DOFS:
            self.pardiso.set_iparm(2, 0)                             # iparm[1] = 0: minimum degree ordering
        self.threads = thread_budget()
        with threadpool_limits(limits=self.threads):
            self.pardiso.factorize(self.U)

    def solve(self, b: np.ndarray) -> np.ndarray:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=self.threads):
            return self.pardiso.solve(self.U, np.asarray(b, float))

    def __del__(self):
        try:
            self.pardiso.free_memory(everything=True)
        except Exception:       # interpreter shutdown: MKL may be gone already
            pass

def _pardiso():
    """pypardiso, told where the mkl wheel put libmkl_rt (else it searches all of sys.prefix, 0.3 s a solver)."""
    import glob
    import sys

    found = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")), key=len)
    if found:
        os.environ.setdefault("PYPARDISO_MKL_RT", found[0])
    import pypardiso

    return pypardiso
