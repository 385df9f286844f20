"""Pair search with the minimum-image convention along the periodic directions."""
from __future__ import annotations

import numpy as np

from opalflow.jit import njit

#: pairs from which :func:`separations` runs compiled (numba) rather than numpy's gathers: below it numba's start
#: (0.3 s, :mod:`opalflow.jit`) costs more than the kernel saves; at the paper's sample (17.5 M bonds in cell
#: order) numpy's gathers and minimum image take 0.7-0.8 s a call, the kernel 0.3 s
KERNEL_MIN_PAIRS = 1_000_000


def kdtree(points: np.ndarray, boxsize=None):
    """scipy's k-d tree of ``points`` (periodic where ``boxsize`` is given).  scipy.spatial is imported here, when
    a tree is built (0.1-0.2 s): a run whose structure comes from the cache never needs it."""
    from scipy.spatial import cKDTree

    return cKDTree(points, boxsize=boxsize)


#: :func:`pairs_within` and :func:`neighbour_counts` by scipy's k-d trees below this many points, by a cell
#: list from it (:class:`CellList`)
CELL_MIN_POINTS = 100_000
#: the cell list's searches split their points into this many shares (on the kernels' threads)
SHARES = 8


def pairs_within(x: np.ndarray, r: float, box: np.ndarray, periodic) -> np.ndarray:
    """All pairs (i < j) no further apart than r, sorted by (i, j), as an (M, 2) int64 array (:func:`_wrapped`):
    scipy's k-d tree (``query_pairs``) below :data:`CELL_MIN_POINTS` points, the cell list from it (the same pairs,
    tests/test_packing.py; the paper's sample's 17.5 M bonds in 3.6 s on two threads where the tree and the sort
    took 10.1)."""
    y, size = _wrapped(x, r, box, periodic)
    if len(y) >= CELL_MIN_POINTS:
        return CellList(y, size, r).pairs(r)
    pairs = kdtree(y, boxsize=size).query_pairs(r, output_type="ndarray").astype(np.int64)
    pairs.sort(axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def neighbour_counts(x: np.ndarray, centres: np.ndarray, radii: np.ndarray, box: np.ndarray, periodic) -> np.ndarray:
    """For each of ``radii``: the pairs (a particle of the ``centres`` mask, any particle, itself included) no
    further apart than it, wrapped as :func:`pairs_within` wraps; no list of pairs (g(r) of the paper's sample took
    20 M pairs, 1 GiB and ~10 s that way): scipy's dual-tree ``count_neighbors`` (``cumulative=True``) below
    :data:`CELL_MIN_POINTS` points, the cell list from it (the same integers, tests/test_packing.py; the paper's
    sample's g(r) shells in 2.3 s on two threads where the trees took 8.4)."""
    y, size = _wrapped(x, float(np.max(radii)), box, periodic)
    if len(y) >= CELL_MIN_POINTS:
        return CellList(y, size, float(np.max(radii))).counts(np.flatnonzero(centres), radii)
    return kdtree(y[centres], boxsize=size).count_neighbors(kdtree(y, boxsize=size), radii, cumulative=True)


class CellList:
    """Points ``y`` in a periodic box ``size`` (:func:`_wrapped`'s) sorted into cells at least ``reach`` wide: the
    searches within ``reach`` of a point look at its cell and the 26 around it (along a direction of fewer than
    three cells, each cell once), the minimum image taken; by :data:`SHARES` shares of the points on the kernels'
    threads (each share's own results, put together in share order)."""

    def __init__(self, y: np.ndarray, size: np.ndarray, reach: float):
        self.y, self.size = y, size
        self.cells = np.maximum(1, np.floor(size / reach)).astype(np.int64)
        self.which = np.minimum((y / size * self.cells).astype(np.int64), self.cells - 1)
        flat = (self.which[:, 0] * self.cells[1] + self.which[:, 1]) * self.cells[2] + self.which[:, 2]
        self.order = np.argsort(flat, kind="stable")
        self.start = np.searchsorted(flat[self.order], np.arange(np.prod(self.cells) + 1))

    def _each(self, work, points: np.ndarray) -> list:
        from opalflow.linalg.direct import in_parts, kernel_threads

        at = np.linspace(0, len(points), SHARES + 1).astype(np.int64)
        out = [None] * SHARES

        def share(k: int) -> None:
            out[k] = work(points[at[k]:at[k + 1]])
        in_parts(share, SHARES, kernel_threads())
        return out

    def _search(self, points, r2, mode, counts, pairs):
        return _cell_search(self.y, self.size, self.cells, self.which, self.start, self.order, points, r2, mode,
                            counts, pairs)

    def counts(self, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """For each of ``radii``: the points no further than it from each of ``centres`` (indices), summed."""
        r2 = np.asarray(radii, float) ** 2

        def work(points):
            out = np.zeros(len(r2), np.int64)
            self._search(points, r2, 0, out, _NO_PAIRS)
            return out
        return np.sum(self._each(work, centres), axis=0)

    def pairs(self, r: float) -> np.ndarray:
        """The pairs (i < j) no further apart than ``r``, sorted by (i, j)."""
        r2 = np.array([r * r])

        def work(points):
            sizes = np.zeros(len(points), np.int64)
            self._search(points, r2, 1, sizes, _NO_PAIRS)
            found = np.empty((int(sizes.sum()), 2), np.int64)
            self._search(points, r2, 2, np.cumsum(sizes) - sizes, found)
            return found
        return np.concatenate(self._each(work, np.arange(len(self.y))))


_NO_PAIRS = np.zeros((0, 2), np.int64)


@njit(cache=True, nogil=True)
def _cell_search(y, size, cells, which, start, order, points, r2, mode, counts, pairs):
    """For each of ``points`` the points of its cell and the cells around it (:class:`CellList`) no further than
    sqrt(r2[k]), minimum image: ``mode`` 0 counts[k] += their number for every k; 1 counts[p] = the number of those
    j > point p within sqrt(r2[0]); 2 writes those pairs (i, j), j ascending, into ``pairs`` from row counts[p]."""
    lo, hi = np.empty(3, np.int64), np.empty(3, np.int64)
    inverse, farthest = 1.0 / size, r2.max()
    for d in range(3):
        lo[d], hi[d] = (-1 if cells[d] >= 3 else 0), (1 if cells[d] >= 2 else 0)
    for p in range(len(points)):
        i = points[p]
        n = 0
        for ox in range(lo[0], hi[0] + 1):
            cx = (which[i, 0] + ox) % cells[0]
            for oy in range(lo[1], hi[1] + 1):
                cy = (which[i, 1] + oy) % cells[1]
                for oz in range(lo[2], hi[2] + 1):
                    c = (cx * cells[1] + cy) * cells[2] + (which[i, 2] + oz) % cells[2]
                    for q in range(start[c], start[c + 1]):
                        j = order[q]
                        if mode > 0 and j <= i:
                            continue
                        d2 = 0.0
                        for d in range(3):
                            e = y[j, d] - y[i, d]
                            e -= size[d] * np.rint(e * inverse[d])
                            d2 += e * e
                        if d2 > farthest:
                            continue
                        if mode == 0:
                            for k in range(len(r2)):
                                if d2 <= r2[k]:
                                    counts[k] += 1
                        else:
                            if mode == 2:
                                pairs[counts[p] + n, 0], pairs[counts[p] + n, 1] = i, j
                            n += 1
        if mode == 1:
            counts[p] = n
        elif mode == 2:
            pairs[counts[p]:counts[p] + n, 1].sort()


def _wrapped(x: np.ndarray, r: float, box: np.ndarray, periodic) -> tuple[np.ndarray, np.ndarray]:
    """(points, box size) for a cKDTree searched to distance ``r``.  ``x`` lies in [0, box) along periodic
    directions.  cKDTree wraps every direction when given ``boxsize``; a non-periodic direction gets a box more
    than twice as long as the data plus r, so nothing wraps across it."""
    periodic = np.asarray(periodic, dtype=bool)
    size = np.where(periodic, box, 2 * (np.ptp(x, axis=0) + r) + 1.0)
    y = np.where(periodic, np.mod(x, size), x - x.min(axis=0))
    return np.where(y >= size, y - size, y), size  # (np.mod can return size itself for tiny negatives)


def separations(x: np.ndarray, pairs: np.ndarray, box: np.ndarray, periodic) -> np.ndarray:
    """Minimum-image vectors x[j] - x[i] for each pair (i, j) (compiled from :data:`KERNEL_MIN_PAIRS`: the same
    operations in the same order, so the same digits)."""
    periodic = np.asarray(periodic, dtype=bool)
    if len(pairs) >= KERNEL_MIN_PAIRS:
        return _separations(x, pairs, np.asarray(box, np.float64), periodic)
    d = x[pairs[:, 1]] - x[pairs[:, 0]]
    for k in np.flatnonzero(periodic):
        d[:, k] -= box[k] * np.round(d[:, k] / box[k])
    return d


@njit(cache=True, nogil=True)
def _separations(x, pairs, box, periodic):
    """:func:`separations`, compiled: x[j] - x[i], less L round(d / L) along each periodic direction."""
    d = np.empty((len(pairs), 3))
    for k in range(len(pairs)):
        i, j = pairs[k, 0], pairs[k, 1]
        for a in range(3):
            v = x[j, a] - x[i, a]
            if periodic[a]:
                v -= box[a] * np.round(v / box[a])
            d[k, a] = v
    return d
