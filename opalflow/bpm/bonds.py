"""Bonds: who is bonded (Dosta et al., section 2.1) and how a bond responds (the bond model).

Pairs closer than ``cutoff_factor`` x (d_i + d_j)/2 are bonded (1.75 d = 26.25 nm for
d = 15 nm), across periodic boundaries too, and, with ``min_length_factor`` f > 0, only those at
least f (d_i + d_j)/2 apart: MUSEN's bond generator (Modules/BondsGenerator) bonds pairs whose
surface gap lies between a minimum and a maximum distance, and its default minimum, 0, is f = 1
(overlapping pairs unbonded; they touch by contacts only).  A bond takes the coating material's
type when a coating particle takes part, else the matrix material's type (silica
bonds between silica and substrate, titania bonds wherever titania takes part).

Bond models (``bonds.model``, Roy and Hossain Fig. 10.8) are objects, one class and one line in
:data:`BOND_MODELS` each: the LAMMPS bond style's deck block and its coefficients.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from opalflow.materials import BondCoefficients
from opalflow.neighbors import neighbour_counts, pairs_within, separations


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
               cutoff_factor: float, min_length_factor: float = 0.0) -> np.ndarray:
    """(M, 2) sorted particle index pairs to bond (module docstring)."""
    pairs = pairs_within(positions, cutoff_factor * float(diameters.max()), box, periodic)
    if diameters.min() != diameters.max() or min_length_factor > 0:
        d = separations(positions, pairs, box, periodic)
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        contact = 0.5 * (diameters[pairs[:, 0]] + diameters[pairs[:, 1]])
        pairs = pairs[(r < cutoff_factor * contact) & (r >= min_length_factor * contact)]
    return pairs


#: a bond shorter than this x (d_i + d_j) / 2 counts as near contact in :func:`network_statistics`
NEAR_CONTACT = 1.005
#: g(r) is counted in shells of +- this fraction of r
SHELL = 0.025


@dataclass
class NetworkStatistics:
    """The bond network's numbers of :func:`network_statistics` (``near_contact_bond_share`` None: no bonds)."""

    bonds_per_particle: float
    near_contact_bond_share: float | None
    g_at_d: float
    g_at_sqrt3_d: float


def network_statistics(positions: np.ndarray, diameters: np.ndarray, box: np.ndarray, periodic,
                       bonds: np.ndarray, solid_fraction: float) -> NetworkStatistics:
    """What the bond network's strength is sensitive to, for the build report (Dosta et al. section 2.1:
    ~10.5 bonds a particle at 1.75 d):

    - ``bonds_per_particle``: M / N;
    - ``near_contact_bond_share``: the share of bonds shorter than :data:`NEAR_CONTACT` (d_i + d_j) / 2 (the
      pairs MUSEN's default bonding leaves unbonded where they overlap);
    - ``g_at_d`` and ``g_at_sqrt3_d``: the pair correlation g(r) at the contact peak r = d and at the second
      shell r = sqrt(3) d (where the 1.75 d cutoff lies, so the bond count follows its height), counted in
      shells of +-:data:`SHELL` r around the particles at least 1.8 d from an open face, against the number
      density of the packing, phi / V_p (a particle next to a pore has fewer neighbours: compare g between
      structures of the same pore geometry).
    """
    n = len(positions)
    d = float(np.mean(diameters))
    near = None
    if len(bonds):
        sep = separations(positions, bonds, box, periodic)
        r0 = np.sqrt(np.einsum("ij,ij->i", sep, sep))
        contact = 0.5 * (diameters[bonds[:, 0]] + diameters[bonds[:, 1]])
        near = float(np.mean(r0 < NEAR_CONTACT * contact))
    reach = 1.8 * d
    periodic = np.asarray(periodic, bool)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    inner = np.all(periodic | ((positions >= lo + reach) & (positions <= hi - reach)), axis=1)
    density = solid_fraction / (np.pi / 6 * np.mean(diameters**3))
    radii = np.array([at * f for at in (d, np.sqrt(3) * d) for f in (1 - SHELL, 1 + SHELL)])
    within = neighbour_counts(positions, inner, radii, box, periodic)
    g = []
    for k, at in enumerate((d, np.sqrt(3) * d)):
        ideal = inner.sum() * density * 4 / 3 * np.pi * at**3 * ((1 + SHELL) ** 3 - (1 - SHELL) ** 3)
        g.append(int(within[2 * k + 1] - within[2 * k]) / ideal if ideal > 0 else float("nan"))
    return NetworkStatistics(len(bonds) / max(n, 1), near, *g)


def bond_types_by_material(pairs: np.ndarray, coated: np.ndarray) -> np.ndarray:
    """Bond type 1 (matrix material) or 2 (coating material takes part)."""
    return np.where(coated[pairs[:, 0]] | coated[pairs[:, 1]], 2, 1).astype(np.int32)


def describe_network(stats: NetworkStatistics) -> str:
    """:func:`network_statistics` in one line."""
    return (f"{stats.bonds_per_particle:.2f} bonds a particle, "
            f"{100 * (stats.near_contact_bond_share or 0.0):.1f} % of them shorter than {NEAR_CONTACT:g} d, "
            f"g(d) {stats.g_at_d:.2f}, g(sqrt(3) d) {stats.g_at_sqrt3_d:.2f}")
