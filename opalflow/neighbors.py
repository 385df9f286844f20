"""Pair search with the minimum-image convention along the periodic directions."""
from __future__ import annotations

import numpy as np


def kdtree(points: np.ndarray, boxsize=None):
    """scipy's k-d tree of ``points`` (periodic where ``boxsize`` is given).  scipy.spatial is imported here, when
    a tree is built (0.1-0.2 s): a run whose structure comes from the cache never needs it."""
    from scipy.spatial import cKDTree

    return cKDTree(points, boxsize=boxsize)


def pairs_within(x: np.ndarray, r: float, box: np.ndarray, periodic) -> np.ndarray:
    """All pairs (i < j) closer than r, sorted by (i, j), as an (M, 2) int64 array (:func:`_wrapped`)."""
    y, size = _wrapped(x, r, box, periodic)
    tree = kdtree(y, boxsize=size)
    pairs = tree.query_pairs(r, output_type="ndarray").astype(np.int64)
    pairs.sort(axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def neighbour_counts(x: np.ndarray, centres: np.ndarray, radii: np.ndarray, box: np.ndarray, periodic) -> np.ndarray:
    """For each of ``radii``: the pairs (a particle of the ``centres`` mask, any other particle) closer than it,
    counted by scipy's dual-tree ``count_neighbors`` (no list of pairs: g(r) of the paper's sample took 20 M
    pairs, 1 GiB and ~10 s that way), wrapped as :func:`pairs_within` wraps."""
    y, size = _wrapped(x, float(np.max(radii)), box, periodic)
    return kdtree(y[centres], boxsize=size).count_neighbors(kdtree(y, boxsize=size), radii, cumulative=True)


def _wrapped(x: np.ndarray, r: float, box: np.ndarray, periodic) -> tuple[np.ndarray, np.ndarray]:
    """(points, box size) for a cKDTree searched to distance ``r``.  ``x`` lies in [0, box) along periodic
    directions.  cKDTree wraps every direction when given ``boxsize``; a non-periodic direction gets a box more
    than twice as long as the data plus r, so nothing wraps across it."""
    periodic = np.asarray(periodic, dtype=bool)
    size = np.where(periodic, box, 2 * (np.ptp(x, axis=0) + r) + 1.0)
    y = np.where(periodic, np.mod(x, size), x - x.min(axis=0))
    return np.where(y >= size, y - size, y), size  # (np.mod can return size itself for tiny negatives)


def separations(x: np.ndarray, pairs: np.ndarray, box: np.ndarray, periodic) -> np.ndarray:
    """Minimum-image vectors x[j] - x[i] for each pair (i, j)."""
    d = x[pairs[:, 1]] - x[pairs[:, 0]]
    for k in np.flatnonzero(np.asarray(periodic, dtype=bool)):
        d[:, k] -= box[k] * np.round(d[:, k] / box[k])
    return d
