"""Bonds: who is bonded (Dosta et al., section 2.1) and how a bond responds (the bond model).

Pairs closer than ``cutoff_factor`` x (d_i + d_j)/2 are bonded (1.75 d = 26.25 nm for
d = 15 nm), across periodic boundaries too.  A bond takes the coating material's
type when a coating particle takes part, else the matrix material's type (silica
bonds between silica and substrate, titania bonds wherever titania takes part).

Bond models (``bonds.model``, Roy and Hossain Fig. 10.8) are objects, one class and one line in
:data:`BOND_MODELS` each: the LAMMPS bond style's deck block and its coefficients.
"""
from __future__ import annotations

import numpy as np

from opalflow.materials import BondCoefficients
from opalflow.neighbors import pairs_within, separations


class BondModel:
    """How a bond responds: the deck block of its LAMMPS bond style and its ``bond_coeff`` values."""

    name = ""
    block = ""
    moments = True                 # carries bending and twisting moments (and so static stiffness)

    def coefficients(self, c: BondCoefficients) -> list[float]:
        raise NotImplementedError


class ParallelBond(BondModel):
    """PFC's parallel bond: force and moment over the bond's cross-section (``bpm/rotational``)."""

    name, block, moments = "parallel", "bonds", True

    def coefficients(self, c):
        return c.values()


class ContactBond(BondModel):
    """PFC's contact bond: a force at the contact point, no moment (``bpm/spring``)."""

    name, block, moments = "contact", "bonds_spring", False

    def coefficients(self, c):
        return c.spring_values()


#: ``bonds.model`` -> model
BOND_MODELS: dict[str, BondModel] = {"parallel": ParallelBond(), "contact": ContactBond()}


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
