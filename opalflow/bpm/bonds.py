"""Bonds between all particle pairs closer than a cutoff (Dosta et al., section 2.1).

Pairs closer than ``cutoff_factor`` x (d_i + d_j)/2 are bonded (1.75 d = 26.25 nm for
d = 15 nm), across periodic boundaries too.  A bond takes the coating material's
type when a coating particle takes part, else the matrix material's type (silica
bonds between silica and substrate, titania bonds wherever titania takes part).
"""
from __future__ import annotations

import numpy as np

from opalflow.neighbors import pairs_within, separations


def find_bonds(positions: np.ndarray, diameters: np.ndarray, box: np.ndarray, periodic,
               cutoff_factor: float) -> np.ndarray:
    """(M, 2) sorted particle index pairs to bond."""
    pairs = pairs_within(positions, cutoff_factor * float(diameters.max()), box, periodic)
    if diameters.min() != diameters.max():
        d = separations(positions, pairs, box, periodic)
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        pairs = pairs[r < cutoff_factor * 0.5 * (diameters[pairs[:, 0]] + diameters[pairs[:, 1]])]
    return pairs


def bond_types_by_material(pairs: np.ndarray, coated: np.ndarray) -> np.ndarray:
    """Bond type 1 (matrix material) or 2 (coating material takes part)."""
    return np.where(coated[pairs[:, 0]] | coated[pairs[:, 1]], 2, 1).astype(np.int32)
