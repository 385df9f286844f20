"""Contacts in the quasi-static method (``contacts.quasistatic``): touching particles that no bond joins (never
bonded, or their bond broke) press on each other, as the Hertz-Mindlin contacts of the paper's model do (Dosta
et al. eqs. 5-10: "applied only for pairs of particles between which there is no solid bond").

The event algebra of :mod:`opalflow.bpm.quasistatic` needs the response positively homogeneous in the strain
(x(e) = e x(1)), so a contact here is linear and has no gap to close:

- the pairs are those touching in the built structure: centre distance below :data:`CONTACT_REACH` (d_i + d_j)
  / 2 (the gap, at most 0.5 % d, is taken as closed; pairs further apart never touch here);
- its normal spring is Hertz's secant at the overlap a pair reaches at ``contacts.reference_strain`` of its
  contact distance, k_n = 4/3 E* sqrt(R* delta) (eq. 5, F = 4/3 E* sqrt(R*) delta^1.5), and it acts in
  compression only (an active set, iterated inside each event until no contact opens or closes);
- its tangential spring is Mindlin's, k_t = 8 G* sqrt(R* delta) (eq. 8), on the slip at the contact point,
  with no slip limit (``"sticking"``: Coulomb friction with mu = infinity) or none at all (``"frictionless"``:
  mu = 0); a real mu lies between the two, which bracket what friction can do;
- no rolling or twisting resistance (the paper's contacts have none).

E*, G* and R* are Hertz-Mindlin's pair values, E* = 1 / ((1 - nu_i^2) / E_i + (1 - nu_j^2) / E_j),
G* = 1 / ((2 - nu_i) / G_i + (2 - nu_j) / G_j), R* = R_i R_j / (R_i + R_j), from each particle's material's
contact properties (data/materials.toml: the paper's particles have its bonds' E, 6.53 GPa for silica).
A contact element is a :class:`opalflow.bpm.stiffness.BondNetwork` bond with a_r = k_n, a_s = k_t (or 0) and
no bending or twisting stiffness, so every re-solve takes it as it takes a bond.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opalflow.bpm.bonds import find_bonds
from opalflow.bpm.stiffness import BondNetwork
from opalflow.materials import ContactProperties
from opalflow.neighbors import separations

#: pairs whose centres lie within this factor of their contact distance touch (module docstring)
CONTACT_REACH = 1.005
#: friction of the quasi-static contacts (``contacts.quasistatic``): the two bounds of Coulomb's mu
CONTACT_FRICTION = ("frictionless", "sticking")


@dataclass
class Contacts:
    """The touching pairs as contact elements (``net``, one bond each) and the bond that joins each pair (-1:
    none); a pair's contact acts only while its bond is broken or absent, and only in compression."""

    net: BondNetwork
    bond: np.ndarray

    def usable(self, alive: np.ndarray, loose: np.ndarray) -> np.ndarray:
        """The contacts that may act: no intact bond joins the pair, and neither particle is loose (held still:
        it would anchor its neighbours)."""
        free_pair = (self.bond < 0) | ~alive[np.maximum(self.bond, 0)]
        return free_pair & ~loose[self.net.i] & ~loose[self.net.j]

    def stretch(self, x: np.ndarray) -> np.ndarray:
        """n . (u_i - u_j) of each pair for x (N, 6): > 0 the pair separates, < 0 it presses."""
        return np.einsum("ij,ij->i", self.net.n, x[self.net.i, :3] - x[self.net.j, :3])


def hertz_mindlin_springs(a: ContactProperties, b: ContactProperties, r_a: np.ndarray, r_b: np.ndarray,
                          reference_strain: float) -> tuple[np.ndarray, np.ndarray]:
    """(k_n, k_t) of the module docstring for pairs of radii r_a, r_b (nm) of materials a and b (pN/nm)."""
    e_star = 1.0 / ((1 - a.poisson_ratio**2) / a.youngs_modulus_MPa + (1 - b.poisson_ratio**2) / b.youngs_modulus_MPa)
    g_a = a.youngs_modulus_MPa / (2 * (1 + a.poisson_ratio))
    g_b = b.youngs_modulus_MPa / (2 * (1 + b.poisson_ratio))
    g_star = 1.0 / ((2 - a.poisson_ratio) / g_a + (2 - b.poisson_ratio) / g_b)
    r_star = r_a * r_b / (r_a + r_b)
    root = np.sqrt(r_star * reference_strain * (r_a + r_b))
    return 4.0 / 3.0 * e_star * root, 8.0 * g_star * root


def contact_elements(positions: np.ndarray, diameters: np.ndarray, box: np.ndarray, periodic, bonds: np.ndarray,
                     properties: list[ContactProperties], kinds: np.ndarray, friction: str,
                     reference_strain: float) -> Contacts:
    """The contacts of a structure: its touching pairs (``CONTACT_REACH``), their springs by the materials
    ``properties[kinds[p]]`` of their particles, the tangential one kept with ``friction = "sticking"``."""
    pairs = find_bonds(positions, diameters, box, periodic, CONTACT_REACH)      # the touching pairs
    sep = separations(positions, pairs, box, periodic)
    L = np.sqrt(np.einsum("ij,ij->i", sep, sep))
    k_n, k_t = np.zeros(len(pairs)), np.zeros(len(pairs))
    for a in np.unique(kinds):
        for b in np.unique(kinds):
            sel = (kinds[pairs[:, 0]] == a) & (kinds[pairs[:, 1]] == b)
            if sel.any():
                k_n[sel], k_t[sel] = hertz_mindlin_springs(properties[a], properties[b], diameters[pairs[sel, 0]] / 2,
                                                           diameters[pairs[sel, 1]] / 2, reference_strain)
    if friction == "frictionless":
        k_t[:] = 0.0
    bond = np.full(len(pairs), -1, np.int64)          # each pair's bond: keys i n + j, sorted, searched
    if len(bonds):
        n = len(positions)
        keys = np.minimum(bonds[:, 0], bonds[:, 1]).astype(np.int64) * n + np.maximum(bonds[:, 0], bonds[:, 1])
        order = np.argsort(keys)
        wanted = pairs[:, 0] * n + pairs[:, 1]
        at = np.minimum(np.searchsorted(keys[order], wanted), len(order) - 1)
        hit = keys[order][at] == wanted
        bond[hit] = order[at[hit]]
    zero = np.zeros(len(pairs))
    net = BondNetwork(len(positions), pairs[:, 0].copy(), pairs[:, 1].copy(), -sep / L[:, None], L, k_n, k_t, zero,
                      zero.copy())
    return Contacts(net, bond)


def joined(a: BondNetwork, b: BondNetwork) -> BondNetwork:
    """One network of a's bonds followed by b's (a contact's index is len(a.L) + its own)."""
    return BondNetwork(a.n_particles, *(np.concatenate([getattr(a, k), getattr(b, k)])
                                        for k in ("i", "j", "n", "L", "a_r", "a_s", "bend", "twist")))


def describe(contacts: Contacts, friction: str, reference_strain: float) -> str:
    """One line for the report: how many contacts, their springs against the bonds'."""
    k = contacts.net.a_r
    return (f"{len(k)} touching pairs (centres within {CONTACT_REACH:g} of contact; {int(np.sum(contacts.bond >= 0))} "
            f"of them bonded: their contact acts once the bond breaks), linear Hertz-Mindlin springs at "
            f"{100 * reference_strain:g} % overlap (k_n {np.mean(k) if len(k) else math.nan:.4g} pN/nm), "
            f"{friction}, in compression only")
