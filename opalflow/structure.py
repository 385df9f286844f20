"""The Structure: what every generator returns and every deck is written from.

Arrays are numpy in LAMMPS ``units nano``: lengths in nm, densities in attogram/nm^3.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from opalflow.jit import njit
from opalflow.neighbors import separations


@dataclass
class Structure:
    """Bonded-particle structure in an orthogonal box.

    Attributes
    ----------
    positions : (N, 3) float64, nm, inside ``[lo, hi)`` of the box.
    diameters : (N,) float64, nm.
    types : (N,) int32, LAMMPS atom types starting at 1 (see ``type_names``).
    densities : (N,) float64, attogram/nm^3 (1 kg/m^3 = 1e-6 ag/nm^3, see units.py).
    box_lo, box_hi : (3,) float64, nm.
    periodic : (3,) bool, which directions are periodic.
    bonds : (M, 2) int64, 0-based particle indices, i < j, sorted.
    bond_types : (M,) int32, LAMMPS bond types starting at 1 (see ``bond_type_names``).
    molecules : (N,) int32, LAMMPS molecule IDs.
    type_names, bond_type_names : names of the types, index 0 = type 1.
    groups : named boolean masks over particles (e.g. ``substrate``).
    meta : free-form provenance and geometry (pore centres, heights ...).
    """

    positions: np.ndarray
    diameters: np.ndarray
    types: np.ndarray
    densities: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    periodic: np.ndarray
    bonds: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    bond_types: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    molecules: np.ndarray | None = None
    type_names: list[str] = field(default_factory=list)
    bond_type_names: list[str] = field(default_factory=list)
    groups: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float64)
        self.diameters = np.asarray(self.diameters, dtype=np.float64)
        self.types = np.asarray(self.types, dtype=np.int32)
        self.densities = np.asarray(self.densities, dtype=np.float64)
        self.box_lo = np.asarray(self.box_lo, dtype=np.float64)
        self.box_hi = np.asarray(self.box_hi, dtype=np.float64)
        self.periodic = np.asarray(self.periodic, dtype=bool)
        self.bonds = np.asarray(self.bonds, dtype=np.int64).reshape(-1, 2)
        self.bond_types = np.asarray(self.bond_types, dtype=np.int32)
        if self.molecules is None:
            self.molecules = np.ones(len(self.positions), dtype=np.int32)
        self.molecules = np.asarray(self.molecules, dtype=np.int32)

    @property
    def n_particles(self) -> int:
        return len(self.positions)

    @property
    def n_bonds(self) -> int:
        return len(self.bonds)

    @property
    def box_lengths(self) -> np.ndarray:
        return self.box_hi - self.box_lo

    def minimum_image(self, delta: np.ndarray) -> np.ndarray:
        """Apply the minimum-image convention to separation vectors (in place)."""
        L = self.box_lengths
        for k in np.flatnonzero(self.periodic):
            delta[:, k] -= L[k] * np.round(delta[:, k] / L[k])
        return delta

    def bond_vectors(self) -> np.ndarray:
        """Minimum-image vectors x[j] - x[i] of the bonds (i, j), nm (:func:`opalflow.neighbors.separations`)."""
        return separations(self.positions, self.bonds, self.box_lengths, self.periodic)

    def bond_lengths(self) -> np.ndarray:
        """Current (initial, for a fresh build) bond lengths in nm, minimum image."""
        d = self.bond_vectors()
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def image_flags(self) -> np.ndarray:
        """LAMMPS image flags (N, 3) that make every bond short when positions are unwrapped, where any can.

        Each bonded cluster is unwrapped along a spanning tree (breadth first from its first particle):
        a particle's image is its tree parent's plus the box crossings of the bond between them,
        summed from the root by pointer jumping (log2(depth) vectorised passes).  A cluster whose
        bonds close a loop around the periodic box along x or y (an infinite network, the usual
        opal and aerogel sample) cannot be made whole that way: some bond on that loop stays a box
        length long whatever the flags (LAMMPS manual, Errors_warnings "Inconsistent image flags":
        "the bond image flags *must* be inconsistent for the one bond that reaches back").  For such
        a cluster the flags along that direction stay 0, which puts the unavoidable long bonds on
        the box faces, the fewest a plane can cut (:meth:`wrapping_bonds` counts them).
        """
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import breadth_first_order, connected_components

        n = self.n_particles
        flags = np.zeros((n, 3), np.int64)
        if not self.n_bonds or not self.periodic.any():
            return flags
        i, j = self.bonds.T
        graph = coo_matrix((np.ones(self.n_bonds), (i, j)), shape=(n, n)).tocsr()
        graph = (graph + graph.T).tocsr()          # undirected once (an undirected search transposes at each call)
        n_comp, comp = connected_components(graph, directed=True, connection="weak")
        parent = np.arange(n)
        for root in np.unique(comp, return_index=True)[1]:
            order, pred = breadth_first_order(graph, root, directed=True)
            parent[order[1:]] = pred[order[1:]]
        L = self.box_lengths
        shift = np.zeros((n, 3), np.int64)
        for k in np.flatnonzero(self.periodic):    # crossings of the bond child -> parent
            shift[:, k] = np.round((self.positions[parent, k] - self.positions[:, k]) / L[k]).astype(np.int64)
        up = parent.copy()
        while np.any(up != up[up]):                # pointer jumping: shift sums the path to the root
            shift += shift[up]
            up = up[up]
        for k in np.flatnonzero(self.periodic):
            d = self.positions[j, k] + shift[j, k] * L[k] - self.positions[i, k] - shift[i, k] * L[k]
            wraps = np.zeros(n_comp, bool)
            wraps[comp[i[np.abs(d) > L[k] / 2]]] = True
            flags[:, k] = np.where(wraps[comp], 0, shift[:, k])
        return flags

    def wrapping_bonds(self, flags: np.ndarray | None = None) -> np.ndarray:
        """Per direction, how many bonds are longer than half the box when unwrapped with ``flags``
        (default :meth:`image_flags`): the bonds LAMMPS calls inconsistent."""
        flags = self.image_flags() if flags is None else flags
        i, j = self.bonds.T
        unwrapped = self.positions + flags * self.box_lengths
        d = np.abs(unwrapped[j] - unwrapped[i])
        return np.array([int(np.sum(d[:, k] > self.box_lengths[k] / 2)) if self.periodic[k] else 0
                         for k in range(3)])

    def particle_volumes(self) -> np.ndarray:
        """Sphere volumes pi d^3 / 6 in nm^3."""
        return np.pi / 6.0 * self.diameters**3

    def select(self, keep: np.ndarray) -> "Structure":
        """A new Structure with the particles where ``keep`` is True; bonds renumbered."""
        keep = np.asarray(keep, dtype=bool)
        new_index = np.full(self.n_particles, -1, dtype=np.int64)
        new_index[keep] = np.arange(int(keep.sum()))
        bonds, bond_types = self.bonds, self.bond_types
        if len(bonds):
            ok = keep[bonds[:, 0]] & keep[bonds[:, 1]]
            bonds, bond_types = new_index[bonds[ok]], bond_types[ok]
        return Structure(
            positions=self.positions[keep], diameters=self.diameters[keep],
            types=self.types[keep], densities=self.densities[keep],
            box_lo=self.box_lo.copy(), box_hi=self.box_hi.copy(), periodic=self.periodic.copy(),
            bonds=bonds, bond_types=bond_types, molecules=self.molecules[keep],
            type_names=list(self.type_names), bond_type_names=list(self.bond_type_names),
            groups={k: v[keep] for k, v in self.groups.items()},
            meta={k: v for k, v in self.meta.items() if k != "statistics"},    # (the whole's: not this part's)
        )

    def reordered(self, order: np.ndarray) -> "Structure":
        """The same structure with its particles in ``order`` (particle k of the new one is ``order[k]`` of this
        one): bonds renumbered, i < j and sorted again, their types with them."""
        order = np.asarray(order, np.int64)
        n = self.n_particles
        new_index = np.empty(n, np.int64)
        new_index[order] = np.arange(n)
        bonds, sort = _sorted_bonds(new_index[self.bonds], n)
        return Structure(
            positions=self.positions[order], diameters=self.diameters[order], types=self.types[order],
            densities=self.densities[order], box_lo=self.box_lo.copy(), box_hi=self.box_hi.copy(),
            periodic=self.periodic.copy(), bonds=bonds,
            bond_types=self.bond_types[sort], molecules=self.molecules[order], type_names=list(self.type_names),
            bond_type_names=list(self.bond_type_names), groups={k: v[order] for k, v in self.groups.items()},
            meta=dict(self.meta))

    def cell_order(self, cell_nm: float) -> np.ndarray:
        """The particles sorted by the cell of a grid of ``cell_nm`` that holds each (cells in z, y, x order, x the
        fastest; a cell's particles as they were): a particle's bonded neighbours lie in its cell or the next
        ones, so they lie near it in memory (what LAMMPS's ``atom_modify sort`` does to its atoms, for the same
        reason: :mod:`opalflow.bpm.scene`, ORDER_MIN_PARTICLES)."""
        cell = np.floor((self.positions - self.box_lo) / cell_nm).astype(np.int64)
        cell = np.clip(cell, 0, None)
        counts = cell.max(axis=0) + 1
        return np.argsort((cell[:, 2] * counts[1] + cell[:, 1]) * counts[0] + cell[:, 0], kind="stable")


@njit(cache=True, nogil=True)
def _sorted_bonds(b, n):
    """The bonds ``b`` (M, 2; particles 0 <= i < n) as (lo, hi) rows sorted by lo, then hi, ties as they were, and
    each row's bond in ``b``: numpy's ``np.argsort(lo * n + hi, kind="stable")`` of ``b.min(1)`` and ``b.max(1)``, by
    a counting sort on lo and an insertion sort of each lo's few bonds on hi.  At the paper's sample (17.5 M bonds)
    numpy's reductions and sort took 4.2 s of the build (py-spy); on its bonds and particles shuffled, 5.3 s
    against this kernel's 1.2 s."""
    m = len(b)
    start = np.zeros(n + 1, np.int64)
    for k in range(m):
        start[min(b[k, 0], b[k, 1]) + 1] += 1
    for p in range(n):
        start[p + 1] += start[p]
    fill = start[:n].copy()
    order = np.empty(m, np.int64)
    out = np.empty((m, 2), np.int64)
    for k in range(m):
        lo, hi = min(b[k, 0], b[k, 1]), max(b[k, 0], b[k, 1])
        q = fill[lo]
        order[q], out[q, 0], out[q, 1] = k, lo, hi
        fill[lo] += 1
    for p in range(n):
        for q in range(start[p] + 1, start[p + 1]):
            hq, oq, r = out[q, 1], order[q], q - 1
            while r >= start[p] and out[r, 1] > hq:
                out[r + 1, 1], order[r + 1] = out[r, 1], order[r]
                r -= 1
            out[r + 1, 1], order[r + 1] = hq, oq
    return out, order


#: positions are rounded to this many decimals (nm) so data files round-trip exactly
POSITION_DECIMALS = 6


def quantize(x: np.ndarray, box: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Round to POSITION_DECIMALS (k / 10^n is the double nearest the decimal text) and wrap."""
    scale = 10.0**POSITION_DECIMALS
    q = np.round(x * scale) / scale
    for k in np.flatnonzero(periodic):
        q[:, k] = np.where(q[:, k] >= box[k], q[:, k] - box[k], q[:, k])
        q[:, k] = np.where(q[:, k] < 0, q[:, k] + box[k], q[:, k])
        q[:, k] = np.round(q[:, k] * scale) / scale
    return q
