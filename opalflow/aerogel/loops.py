"""Loops in the aggregate's network: the models that close them, and how many there are.

Off-lattice DLCA bonded only where clusters collided is a tree (every merger adds one contact): mean
coordination 2.00 and a few loops per 10 000 spheres, so every load path is a chain of cantilevers
(Ma, Prevost and Scherer, Int. J. Solids Struct. 39, 4605, 2002: "loop structure is lacking in the
model gels").  ``aggregate.loops`` chooses how loops are closed:

- ``"none"``: the tree as aggregated (bonds at contacts, ``bonds.cutoff_factor``).
- ``"deflection"``: the dangling-bond deflection of Ma, Jullien and Scherer (Phys. Rev. E 65, 041403,
  2002): a sphere held by a single bond is rotated about the centre of its neighbour, at fixed contact,
  until it touches a second sphere, and bonds to it.  Here the rotation is the smallest one that makes
  a contact (in the plane of the sphere, its neighbour and the sphere it reaches; no other sphere can be
  met on the way, since meeting it would take a smaller rotation), after the growth rather than during
  it (a cluster's shape is frozen once it forms, so the spheres a dangling sphere can reach are the same,
  except those of clusters that arrive later: deflecting at the end gives them a chance too).  Dangling
  spheres are taken in index order with the positions as they stand; one that no rotation can bring to a
  second contact (nothing within reach) stays dangling.
- ``"restructuring"``: the same rotation at every merger, for whole clusters, during the growth: when two
  clusters stick, the smaller turns about the centre of the larger's contact sphere (about a random axis
  perpendicular to the contact) until a second pair of spheres touches (Meakin and Jullien, J. Chem. Phys.
  89, 246, 1988; ``opalflow.aerogel.aggregation._restructure``).  A merger then closes a loop at the scale
  of the clusters it joins, not only around one sphere; a single sphere joining is deflected as above.
- ``"necks"``: bonds between near-contacts: every pair whose surface gap is below ``aggregate.neck_gap``
  times the contact distance r_i + r_j gets a bond (a silica neck bridging the gap; Ma, Roberts et al.,
  J. Non-Cryst. Solids 277, 127, 2000 bond every neighbour pair of their on-lattice gels).  The spheres
  do not move; within a cluster the gaps are frozen at its formation, so these are the near-contacts
  formed during growth.

Counting (:func:`loop_statistics`): the cycle rank of the bond graph, bonds - spheres + connected pieces
(the number of independent loops; bonds through the periodic boundaries close loops too).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from opalflow.aerogel.aggregation import Aggregate, _cell, _insert, _min_image, _neighbour_cells, _set_position
from opalflow.bpm.bonds import find_bonds
from opalflow.structure import quantize
#: a deflected sphere stops this fraction of the contact distance short of touching (never an overlap)
CLEARANCE = 1e-9


def bond_cutoff(loops: str, cutoff_factor: float, neck_gap: float) -> float:
    """Centre distance, as a multiple of r_i + r_j, within which two spheres are bonded."""
    return cutoff_factor + neck_gap if loops == "necks" else cutoff_factor


def network_bonds(agg: Aggregate, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """The aggregate's positions as the structure stores them (quantized) and its bonds at ``cutoff``."""
    box = np.full(3, agg.box)
    periodic = np.ones(3, bool)
    x = quantize(agg.positions, box, periodic)
    return x, find_bonds(x, agg.diameters, box, periodic, cutoff)


@njit(cache=True)
def _deflect(pos, r, box, nc, head, nxt, prv, cell_of, leaves, anchors, partner):
    """Rotate each leaf about its anchor to its first contact (see the module docstring); partner[k] = the
    sphere leaf k reached (-1: none within reach, -2: it already touches a second sphere)."""
    n0 = np.empty(3)
    e = np.empty(3)
    best_e = np.empty(3)
    for m in range(len(leaves)):
        i = leaves[m]
        j = anchors[m]
        rho = 0.0
        for k in range(3):
            n0[k] = _min_image(pos[i, k] - pos[j, k], box)
            rho += n0[k] * n0[k]
        rho = math.sqrt(rho)
        for k in range(3):
            n0[k] /= rho
        best = math.inf
        best_k = -1
        best_th = 0.0
        for cc in _neighbour_cells(cell_of[j], nc):
            q = head[cc]
            while q >= 0:
                if q != i and q != j:
                    dd = 0.0
                    for k in range(3):
                        e[k] = _min_image(pos[q, k] - pos[j, k], box)
                        dd += e[k] * e[k]
                    dd = math.sqrt(dd)
                    s = (r[i] + r[q]) * (1.0 + CLEARANCE)
                    if dd < rho + s and dd > 1e-12:
                        c_th = min(1.0, max(-1.0, (rho * rho + dd * dd - s * s) / (2.0 * rho * dd)))
                        c_phi = 0.0
                        for k in range(3):
                            c_phi += n0[k] * e[k] / dd
                        delta = math.acos(min(1.0, max(-1.0, c_phi))) - math.acos(c_th)
                        if delta < best:
                            best = delta
                            best_k = q
                            best_th = math.acos(c_th)
                            for k in range(3):
                                best_e[k] = e[k] / dd
                q = nxt[q]
        if best_k < 0:
            partner[m] = -1
            continue
        if best <= 1e-9:           # already touching (a sphere deflected earlier onto this one)
            partner[m] = -2
            continue
        # the new direction: at angle th from e, in the plane of n0 and e, on n0's side
        c = 0.0
        for k in range(3):
            c += n0[k] * best_e[k]
        w = np.empty(3)
        wn = 0.0
        for k in range(3):
            w[k] = n0[k] - c * best_e[k]
            wn += w[k] * w[k]
        wn = math.sqrt(wn)
        if wn < 1e-12:           # n0 along e: any perpendicular (cannot happen without an overlap)
            w[0], w[1], w[2] = -best_e[1], best_e[0], 0.0
            wn = math.sqrt(w[0] * w[0] + w[1] * w[1])
        x = np.empty(3)
        for k in range(3):
            x[k] = pos[j, k] + rho * (math.cos(best_th) * best_e[k] + math.sin(best_th) * w[k] / wn)
        _set_position(i, x, pos, box, nc, head, nxt, prv, cell_of)
        partner[m] = best_k


def deflect_dangling(agg: Aggregate, cutoff_factor: float) -> tuple[Aggregate, dict]:
    """The aggregate with its dangling spheres deflected to a second contact (the ``"deflection"`` model),
    and counts: dangling spheres before, deflected, left dangling."""
    x, bonds = network_bonds(agg, cutoff_factor)
    n = len(x)
    z = np.bincount(bonds.ravel(), minlength=n)
    leaves = np.flatnonzero(z == 1)
    other = {**dict(zip(bonds[:, 0], bonds[:, 1])), **dict(zip(bonds[:, 1], bonds[:, 0]))}
    anchors = np.array([other[i] for i in leaves], np.int64)
    r = 0.5 * agg.diameters
    nc = max(3, int(agg.box // (2.0 * float(agg.diameters.max()))))
    head = np.full(nc**3, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    prv = np.full(n, -1, np.int64)
    cell_of = np.zeros(n, np.int64)
    pos = agg.positions.copy()          # as aggregated (the bonds above are the structure's, on quantized ones)
    for i in range(n):
        _insert(i, _cell(pos[i], agg.box, nc), head, nxt, prv, cell_of)
    partner = np.full(len(leaves), -1, np.int64)
    _deflect(pos, r, agg.box, nc, head, nxt, prv, cell_of, leaves.astype(np.int64), anchors, partner)
    counts = {"dangling_before": int(len(leaves)), "deflected": int(np.sum(partner >= 0)),
              "touched_by_another": int(np.sum(partner == -2)), "left_dangling": int(np.sum(partner == -1))}
    return replace(agg, positions=pos), counts


@dataclass
class Loops:
    """Coordination and loops of a bond graph: mean coordination, the fraction of dangling spheres (one bond), the
    cycle rank ``loops`` (bonds - spheres + pieces), it per 10 000 spheres, and the connected ``pieces``."""

    mean_coordination: float
    dangling_fraction: float
    loops: int
    loops_per_10k: float
    pieces: int


def loop_statistics(n: int, bonds: np.ndarray) -> Loops:
    """The :class:`Loops` of the graph of ``n`` spheres and ``bonds``."""
    z = np.bincount(bonds.ravel(), minlength=n)
    pieces = connected_components(coo_matrix((np.ones(len(bonds)), (bonds[:, 0], bonds[:, 1])), shape=(n, n)),
                                  directed=False)[0]
    loops = int(len(bonds) - n + pieces)
    return Loops(float(z.mean()), float(np.mean(z == 1)), loops, 1e4 * loops / max(n, 1), int(pieces))


def winding_rank(x: np.ndarray, bonds: np.ndarray, box: float) -> int:
    """In how many independent directions the bond graph wraps around the periodic cube (0-3): the rank of
    the box-vector windings of its loops.  Each sphere of a piece gets an unwrapped position along a
    breadth-first tree of minimum-image bond vectors; a bond outside the tree closes a loop whose winding is
    (its unwrapped ends' difference less its own vector) / L.  A network needs 3 for a stiffness tensor as a
    periodic solid: with fewer it is a finite piece interleaved with its images, free to rotate and
    stretch."""
    n = len(x)
    if not len(bonds):
        return 0
    A = coo_matrix((np.ones(len(bonds)), (bonds[:, 0], bonds[:, 1])), shape=(n, n)).tocsr()
    A = A + A.T
    u = np.full((n, 3), np.nan)
    tree = np.zeros(n, np.int64) - 1
    for root in range(n):
        if not np.isnan(u[root, 0]):
            continue
        order, pred = breadth_first_order(A, root, directed=False)
        u[root] = x[root]
        for v in order[1:]:
            d = x[v] - x[pred[v]]
            u[v] = u[pred[v]] + d - box * np.round(d / box)
            tree[v] = pred[v]
    i, j = bonds[:, 0], bonds[:, 1]
    in_tree = (tree[j] == i) | (tree[i] == j)
    d = x[j[~in_tree]] - x[i[~in_tree]]
    d -= box * np.round(d / box)
    w = np.round((u[i[~in_tree]] + d - u[j[~in_tree]]) / box)
    w = w[np.any(w != 0, axis=1)]
    return int(np.linalg.matrix_rank(w)) if len(w) else 0
