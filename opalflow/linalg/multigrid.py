"""Smoothed-aggregation algebraic multigrid as a preconditioner: pyamg's hierarchy, opalflow's own V-cycle and
block Gauss-Seidel sweeps (numba, the block size compiled in).

Used by the static method's ``amg`` and ``block-amg`` solvers and the quasi-static method's AMG re-solves
(:mod:`opalflow.bpm.static`, :mod:`opalflow.bpm.quasistatic`); it takes a BSR matrix and its near-null space.
"""
from __future__ import annotations

import functools

import numpy as np

from opalflow.jit import njit


def amg_preconditioner(K, B, threads: int = 1):
    """One V-cycle of the smoothed-aggregation AMG of ``K`` (BSR) with near-null space ``B`` (pyamg; Jacobi-smoothed
    prolongation, omega 4/3 over a row-sum (Gershgorin) bound of the spectral radius instead of pyamg's
    Lanczos estimate: at 1.1 M dofs block-amg's set-up 11.6 -> 10.1 s for 46 iterations instead of 45; the
    rigid-body modes taken as they are: pyamg's default of improving them by four Gauss-Seidel sweeps each
    costs 40 % of the set-up and saves no iteration; one forward Gauss-Seidel sweep before and one
    backward after the coarse correction (a symmetric V-cycle, as CG needs) instead of two symmetric ones:
    10-40 % more iterations at half the cost each; measured at 140 k dofs, amg 5.3 -> 4.7 s, block-amg
    9.0 -> 7.4 s).  pyamg starts its spectral-radius estimates from numpy's global random generator: it is
    seeded here (and restored after), so the same matrix gives the same hierarchy, and the same solve to
    the last digit, in any process (a local pool, a Dask worker, a SLURM task).  The sweeps are
    :func:`v_cycle`'s own (pyamg sets up no smoother).  Returns b -> the V-cycle's approximation of K^-1 b
    (its residuals on ``threads`` threads: :func:`residual`)."""
    import pyamg

    state = np.random.get_state()
    np.random.seed(20240901)
    try:
        ml = pyamg.smoothed_aggregation_solver(K, B=B, strength=("symmetric", {"theta": 0.0}), max_coarse=500,
                                               smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
                                               improve_candidates=None, presmoother=None, postsmoother=None)
        return v_cycle(ml, threads)
    finally:
        np.random.set_state(state)

def v_cycle(ml, threads: int = 1):
    """b -> one V-cycle from x = 0 on pyamg's hierarchy ``ml`` (as MultilevelSolver.__solve: R, P and its
    coarse solver), a forward block Gauss-Seidel sweep (:func:`gauss_seidel`) before the coarse correction and
    a backward one after, run as a forward sweep over a copy of the level's matrix with its rows and columns
    reversed (:func:`smoothers`: this CPU reads memory in descending order 2.4x slower; the copy doubles
    the hierarchy's memory).  pyamg's own preconditioner (``aspreconditioner``) also forms the fine-level
    residual before the cycle and after it, two products with the finest matrix that a preconditioner does
    not need, and its block Gauss-Seidel loops over a block size it learns at run time.  Measured: block-amg's
    preconditioner 41 -> 27 ms a call at 140 k dofs (own sweeps in single precision); amg's at the paper's
    sample at d = 45 nm (310 k dofs), the first 40 quasi-static events, 124 -> 65 ms a call for the same
    405 CG iterations (pyamg's sweeps 115 ms forward and 210 backward a sweep at d = 30 nm, these 70 and 70).
    Each level's residual b - A x is :func:`residual`'s, on ``threads`` threads."""
    levels = ml.levels
    bsr = [lv.A if lv.A.format == "bsr" else lv.A.tobsr(blocksize=(1, 1)) for lv in levels[:-1]]
    sweeps = [smoothers(A) for A in bsr]
    residuals = [residual(A, threads) for A in bsr]

    def cycle(lvl: int, b: np.ndarray) -> np.ndarray:
        A = levels[lvl].A
        if lvl == len(levels) - 1:
            return np.asarray(ml.coarse_solver(A, b), b.dtype).reshape(b.shape)
        x = np.zeros_like(b)
        sweeps[lvl][0](x, b)
        x += levels[lvl].P @ cycle(lvl + 1, levels[lvl].R @ residuals[lvl](x, b))
        sweeps[lvl][1](x, b)
        return x

    return lambda b: cycle(0, np.ascontiguousarray(b))

def smoothers(A):
    """(forward, backward) for a BSR matrix ``A``: (x, b) -> one block Gauss-Seidel sweep over A in place, rows
    in order (:func:`gauss_seidel`) or reversed (the kernel compiled for reversed order run over
    :func:`_reversed`: it reads x and b where they are, block n - 1 - k for the copy's k; flipping the two
    vectors before the sweep and x after cost 6 of the paper's 106 s of solve)."""
    from pyamg.util.utils import get_block_diag

    bs = A.blocksize[0]
    D = get_block_diag(A, bs, inv_flag=True).astype(A.dtype)
    rev = _reversed(A)
    D_rev = np.ascontiguousarray(D[::-1])
    sweep, sweep_reversed = gauss_seidel(bs), gauss_seidel(bs, reversed_order=True)

    def forward(x: np.ndarray, b: np.ndarray) -> None:
        sweep(A.indptr, A.indices, A.data, D, x, b)

    def backward(x: np.ndarray, b: np.ndarray) -> None:
        sweep_reversed(rev.indptr, rev.indices, rev.data, D_rev, x, b)

    return forward, backward

def _reversed(A):
    """A with its block rows and columns in reverse order (P A P, P the block reversal): a backward sweep over A
    is a forward one over it, which this CPU runs 2.4x faster (memory read in descending order)."""
    import scipy.sparse as sp

    n = A.shape[0] // A.blocksize[0]
    counts = np.diff(A.indptr)[::-1]
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(A.indptr.dtype)
    # (every stored block in reverse order: the rows reversed, and within each row the columns)
    return sp.bsr_matrix((np.ascontiguousarray(A.data[::-1]), (n - 1 - A.indices[::-1]).astype(A.indices.dtype),
                          indptr), shape=A.shape)

@functools.cache
def gauss_seidel(bs: int, reversed_order: bool = False):
    """One forward block Gauss-Seidel sweep over a BSR matrix of ``bs`` x ``bs`` blocks, compiled for that block
    size (the loops over it unrolled: 6 x 6 blocks 70 ms a sweep at 3.8 M blocks where a block size known
    only at run time takes 130 and pyamg's amg_core.block_gauss_seidel 110): ``sweep(indptr, indices, data,
    Dinv, x, b)`` sets x_i = D_i^-1 (b_i - sum over j != i of A_ij x_j), rows in order.  ``reversed_order``:
    the matrix is :func:`_reversed`'s copy of the one x and b belong to, its block k is their block n - 1 - k
    (a backward sweep over the original)."""

    @njit(cache=True, nogil=True)
    def sweep(indptr, indices, data, Dinv, x, b):
        last = len(indptr) - 2
        r = np.empty(bs, data.dtype)
        for row in range(len(indptr) - 1):
            at = (last - row if reversed_order else row) * bs
            for a in range(bs):
                r[a] = b[at + a]
            for jj in range(indptr[row], indptr[row + 1]):
                col = indices[jj]
                if col != row:
                    xat = (last - col if reversed_order else col) * bs
                    for c in range(bs):
                        xc = x[xat + c]
                        for a in range(bs):
                            r[a] -= data[jj, a, c] * xc
            for a in range(bs):
                acc = 0.0
                for c in range(bs):
                    acc += Dinv[row, a, c] * r[c]
                x[at + a] = acc

    return sweep


#: :func:`residual` runs on threads from this many block rows (the paper's sample's K_uu: 1.6 M)
PARTS_MIN_ROWS = 20_000


def residual(A, threads: int = 1):
    """(x, b) -> b - A x for a BSR matrix ``A`` (:func:`_residual`: its block size compiled in), its block rows
    in ``threads`` contiguous shares at once (:func:`opalflow.linalg.direct.in_parts`; each row is one thread's,
    so any number of threads gives the same digits) from :data:`PARTS_MIN_ROWS` block rows."""
    from opalflow.linalg.direct import in_parts

    rows = len(A.indptr) - 1
    parts = threads if rows >= PARTS_MIN_ROWS else 1
    at = np.linspace(0, rows, parts + 1).astype(np.int64)
    kernel = _residual(A.blocksize[0])

    def of(x: np.ndarray, b: np.ndarray) -> np.ndarray:
        r = np.empty_like(b)
        in_parts(lambda k: kernel(A.indptr, A.indices, A.data, x, b, r, at[k], at[k + 1]), parts)
        return r
    return of


@functools.cache
def _residual(bs: int):
    """r = b - A x on block rows ``first`` .. ``last`` - 1 of a BSR matrix of ``bs`` x ``bs`` blocks (scipy's
    ``b - A @ x``, in one pass and without its temporaries)."""

    @njit(cache=True, nogil=True)
    def kernel(indptr, indices, data, x, b, r, first, last):
        acc = np.empty(bs, data.dtype)
        for row in range(first, last):
            at = row * bs
            for a in range(bs):
                acc[a] = b[at + a]
            for jj in range(indptr[row], indptr[row + 1]):
                xat = indices[jj] * bs
                for c in range(bs):
                    xc = x[xat + c]
                    for a in range(bs):
                        acc[a] -= data[jj, a, c] * xc
            for a in range(bs):
                r[at + a] = acc[a]

    return kernel
