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

The nonlinear quasi-static method (``compression.geometry = "nonlinear"``) has LAMMPS's own contacts instead, at
finite displacement, with friction and found as the spheres move: :class:`GranularContacts`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opalflow.bpm.bonds import find_bonds
from opalflow.bpm.stiffness import BondNetwork, cross
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


def effective_moduli(E_a, nu_a, E_b, nu_b):
    """Hertz-Mindlin's pair moduli (E*, G*) of the module docstring (MPa; scalars or arrays), G = E / (2 (1 + nu))."""
    e_star = 1.0 / ((1 - nu_a**2) / E_a + (1 - nu_b**2) / E_b)
    g_star = 1.0 / (2 * (2 - nu_a) * (1 + nu_a) / E_a + 2 * (2 - nu_b) * (1 + nu_b) / E_b)
    return e_star, g_star


def hertz_mindlin_springs(a: ContactProperties, b: ContactProperties, r_a: np.ndarray, r_b: np.ndarray,
                          reference_strain: float) -> tuple[np.ndarray, np.ndarray]:
    """(k_n, k_t) of the module docstring for pairs of radii r_a, r_b (nm) of materials a and b (pN/nm)."""
    e_star, g_star = effective_moduli(a.youngs_modulus_MPa, a.poisson_ratio, b.youngs_modulus_MPa, b.poisson_ratio)
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


#: the nonlinear contacts' friction follows Coulomb's cap exactly up to this fraction of it (GranularContacts)
STICK = 0.9


@dataclass
class GranularContacts:
    """Hertz-Mindlin contacts with Coulomb friction at finite displacement, for the nonlinear quasi-static method
    (:mod:`opalflow.bpm.nonlinear`): LAMMPS's ``pair_style granular`` with ``hertz/material`` and ``tangential
    mindlin`` (src/GRANULAR/gran_sub_mod_normal.cpp, gran_sub_mod_tangential.cpp, LAMMPS 22 Jul 2025) without its
    damping (a static state has no relative velocity), between spheres that overlap and that no intact bond joins
    (the deck's ``special_bonds lj 0``; a broken bond's pair then touches as any other):

    - normal: F_n = 4/3 E* sqrt(R* delta) delta along n = (x_i - x_j) / r, delta = R_i + R_j - r > 0 (Dosta et al.
      eq. 5);
    - tangential: k_t = 8 G* sqrt(R* delta) (eq. 8) on the history xi, the slip of i's contact point on j's since
      the pair touched, F_t = -k_t xi, at most mu F_n (Coulomb; where reached, xi = -F_t / k_t, LAMMPS's rescale),
      xi turned into each new tangent plane with its length kept, dropped when the pair parts; the cap is rounded
      above :data:`STICK` of it (|F_t| = mu F_n (s + (1 - s) tanh((x - s) / (1 - s))), x = k_t |xi| / (mu F_n),
      the same force below s, continuous in slope) so that Newton's tangent is continuous; a pair that comes to
      touch in a load step counts its slip from the step's start (LAMMPS: from the touch; the cap bounds the
      difference, mu F_n, which is zero at the touch);
    - torques (-(R - delta / 2) n) x F_t on i and on j (LAMMPS's dist_to_contact), no rolling or twisting
      resistance (the deck's contacts have none).

    E*, G* by :func:`effective_moduli`, mu the geometric mean of the two particles' (LAMMPS's mixing).
    A load step is one increment of the history from the last accepted equilibrium (:meth:`commit`): the slip
    increment (du_i - du_j) - (R_i dphi_i + R_j dphi_j) x n, its tangential part; so the forces are a function of
    the displacements and rotations z alone within a step, and Newton's tangent sees the friction's return map.
    The pairs a step considers (:meth:`find`) are those within ``reach`` of contact at its start; a pair that comes
    to overlap outside them is found after the solve, and the step solved again with it."""

    x0: np.ndarray
    radius: np.ndarray
    E: np.ndarray
    nu: np.ndarray
    mu: np.ndarray
    box: np.ndarray
    periodic: np.ndarray
    reach: float = 1.05

    def __post_init__(self) -> None:
        n = len(self.x0)
        self.z_c = np.zeros(6 * n)
        self.keys_c = np.zeros(0, np.int64)        # the committed contacts (pair keys i n + j, sorted) ...
        self.xi_c = np.zeros((0, 3))               # ... and their slip histories
        self.bonded = np.zeros(0, np.int64)        # keys of the pairs an intact bond joins (sorted)
        self.loose = np.zeros(n, bool)             # particles held still (lost from the supports): no contact
        self.pairs = np.zeros((0, 2), np.int64)    # the candidates of the step under way
        self.xi0 = np.zeros((0, 3))

    @classmethod
    def of(cls, positions, diameters, box, periodic, properties: list[ContactProperties], kinds) -> GranularContacts:
        """From a structure: ``properties[kinds[p]]`` is particle p's material's contact."""
        pick = (lambda f: np.array([getattr(properties[k], f) for k in kinds], float))
        return cls(np.asarray(positions, float), 0.5 * np.asarray(diameters, float), E=pick("youngs_modulus_MPa"),
                   nu=pick("poisson_ratio"), mu=pick("friction"), box=np.asarray(box, float),
                   periodic=np.asarray(periodic, bool))

    def set_bonded(self, i: np.ndarray, j: np.ndarray) -> None:
        """The pairs an intact bond joins (no contact acts between them)."""
        self.bonded = np.unique(np.minimum(i, j).astype(np.int64) * len(self.x0) + np.maximum(i, j))

    def _near(self, z: np.ndarray, factor: float) -> np.ndarray:
        """Pairs (i < j) no intact bond joins, neither particle loose, with centres within ``factor`` x (R_i + R_j)
        at z."""
        x = self._positions(z)
        for k in np.flatnonzero(self.periodic):
            x[:, k] = np.mod(x[:, k], self.box[k])
        pairs = find_bonds(x, 2.0 * self.radius, self.box, self.periodic, factor)
        keys = pairs[:, 0] * len(self.x0) + pairs[:, 1]
        return pairs[~np.isin(keys, self.bonded) & ~self.loose[pairs[:, 0]] & ~self.loose[pairs[:, 1]]]

    def _positions(self, z: np.ndarray) -> np.ndarray:
        return self.x0 + z.reshape(-1, 6)[:, :3]

    def find(self, z: np.ndarray) -> None:
        """The candidates of a step from z: the pairs within ``reach`` of contact, each with its history."""
        self.pairs = self._near(z, self.reach)
        keys = self.pairs[:, 0] * len(self.x0) + self.pairs[:, 1]
        at = np.minimum(np.searchsorted(self.keys_c, keys), max(len(self.keys_c) - 1, 0))
        hit = (self.keys_c[at] == keys) if len(self.keys_c) else np.zeros(len(keys), bool)
        self.xi0 = np.zeros((len(keys), 3))
        self.xi0[hit] = self.xi_c[at[hit]]

    def missed(self, z: np.ndarray) -> bool:
        """Whether a pair overlaps at z that is not among the step's candidates."""
        n = len(self.x0)
        over = self._near(z, 1.0)
        inside = np.isin(over[:, 0] * n + over[:, 1], self.pairs[:, 0] * n + self.pairs[:, 1])
        return not np.all(inside)

    def _state(self, z: np.ndarray):
        """Each candidate's overlap flag, normal, forces, slip history and lever arms at z (:meth:`_pair_state`)."""
        X = z.reshape(-1, 6)
        return self._pair_state(X[self.pairs[:, 0]], X[self.pairs[:, 1]])

    def _pair_state(self, Zi: np.ndarray, Zj: np.ndarray):
        """The candidates' overlap flag, normal n, F_n, F_t, slip history and the arms of i and j (the class
        docstring) for the displacements and rotations Zi, Zj (M, 6) of each pair's two particles.  Analytic in
        them (the lengths as square roots, the branches chosen on real parts), so that complex Zi, Zj give the
        derivatives (:meth:`tangent`)."""
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        m = len(i)
        C = self.z_c.reshape(-1, 6)
        ends = np.concatenate([self.x0[i] + Zi[:, :3], self.x0[j] + Zj[:, :3]])
        sep = separations(ends, np.column_stack([np.arange(m), np.arange(m, 2 * m)]), self.box, self.periodic)
        r = np.sqrt(np.einsum("ij,ij->i", sep, sep))
        n = -sep / r[:, None]
        Ri, Rj = self.radius[i], self.radius[j]
        delta = Ri + Rj - r
        on = delta.real > 0
        d = np.where(on, delta, 0.0)
        e_star, g_star = effective_moduli(self.E[i], self.nu[i], self.E[j], self.nu[j])
        a = np.sqrt(Ri * Rj / (Ri + Rj) * d)
        Fn = 4.0 / 3.0 * e_star * a * d
        # the history into the tangent plane, its length kept; plus the slip of this step
        xi = self.xi0 - np.einsum("ij,ij->i", self.xi0, n)[:, None] * n
        old, new = np.linalg.norm(self.xi0, axis=1), np.sqrt(np.einsum("ij,ij->i", xi, xi))
        xi = xi * np.divide(old, new, out=np.ones_like(new), where=new.real > 0)[:, None]
        du = (Zi[:, :3] - C[i, :3]) - (Zj[:, :3] - C[j, :3])
        dphi = Ri[:, None] * (Zi[:, 3:] - C[i, 3:]) + Rj[:, None] * (Zj[:, 3:] - C[j, 3:])
        slip = du - cross(dphi, n)
        xi = xi + slip - np.einsum("ij,ij->i", slip, n)[:, None] * n
        kt = 8.0 * g_star * a
        Ft = -kt[:, None] * xi
        limit = np.sqrt(self.mu[i] * self.mu[j]) * Fn
        size = np.sqrt(np.einsum("ij,ij->i", Ft, Ft))
        ratio = np.divide(size, limit, out=np.zeros_like(size), where=limit.real > 0)
        over = ratio.real > STICK
        cap = STICK + (1 - STICK) * np.tanh((ratio[over] - STICK) / (1 - STICK))
        Ft[over] *= (cap / ratio[over])[:, None]
        xi[over] = -Ft[over] / np.where(kt[over].real > 0, kt[over], 1.0)[:, None]
        Ft[~on], xi[~on] = 0.0, 0.0
        return on, n, Fn, Ft, xi, Ri - 0.5 * d, Rj - 0.5 * d

    def _pair_internal(self, Zi: np.ndarray, Zj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M, 6) each: minus the force and torque of each candidate's contact on its i and on its j."""
        on, n, Fn, Ft, _, arm_i, arm_j = self._pair_state(Zi, Zj)
        f = np.where(on[:, None], Fn[:, None] * n + Ft, 0.0)         # on i; -f on j
        nxF = cross(n, Ft)
        return np.hstack([-f, arm_i[:, None] * nxF]), np.hstack([f, arm_j[:, None] * nxF])

    def internal(self, z: np.ndarray) -> np.ndarray:
        """(N, 6): minus the contacts' force and torque on each particle at z (as the bonds' internal force)."""
        X = z.reshape(-1, 6)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        gi, gj = self._pair_internal(X[i], X[j])
        g = np.zeros((len(self.x0), 6))
        for k in range(6):
            g[:, k] = np.bincount(i, gi[:, k], len(g)) + np.bincount(j, gj[:, k], len(g))
        return g

    def tangent(self, z: np.ndarray):
        """d(internal)/dz at z (6N x 6N, sparse): each pair's 12 x 12 block by complex steps (Squire and Trapp,
        SIAM Rev. 40:110, 1998: f'(x) = Im f(x + i h) / h, exact to rounding for any small h).  The friction's
        rounded cap turns within 0.1 mu F_n / k_t of slip (mu E* delta / (60 G*): 0.02 of the overlap for silica),
        where a difference quotient of the forces is off by its curvature times its step."""
        import scipy.sparse as sp

        X = z.reshape(-1, 6)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        Zi, Zj = X[i].astype(complex), X[j].astype(complex)
        h = 1e-30
        rows_of = np.hstack([i[:, None] * 6 + np.arange(6), j[:, None] * 6 + np.arange(6)])     # (M, 12)
        rows, cols, vals = [], [], []
        for d in range(12):
            Ai, Aj = Zi.copy(), Zj.copy()
            (Ai if d < 6 else Aj)[:, d % 6] += 1j * h
            gi, gj = self._pair_internal(Ai, Aj)
            rows.append(rows_of)
            cols.append(np.repeat(((i if d < 6 else j) * 6 + d % 6)[:, None], 12, axis=1))
            vals.append(np.hstack([gi.imag, gj.imag]) / h)
        size = 6 * len(self.x0)
        return sp.csr_matrix((np.concatenate(vals).ravel(), (np.concatenate(rows).ravel(),
                                                             np.concatenate(cols).ravel())), shape=(size, size))

    def commit(self, z: np.ndarray) -> int:
        """Accept z: the touching candidates' histories become the next step's start; the number touching."""
        on, *_, xi, _, _ = self._state(z)
        keys = self.pairs[:, 0] * len(self.x0) + self.pairs[:, 1]
        order = np.argsort(keys[on])
        self.keys_c, self.xi_c = keys[on][order], xi[on][order]
        self.z_c = z.copy()
        return int(on.sum())
