"""Smoothed-aggregation algebraic multigrid as a preconditioner: the hierarchy from pyamg's pieces with opalflow's
own smoothing of the prolongation, V-cycle and block Gauss-Seidel sweeps (numba, the block size compiled in).

Used by the static method's ``amg`` and ``block-amg`` solvers and the quasi-static method's AMG re-solves
(:mod:`opalflow.bpm.static`, :mod:`opalflow.bpm.quasistatic`); it takes a BSR matrix and its near-null space.
"""
from __future__ import annotations

import functools

import numpy as np

from opalflow.jit import njit
from opalflow.linalg.direct import in_parts


def amg_preconditioner(K, B, threads: int = 1):
    """One V-cycle of the smoothed-aggregation AMG of ``K`` (BSR) with near-null space ``B`` (:func:`hierarchy`;
    Jacobi-smoothed prolongation, omega 4/3 over a row-sum (Gershgorin) bound of the spectral radius instead of
    pyamg's Lanczos estimate: at 1.1 M dofs block-amg's set-up 11.6 -> 10.1 s for 46 iterations instead of 45;
    the rigid-body modes taken as they are: pyamg's default of improving them by four Gauss-Seidel sweeps each
    costs 40 % of the set-up and saves no iteration; one forward Gauss-Seidel sweep before and one
    backward after the coarse correction (a symmetric V-cycle, as CG needs) instead of two symmetric ones:
    10-40 % more iterations at half the cost each; measured at 140 k dofs, amg 5.3 -> 4.7 s, block-amg
    9.0 -> 7.4 s).  The sweeps are :func:`v_cycle`'s own.  Returns b -> the V-cycle's approximation of K^-1 b
    (its kernels on ``threads`` threads)."""
    return v_cycle(hierarchy(K, B, threads), threads)


#: the hierarchy's levels at most, and its coarsest level's block rows at most (solved by pyamg's pseudo-inverse)
MAX_LEVELS, MAX_COARSE = 10, 500
#: the prolongation's Jacobi weight (over each row's Gershgorin bound)
OMEGA = 4.0 / 3.0


def hierarchy(K, B, threads: int = 1):
    """The smoothed-aggregation hierarchy of ``K`` (BSR) with near-null space ``B`` (N, k), as pyamg's
    ``smoothed_aggregation_solver(K, B, strength=("symmetric", {"theta": 0.0}), max_coarse=500,
    smooth=("jacobi", {"omega": 4/3, "weighting": "local"}), improve_candidates=None)`` builds it (Vanek, Mandel
    and Brezina, Computing 56:179, 1996; pyamg's strength of connection, aggregation, tentative prolongator
    and coarse solver), but for the prolongation: smoothed here (:func:`smoothed_prolongation`) without the
    two scaled copies of the finest matrix that pyamg's ``jacobi_prolongation_smoother`` holds at once (the
    paper's sample: 2.7 GiB, its set-up's peak), on ``threads`` threads, and the coarse matrix by slabs
    (:func:`galerkin`); no restriction R kept (the V-cycle applies P^T from P).  A pyamg ``MultilevelSolver``
    without smoothers (:func:`v_cycle` brings its own).  The same matrix gives the same hierarchy to the last
    digit in any process (no random start)."""
    from pyamg.aggregation.aggregate import standard_aggregation
    from pyamg.aggregation.tentative import fit_candidates
    from pyamg.multilevel import MultilevelSolver
    from pyamg.strength import symmetric_strength_of_connection

    levels = [MultilevelSolver.Level()]
    levels[0].A, levels[0].B = K, np.asarray(B, K.dtype)
    while len(levels) < MAX_LEVELS and levels[-1].A.shape[0] // levels[-1].A.blocksize[0] > MAX_COARSE:
        A = levels[-1].A
        aggregates = standard_aggregation(symmetric_strength_of_connection(A, theta=0.0))[0]
        T, coarse_B = fit_candidates(aggregates, levels[-1].B)
        del aggregates
        P = smoothed_prolongation(A, T, threads)
        del T
        levels[-1].P, levels[-1].R = P, None         # (None: pyamg's solver would make R = P^T, a copy of P)
        levels.append(MultilevelSolver.Level())
        levels[-1].A = galerkin(A, P, threads)
        levels[-1].B = coarse_B
    return MultilevelSolver(levels)


def galerkin(A, P, threads: int = 1):
    """The coarse matrix P^T A P (BSR, k x k blocks) as the sum over :data:`SWEEP_PARTS` slabs of A's block rows
    (one below :data:`PARTS_MIN_ROWS`) of P_s^T (A_s P), the slabs on ``threads`` threads: A_s P row by row, then
    P_s^T of it by coarse rows (:func:`_row_sums`: a row's columns gathered and sorted, its blocks summed in double
    precision in a fixed order), the slabs' coarse rows added in slab order (the same digits on any number of
    threads).  pyamg forms R A whole before its product with P (1.25 GiB at the paper's sample, the set-up's
    peak): a slab's product is an eighth of it.  At the paper's sample's K_uu (1.6 M block rows, 36.6 M blocks;
    this machine, the study's jobs stopped) scipy's products of the slabs took 20.4 s (one thread), these 18.7 s on
    one thread and 9.5 s on two; the coarse matrix to 1.2e-7 of its largest entry where scipy's single precision
    left 1.3e-6 (the d = 30 nm sample)."""
    import scipy.sparse as sp

    bs, k = P.blocksize
    coarse = P.shape[1] // k
    at = _shares(len(A.indptr) - 1)
    parts = len(at) - 1
    slabs = [None] * parts

    def slab(s: int) -> None:
        first, last = int(at[s]), int(at[s + 1])
        ap = _products(A.indptr, A.indices, A.data, P.indptr, P.indices, P.data, coarse, first, last, "ab", A.dtype)
        cols = P.indices[P.indptr[first]:P.indptr[last]]
        lo, hi = int(cols.min(initial=0)), int(cols.max(initial=-1))
        ptr, rows, at_p = _transposed_pattern(P.indptr, P.indices, first, last, lo, hi)
        slabs[s] = lo, _products(ptr, rows, P.data[at_p], *ap, coarse, 0, hi - lo + 1, "tb", np.float64)

    in_parts(slab, parts, threads)
    starts, base = [], 0                 # the slabs' coarse rows stacked: row (s, I) is row s * coarse + I
    for lo, (ptr, _, _) in slabs:
        full = np.zeros(coarse + 1, np.int64)
        full[lo + 1:lo + len(ptr)] = ptr[1:]
        full[lo + len(ptr):] = ptr[-1]
        starts.append(full[:-1] + base)
        base += int(ptr[-1])
    stacked = (np.append(np.concatenate(starts), base), np.concatenate([c[1] for _, c in slabs]),
               np.concatenate([c[2] for _, c in slabs]))
    each = np.arange(0, parts * coarse + 1, parts), (np.arange(parts) * coarse + np.arange(coarse)[:, None]).ravel()
    ptr, ind, data = _products(*each, np.zeros((1, k, k)), *stacked, coarse, 0, coarse, "b", A.dtype)
    return sp.bsr_matrix((data, ind.astype(P.indices.dtype), ptr.astype(P.indptr.dtype)),
                         shape=(coarse * k, coarse * k))


def _products(Xptr, Xind, Xdata, Yptr, Yind, Ydata, width: int, first: int, last: int, mode: str, dtype):
    """Rows ``first`` .. ``last`` - 1 of the block-sparse product X Y, X's blocks taken as ``mode`` says
    (:func:`_row_sums`), Y's columns < ``width``: (indptr from 0, sorted column indices, blocks in ``dtype``)."""
    mark = np.full(width, -1, np.int64)
    sizes = np.zeros(last - first, np.int64)
    _row_sizes(Xptr, Xind, Yptr, Yind, mark, sizes, first, last)
    ptr = np.zeros(last - first + 1, np.int64)
    np.cumsum(sizes, out=ptr[1:])
    m = {"ab": Xdata.shape[1], "tb": Xdata.shape[2], "b": Ydata.shape[1]}[mode]          # (the result's rows)
    n, q = Ydata.shape[1], Ydata.shape[2]
    ind, data = np.empty(ptr[-1], np.int64), np.empty((ptr[-1], m, q), dtype)
    mark[:] = -1
    acc = np.empty((int(sizes.max(initial=1)), m, q))
    _row_sums(m, n, q, mode)(Xptr, Xind, Xdata, Yptr, Yind, Ydata, mark, acc, ptr, ind, data, first, last)
    return ptr, ind, data


@njit(cache=True, nogil=True)
def _row_sizes(Xptr, Xind, Yptr, Yind, mark, sizes, first, last):
    """sizes[r - first]: how many distinct columns row r of X Y has (the columns of Y's rows that X's row r names),
    rows ``first`` .. ``last`` - 1; ``mark`` (Y's columns,) -1 on entry."""
    for r in range(first, last):
        n = 0
        for x in range(Xptr[r], Xptr[r + 1]):
            row = Xind[x]
            for y in range(Yptr[row], Yptr[row + 1]):
                if mark[Yind[y]] != r:
                    mark[Yind[y]] = r
                    n += 1
        sizes[r - first] = n


@njit(cache=True, nogil=True)
def _transposed_pattern(ptr, ind, first, last, lo, hi):
    """The columns ``lo`` .. ``hi`` of block rows ``first`` .. ``last`` - 1 of (ptr, ind) as rows: (indptr, the
    rows - ``first`` holding each column in ascending order, their positions in ``ind``)."""
    count = np.zeros(hi - lo + 2, np.int64)
    for p in range(ptr[first], ptr[last]):
        count[ind[p] - lo + 1] += 1
    at = np.cumsum(count)
    rows, where, fill = np.empty(at[-1], np.int64), np.empty(at[-1], np.int64), at[:-1].copy()
    for r in range(first, last):
        for p in range(ptr[r], ptr[r + 1]):
            c = ind[p] - lo
            rows[fill[c]], where[fill[c]] = r - first, p
            fill[c] += 1
    return at, rows, where


@functools.cache
def _row_sums(m: int, n: int, q: int, mode: str):
    """The numeric pass of :func:`_products` for m x q result blocks, compiled for the block sizes: each row r's
    columns gathered (as :func:`_row_sizes` counts them) and sorted, then its blocks summed over X's row r in order
    (and over each named Y row in order) in double precision, ``mode`` "ab": X's n x n blocks times Y's n x q, "tb":
    X's n x m blocks transposed times Y's n x q, "b": Y's blocks alone (X only names rows).  ``mark`` -1 on
    entry; while a row is summed it holds -2 - the slot of each of its columns."""
    product, transposed = mode == "ab", mode == "tb"

    @njit(cache=True, nogil=True)
    def sums(Xptr, Xind, Xdata, Yptr, Yind, Ydata, mark, acc, Optr, Oind, Odata, first, last):
        for r in range(first, last):
            start, size = Optr[r - first], Optr[r - first + 1] - Optr[r - first]
            k = 0
            for x in range(Xptr[r], Xptr[r + 1]):
                for y in range(Yptr[Xind[x]], Yptr[Xind[x] + 1]):
                    if mark[Yind[y]] != r:
                        mark[Yind[y]] = r
                        Oind[start + k] = Yind[y]
                        k += 1
            cols = Oind[start:start + size]
            cols.sort()
            for s in range(size):
                mark[cols[s]] = -2 - s
                acc[s] = 0.0
            for x in range(Xptr[r], Xptr[r + 1]):
                for y in range(Yptr[Xind[x]], Yptr[Xind[x] + 1]):
                    s = -2 - mark[Yind[y]]
                    if product or transposed:                  # (a sum in a register: ~1.3x the sum in acc)
                        for a in range(m):
                            for c in range(q):
                                t = acc[s, a, c]
                                for b in range(n):
                                    t += (Xdata[x, a, b] if product else Xdata[x, b, a]) * Ydata[y, b, c]
                                acc[s, a, c] = t
                    else:
                        for a in range(m):
                            for c in range(q):
                                acc[s, a, c] += Ydata[y, a, c]
            for s in range(size):
                Odata[start + s] = acc[s]
                mark[cols[s]] = r

    return sums


def smoothed_prolongation(A, T, threads: int = 1):
    """P = T - omega D^-1 A T (Jacobi smoothing of the tentative prolongator T, BSR of bs x k blocks, one a row at
    most), D the diagonal of each row's sum of |A_ij| (pyamg's ``jacobi_prolongation_smoother`` with
    ``weighting="local"``, :data:`OMEGA`): each block row of P in one pass over the same row of A
    (:func:`_prolongation_rows`), its columns the aggregates of the row's neighbours, sorted; computed in
    double precision and stored in A's.  No copy of A (pyamg scales two: D^-1 A and omega D^-1 A)."""
    import scipy.sparse as sp

    bs, k = A.blocksize[0], T.blocksize[1]
    rows, coarse = A.shape[0] // bs, T.shape[1] // k
    at = _shares(rows)
    parts = len(at) - 1
    count, fill = _prolongation_rows(bs, k)
    tags = np.full((parts, coarse), -1, np.int64)
    sizes = np.zeros(rows, np.int64)
    in_parts(lambda s: count(A.indptr, A.indices, T.indptr, T.indices, tags[s], sizes, at[s], at[s + 1]), parts,
             threads)
    indptr = np.zeros(rows + 1, np.int64)
    np.cumsum(sizes, out=indptr[1:])
    indices = np.empty(indptr[-1], A.indices.dtype)
    data = np.empty((indptr[-1], bs, k), A.dtype)
    tags[:] = -1
    widest = int(sizes.max(initial=1))
    in_parts(lambda s: fill(A.indptr, A.indices, A.data, T.indptr, T.indices, T.data, OMEGA, tags[s],
                            np.empty((widest, bs, k)), indptr, indices, data, at[s], at[s + 1]), parts, threads)
    return sp.bsr_matrix((data, indices, indptr.astype(A.indptr.dtype)), shape=(A.shape[0], T.shape[1]))


@functools.cache
def _prolongation_rows(bs: int, k: int):
    """(count, fill) over block rows ``first`` .. ``last`` - 1 for :func:`smoothed_prolongation`, compiled for bs x
    bs blocks of A and bs x k of T: ``count`` each row's aggregates (its own and its neighbours'), ``fill`` its
    blocks; ``tag`` (coarse,) scratch of the share, -1 on entry and left so by ``fill`` (a row marks the
    aggregates it has seen, -2 in ``fill``, then their slot in its row)."""

    @njit(cache=True, nogil=True)
    def count(Aptr, Aind, Tptr, Tind, tag, sizes, first, last):
        for row in range(first, last):
            n = 0
            a = Tind[Tptr[row]] if Tptr[row + 1] > Tptr[row] else -1
            if a >= 0:
                tag[a] = row
                n += 1
            for jj in range(Aptr[row], Aptr[row + 1]):
                j = Aind[jj]
                a = Tind[Tptr[j]] if Tptr[j + 1] > Tptr[j] else -1
                if a >= 0 and tag[a] != row:
                    tag[a] = row
                    n += 1
            sizes[row] = n

    @njit(cache=True, nogil=True)
    def fill(Aptr, Aind, Adata, Tptr, Tind, Tdata, omega, tag, acc, Pptr, Pind, Pdata, first, last):
        d = np.empty(bs)
        for row in range(first, last):
            start, n = Pptr[row], Pptr[row + 1] - Pptr[row]
            m = 0
            own = Tind[Tptr[row]] if Tptr[row + 1] > Tptr[row] else -1
            if own >= 0:
                tag[own] = -2
                Pind[start] = own
                m = 1
            for jj in range(Aptr[row], Aptr[row + 1]):
                j = Aind[jj]
                a = Tind[Tptr[j]] if Tptr[j + 1] > Tptr[j] else -1
                if a >= 0 and tag[a] == -1:
                    tag[a] = -2
                    Pind[start + m] = a
                    m += 1
            cols = Pind[start:start + n]
            cols.sort()
            for s in range(n):
                tag[cols[s]] = s
                for a in range(bs):
                    for c in range(k):
                        acc[s, a, c] = 0.0
            for a in range(bs):
                d[a] = 0.0
            for jj in range(Aptr[row], Aptr[row + 1]):
                for a in range(bs):
                    for b in range(bs):
                        d[a] += abs(Adata[jj, a, b])
                j = Aind[jj]
                if Tptr[j + 1] == Tptr[j]:
                    continue
                s, tb = tag[Tind[Tptr[j]]], Tptr[j]
                for a in range(bs):
                    for b in range(bs):
                        ab = Adata[jj, a, b]
                        for c in range(k):
                            acc[s, a, c] += ab * Tdata[tb, b, c]
            for a in range(bs):
                w = -omega / d[a] if d[a] != 0.0 else 0.0
                for s in range(n):
                    for c in range(k):
                        Pdata[start + s, a, c] = w * acc[s, a, c]
            if own >= 0:
                s, tb = tag[own], Tptr[row]
                for a in range(bs):
                    for c in range(k):
                        Pdata[start + s, a, c] += Tdata[tb, a, c]
            for s in range(n):
                tag[cols[s]] = -1

    return count, fill


def v_cycle(ml, threads: int = 1):
    """b -> one V-cycle from x = 0 on the hierarchy ``ml`` (:func:`hierarchy`, or any pyamg ``MultilevelSolver``;
    as MultilevelSolver.__solve: P, its transpose and the coarse solver), a forward block Gauss-Seidel sweep
    (:func:`smoothers`) before the coarse correction and a backward one after.  pyamg's own preconditioner
    (``aspreconditioner``) also forms the fine-level residual before the cycle and after it, two products with
    the finest matrix that a preconditioner does not need, and its block Gauss-Seidel loops over a block size
    it learns at run time.  Measured: block-amg's
    preconditioner 41 -> 27 ms a call at 140 k dofs (own sweeps in single precision); amg's at the paper's
    sample at d = 45 nm (310 k dofs), the first 40 quasi-static events, 124 -> 65 ms a call for the same
    405 CG iterations.  Each level's sweeps, the first with its residual (the matrix read once), and its
    transfers (:func:`transfers`) run on ``threads`` threads; P^T is applied from P (pyamg's restriction R, a copy
    of P^T: the paper's sample, 0.45 GiB).  The paper's sample's V-cycle (4 levels, 4.9 M unknowns on the
    finest) on two threads: 1 254 -> 592 ms a call (the sweeps above; its transfers 177 + 147 ms by scipy's
    products on one thread, 93 + 61 here; bench/results/paper_scale.json ``kernels``)."""
    levels = ml.levels
    bsr = [lv.A if lv.A.format == "bsr" else lv.A.tobsr(blocksize=(1, 1)) for lv in levels[:-1]]
    sweeps = [smoothers(A, threads) for A in bsr]
    moves = [transfers(lv.P if lv.P.format == "bsr" else lv.P.tobsr(), threads) for lv in levels[:-1]]

    def cycle(lvl: int, b: np.ndarray) -> np.ndarray:
        A = levels[lvl].A
        if lvl == len(levels) - 1:
            return np.asarray(ml.coarse_solver(A, b), b.dtype).reshape(b.shape)
        x, r = sweeps[lvl][0](b)
        down, up = moves[lvl]
        x += up(cycle(lvl + 1, down(r)))
        sweeps[lvl][1](x, b)
        return x

    return lambda b: cycle(0, np.ascontiguousarray(b))


#: the sweeps of :func:`smoothers` and the products of :func:`transfers` run on threads
#: from this many block rows (the paper's sample's K_uu: 1.6 M) ...
PARTS_MIN_ROWS = 20_000
#: ... and split a matrix's block rows into this many
#: contiguous shares from :data:`PARTS_MIN_ROWS` block rows (a fixed number: the same digits on any number of
#: threads; each thread takes shares in turn)
SWEEP_PARTS = 8


def _shares(rows: int) -> np.ndarray:
    """The bounds of :data:`SWEEP_PARTS` contiguous shares of ``rows`` block rows (one share below
    :data:`PARTS_MIN_ROWS`)."""
    return np.linspace(0, rows, (SWEEP_PARTS if rows >= PARTS_MIN_ROWS else 1) + 1).astype(np.int64)


def smoothers(A, threads: int = 1):
    """(first, backward) for a BSR matrix ``A``: ``first`` b -> (x, b - A x), one forward block Gauss-Seidel sweep
    from x = 0 and its residual, ``backward`` (x, b) -> one backward sweep over A in place, rows and each row's
    blocks reversed (:func:`_sweeps`).  Above :data:`PARTS_MIN_ROWS` block rows a sweep is hybrid (the parallel
    Gauss-Seidel of hypre's BoomerAMG; Baker, Falgout, Kolev and Yang, SIAM J. Sci. Comput. 33:2864, 2011):
    each of :data:`SWEEP_PARTS` shares of the rows is swept on its own, the other shares' unknowns taken as the
    sweep found them, so the shares run on ``threads`` threads at once and give the same digits on any number;
    the backward sweep is the forward one's adjoint, as CG needs.  One share is the sequential sweep (pyamg's
    block_gauss_seidel).  From x = 0 the forward sweep needs only each share's blocks left of the diagonal, and
    since each row then solved its own equation with the blocks it used, b - A x is minus the other blocks times
    x: the matrix read once for the V-cycle's pre-smoothing and its residual instead of twice (the residual
    the same to the rounding).  Measured at the paper's sample (K_uu in float32, 1.6 M block rows, 36.6 M
    blocks; bench/results/paper_scale.json): forward and backward 326 and 314 ms sequential (the backward one
    over a reversed copy of the matrix, 1.2 GiB there, now gone), 189 and 132 ms hybrid on two threads; the
    forward sweep and the residual 224 + 227 ms, 215 ms in one pass."""
    from pyamg.util.utils import get_block_diag

    bs = A.blocksize[0]
    A.sort_indices()
    D = get_block_diag(A, bs, inv_flag=True).astype(A.dtype)
    at = _shares(len(A.indptr) - 1)
    parts = len(at) - 1
    lower, rest, backward = _sweeps(bs)
    matrix = A.indptr, A.indices, A.data
    split = _diagonal_split(A.indptr, A.indices)

    def first(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, r = np.empty_like(b), np.empty_like(b)
        in_parts(lambda k: lower(*matrix, split, D, x, b, at[k], at[k + 1]), parts, threads)
        in_parts(lambda k: rest(*matrix, split, x, r, at[k], at[k + 1]), parts, threads)
        return x, r

    def back(x: np.ndarray, b: np.ndarray) -> None:
        old = x.copy() if parts > 1 else x
        in_parts(lambda k: backward(*matrix, D, x, old, b, at[k], at[k + 1]), parts, threads)

    return first, back


@njit(cache=True)
def _diagonal_split(indptr, indices):
    """Each block row's first position whose column is not left of the diagonal (columns sorted)."""
    rows = len(indptr) - 1
    split = np.empty(rows, np.int64)
    for row in range(rows):
        jj = indptr[row]
        while jj < indptr[row + 1] and indices[jj] < row:
            jj += 1
        split[row] = jj
    return split


@functools.cache
def _sweeps(bs: int):
    """The block Gauss-Seidel kernels of :func:`smoothers` over block rows ``first`` .. ``last`` - 1 of a BSR
    matrix of ``bs`` x ``bs`` blocks, compiled for that block size (the loops over the block unrolled: 6 x 6
    blocks 70 ms a sweep at 3.8 M blocks where a block size known only at run time takes 130 and pyamg's
    amg_core.block_gauss_seidel 110), x_i = D_i^-1 (b_i - sum over j != i of A_ij x_j):
    ``lower(indptr, indices, data, split, Dinv, x, b, first, last)`` the forward sweep from x = 0 (the share's
    blocks left of the diagonal, up to ``split``: :func:`_diagonal_split`; x written), ``rest(indptr, indices,
    data, split, x, r, first, last)`` r = -(the blocks ``lower`` left out) x, after every share's ``lower``
    (each a loop over its own blocks, no test per block: columns sorted), and ``backward(indptr, indices, data,
    Dinv, x, old, b, first, last)`` the backward sweep from x, rows and blocks in reverse, x_j read from ``old``
    outside the share (``old`` is ``x`` for a whole sweep)."""
    return _lower_sweep(bs), _rest_sweep(bs), _backward_sweep(bs)


@functools.cache
def _lower_sweep(bs: int):
    """The forward sweep of block rows ``first`` .. ``last`` - 1 (:func:`_sweeps`)."""

    @njit(cache=True, nogil=True)
    def lower(indptr, indices, data, split, Dinv, x, b, first, last):
        r = np.empty(bs, data.dtype)
        for row in range(first, last):
            at = row * bs
            for a in range(bs):
                r[a] = b[at + a]
            jj = indptr[row]
            while jj < split[row] and indices[jj] < first:          # (columns sorted: the share's from here)
                jj += 1
            for jj in range(jj, split[row]):
                xat = indices[jj] * bs
                for c in range(bs):
                    xc = x[xat + c]
                    for a in range(bs):
                        r[a] -= data[jj, a, c] * xc
            for a in range(bs):
                acc = 0.0
                for c in range(bs):
                    acc += Dinv[row, a, c] * r[c]
                x[at + a] = acc

    return lower


@functools.cache
def _rest_sweep(bs: int):
    """r = -(the blocks the forward sweeps left out) x (:func:`_sweeps`)."""

    @njit(cache=True, nogil=True)
    def rest(indptr, indices, data, split, x, r, first, last):
        acc = np.empty(bs, data.dtype)
        for row in range(first, last):
            for a in range(bs):
                acc[a] = 0.0
            lo, hi, mid = indptr[row], indptr[row + 1], split[row]
            stop = lo                                   # the blocks left of the share, then right of the diagonal
            while stop < mid and indices[stop] < first:
                stop += 1
            start = mid + 1 if mid < hi and indices[mid] == row else mid
            for part in range(2):
                for jj in range(lo if part == 0 else start, stop if part == 0 else hi):
                    xat = indices[jj] * bs
                    for c in range(bs):
                        xc = x[xat + c]
                        for a in range(bs):
                            acc[a] -= data[jj, a, c] * xc
            for a in range(bs):
                r[row * bs + a] = acc[a]

    return rest


@functools.cache
def _backward_sweep(bs: int):
    """The backward sweep of block rows ``last`` - 1 .. ``first`` (:func:`_sweeps`)."""

    @njit(cache=True, nogil=True)
    def backward(indptr, indices, data, Dinv, x, old, b, first, last):
        r = np.empty(bs, data.dtype)
        for k in range(last - first):
            row = last - 1 - k
            at = row * bs
            for a in range(bs):
                r[a] = b[at + a]
            lo, hi = indptr[row], indptr[row + 1]
            for kk in range(hi - lo):
                jj = hi - 1 - kk
                col = indices[jj]
                xat = col * bs
                if first <= col < last:
                    if col != row:
                        for c in range(bs):
                            xc = x[xat + c]
                            for a in range(bs):
                                r[a] -= data[jj, a, c] * xc
                else:
                    for c in range(bs):
                        xc = old[xat + c]
                        for a in range(bs):
                            r[a] -= data[jj, a, c] * xc
            for a in range(bs):
                acc = 0.0
                for c in range(bs):
                    acc += Dinv[row, a, c] * r[c]
                x[at + a] = acc

    return backward


def transfers(P, threads: int = 1):
    """(r -> P^T r, e -> P e) for pyamg's prolongation ``P`` (BSR), both on ``threads`` threads
    (:func:`_transfer_kernels`): P e by shares of P's block rows; P^T r by the same shares, each into a coarse
    vector of its own, added in share order (the same digits on any number of threads)."""
    br, bc = P.blocksize
    rows, coarse = len(P.indptr) - 1, P.shape[1]
    at = _shares(rows)
    parts = len(at) - 1
    forward, transposed = _transfer_kernels(br, bc)

    def down(r: np.ndarray) -> np.ndarray:
        outs = np.zeros((parts, coarse), r.dtype)
        in_parts(lambda k: transposed(P.indptr, P.indices, P.data, r, outs[k], at[k], at[k + 1]), parts, threads)
        return outs.sum(axis=0) if parts > 1 else outs[0]

    def up(e: np.ndarray) -> np.ndarray:
        out = np.empty(P.shape[0], e.dtype)
        in_parts(lambda k: forward(P.indptr, P.indices, P.data, e, out, at[k], at[k + 1]), parts, threads)
        return out

    return down, up


@functools.cache
def _transfer_kernels(br: int, bc: int):
    """(P e, P^T r) over block rows ``first`` .. ``last`` - 1 of a BSR matrix of ``br`` x ``bc`` blocks: the first
    writes those rows of ``out``, the second adds their part of P^T r into ``out`` (the coarse vector)."""

    @njit(cache=True, nogil=True)
    def forward(indptr, indices, data, e, out, first, last):
        acc = np.empty(br, out.dtype)
        for row in range(first, last):
            for a in range(br):
                acc[a] = 0.0
            for jj in range(indptr[row], indptr[row + 1]):
                at = indices[jj] * bc
                for c in range(bc):
                    ec = e[at + c]
                    for a in range(br):
                        acc[a] += data[jj, a, c] * ec
            for a in range(br):
                out[row * br + a] = acc[a]

    @njit(cache=True, nogil=True)
    def transposed(indptr, indices, data, r, out, first, last):
        for row in range(first, last):
            at = row * br
            for jj in range(indptr[row], indptr[row + 1]):
                to = indices[jj] * bc
                for c in range(bc):
                    acc = 0.0
                    for a in range(br):
                        acc += data[jj, a, c] * r[at + a]
                    out[to + c] += acc

    return forward, transposed
