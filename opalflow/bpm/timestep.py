"""Stable time step of a bonded-particle model from its stiffest mode.

Velocity Verlet is stable for dt < 2 / omega_max (omega_max: the highest natural frequency of the
linearised system M^-1 K); with damping C, for dt <= 2 (sqrt(1 + zeta^2) - zeta) / omega, zeta =
c / (2 omega) (a damped oscillator under central differences; Belytschko, Liu & Moran, Nonlinear Finite
Elements, eq. 6.3.33).  Two ways to omega_max and c:

- **spectral** (the default up to SPECTRAL_MAX_BONDS bonds): the largest eigenvalues of M^-1 K and
  M^-1 C on the mobile particles by Lanczos (scipy ``eigsh``), with K and C the bond network linearised
  from LAMMPS's BondBPMRotational (:mod:`opalflow.bpm.stiffness`), 6 dofs per particle.  Contacts, absent
  at the reference state, are added as a diagonal bound of their stiffness (see below), so omega_max is
  still an upper bound for a densified sample.  The largest omega and the largest c are combined as if one
  mode had both (the safe side when the two differ).  On the stability matrix this is 0.52-0.93 of the
  limit found by bisection.
- **gershgorin**: omega_max^2 bounded per particle by Gershgorin's theorem on the mass-normalised
  stiffness matrix, using for each bond its axial (kr / L0), shear (ks / L0), bending (kb) and twisting
  (kt) stiffness and the shear force's lever arm R on the rotations; c per particle from the diagonal of
  M^-1 C, mostly from the sliding damper acting on the rotations through its lever arm.  Cheap and never
  below the true omega_max, but 0.36-0.67 of the bisected limit; used for larger networks.

Contacts in both: the Hertz tangent stiffness 2 E* sqrt(R* delta) at an overlap of DELTA_CONTACT x d
(eq. 5) for 12 neighbours, counted twice (a graph Laplacian is at most twice its diagonal), and the
plate as a particle of infinite mass.  Each mode is also reported alone ("damping": 2 / c).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opalflow.bpm.loading import CONTACT_LAWS
from opalflow.materials import BondCoefficients, ContactProperties
from opalflow.structure import Structure

#: overlap (fraction of the diameter) at which contact stiffness is evaluated
DELTA_CONTACT = 0.02
#: networks up to this many bonds get the spectral limit (Lanczos, ~1 s per 20 000 bonds here); larger
#: ones the Gershgorin bound, which is cheap and safe but 0.6 of the limit
SPECTRAL_MAX_BONDS = 2_000_000


@dataclass
class TimestepEstimate:
    """Critical time steps (ns): per mode and for all modes together (``limit_ns``)."""

    by_mode_ns: dict[str, float]
    limit_ns: float
    stiffest: str
    method: str = "spectral"

    def as_seconds(self) -> dict:
        return {"limit": self.limit_ns * 1e-9, "stiffest_mode": self.stiffest, "method": self.method,
                **{k: v * 1e-9 for k, v in self.by_mode_ns.items()}}


def _dt(omega2: np.ndarray) -> float:
    """Verlet limit of an undamped oscillator: omega dt <= 2."""
    w2 = float(np.max(omega2, initial=0.0))
    return 2.0 / math.sqrt(w2) if w2 > 0 else math.inf


def estimate_timestep(s: Structure, coeffs: list[BondCoefficients],
                      contacts: dict[int, ContactProperties], plate_E: dict[int, float],
                      plate_props: dict[int, ContactProperties],
                      L0: np.ndarray | None = None, spectral: bool = True) -> TimestepEstimate:
    """Critical time step of ``s`` with bond types ``coeffs`` (1-based types of s.bond_types); the
    Gershgorin bound alone with ``spectral`` False (a deck that will not be run).

    ``contacts`` maps atom type -> contact properties (empty: no particle contacts);
    ``plate_E`` and ``plate_props`` give the plate contact per atom type.
    """
    n = s.n_particles
    m = s.densities * np.pi / 6 * s.diameters**3
    R = s.diameters / 2
    inertia = 0.4 * m * R**2
    i, j = s.bonds[:, 0], s.bonds[:, 1]
    L0 = s.bond_lengths() if L0 is None else L0
    t = s.bond_types - 1
    kr = np.array([c.kr for c in coeffs])[t] / L0
    ks = np.array([c.ks for c in coeffs])[t] / L0
    kb = np.array([c.kb for c in coeffs])[t]
    kt = np.array([c.kt for c in coeffs])[t]

    def both(a_i: np.ndarray, a_j: np.ndarray) -> np.ndarray:
        out = np.bincount(i, a_i, n)
        out += np.bincount(j, a_j, n)
        return out

    mm = np.sqrt(m[i] * m[j])
    ii = np.sqrt(inertia[i] * inertia[j])
    modes = {
        "axial": both(kr / m[i] + kr / mm, kr / m[j] + kr / mm),
        "shear": both(ks / m[i] + ks / mm, ks / m[j] + ks / mm),
        "bending": both(kb / inertia[i] + kb / ii, kb / inertia[j] + kb / ii),
        "twisting": both(kt / inertia[i] + kt / ii, kt / inertia[j] + kt / ii),
    }
    # all modes together: translational and rotational rows with the shear coupling terms
    k_tr = np.maximum(kr, ks)
    k_rot_i = np.maximum(kb, kt) + ks * R[i] ** 2
    k_rot_j = np.maximum(kb, kt) + ks * R[j] ** 2
    tr = both(k_tr / m[i] + k_tr / mm + ks * R[i] / np.sqrt(m[i] * inertia[i])
              + ks * R[j] / np.sqrt(m[i] * inertia[j]),
              k_tr / m[j] + k_tr / mm + ks * R[j] / np.sqrt(m[j] * inertia[j])
              + ks * R[i] / np.sqrt(m[j] * inertia[i]))
    rot = both(k_rot_i / inertia[i] + (np.maximum(kb, kt) + ks * R[i] * R[j]) / ii
               + ks * R[i] / np.sqrt(inertia[i] * m[i]) + ks * R[i] / np.sqrt(inertia[i] * m[j]),
               k_rot_j / inertia[j] + (np.maximum(kb, kt) + ks * R[i] * R[j]) / ii
               + ks * R[j] / np.sqrt(inertia[j] * m[j]) + ks * R[j] / np.sqrt(inertia[j] * m[i]))
    total = np.maximum(tr, rot)

    contact = _contact_omega2(s, contacts, plate_E, plate_props, m)
    modes["contact"] = contact
    total = total + contact
    rate = _damping_rates(coeffs, t, L0, both, m[i], m[j], inertia[i], inertia[j])
    by_mode = {k: _dt(v) for k, v in modes.items()}
    by_mode["damping"] = 2.0 / float(np.max(rate)) if np.max(rate, initial=0) > 0 else math.inf
    # all together, per particle: a damped oscillator with omega^2 = total and rate c,
    # stable for dt <= 2 (sqrt(1 + zeta^2) - zeta) / omega with zeta = c / (2 omega)
    omega = np.sqrt(np.maximum(total, 1e-300))
    zeta = rate / (2 * omega)
    bound = float(np.min(2 * (np.sqrt(1 + zeta**2) - zeta) / omega))
    stiffest = min(by_mode, key=by_mode.get)
    by_mode["gershgorin"] = bound
    if spectral and s.n_bonds <= SPECTRAL_MAX_BONDS:
        by_mode["spectral"] = _spectral_limit(s, coeffs, L0, contact * m)
        return TimestepEstimate(by_mode, by_mode["spectral"], stiffest, "spectral")
    return TimestepEstimate(by_mode, bound, stiffest, "gershgorin")


def _contact_omega2(s: Structure, contacts: dict[int, ContactProperties], plate_E: dict[int, float],
                    plate_props: dict[int, ContactProperties], m: np.ndarray) -> np.ndarray:
    """Contact stiffness over mass per particle: a particle touching ~12 neighbours (dense packing) and the
    plate; Hertz stiffness at an overlap of DELTA_CONTACT d, linear stiffness as it is (the plate's: one ball
    on a rigid wall, 2 K)."""
    contact = np.zeros(s.n_particles)
    R = s.diameters / 2
    for typ, cp in contacts.items():
        sel = s.types == typ
        k = CONTACT_LAWS[cp.model].stiffness(cp, R[sel] / 2, DELTA_CONTACT * s.diameters[sel])
        contact[sel] = 12 * 2 * k / m[sel]
    for typ, E in plate_E.items():
        sel = s.types == typ
        cp = plate_props[typ]
        k = CONTACT_LAWS[cp.model].stiffness(cp, R[sel], DELTA_CONTACT * s.diameters[sel], E=E, wall=True)
        contact[sel] += k / m[sel]
    return contact


def _damping_rates(coeffs: list[BondCoefficients], t: np.ndarray, L0: np.ndarray, both, m_i, m_j, inertia_i,
                   inertia_j) -> np.ndarray:
    """Damping rates (1/ns): the diagonal of M^-1 C per particle (normal and sliding dampers on the translations;
    rolling, twisting and the sliding damper's lever arm on the rotations - LAMMPS applies it through
    0.5 (w1 + w2) x r, so gamma_s L0^2 / 4); ``both`` sums a per-bond term onto its two particles."""
    gn = np.array([c.gn for c in coeffs])[t]
    gs = np.array([c.gs for c in coeffs])[t]
    c_rot = 0.5 * np.array([c.gr for c in coeffs])[t] * L0 + 0.5 * np.array([c.gt for c in coeffs])[t] \
        + gs * L0**2 / 4
    g_tr = gn + gs
    return np.maximum(both(g_tr / m_i, g_tr / m_j), both(c_rot / inertia_i, c_rot / inertia_j))


#: the spectral limit's products by the assembled K and C (scipy) below this many bonds, by the compiled bond
#: operator (:meth:`opalflow.bpm.stiffness.BondNetwork.matvec`) from it: numba's import and first load (0.5 s and
#: ~110 MiB, :mod:`opalflow.jit`) cost a small run more than its products save (the quickstart's 19 891 bonds)
KERNEL_MIN_BONDS = 50_000


def _product(net):
    """x -> the network's matrix times x: assembled below :data:`KERNEL_MIN_BONDS` bonds, else the bond operator."""
    if len(net.L) >= KERNEL_MIN_BONDS:
        return net.matvec
    from opalflow.bpm.static import assemble

    return assemble(net).dot


def _largest_eigenvalue(matvec, n: int) -> float:
    from scipy.sparse.linalg import LinearOperator, eigsh

    op = LinearOperator((n, n), matvec=matvec, dtype=float)
    return float(eigsh(op, k=1, which="LA", tol=1e-6, return_eigenvectors=False, v0=np.ones(n))[0])


def _spectral_limit(s: Structure, coeffs: list[BondCoefficients], L0: np.ndarray, contact_k: np.ndarray) -> float:
    """Verlet limit 2 (sqrt(1 + zeta^2) - zeta) / omega_max from the largest eigenvalues of M^-1 (K + D_c)
    and M^-1 C on the mobile particles (Lanczos; K, C: the linearised bonds, D_c: the contact bound)."""
    from opalflow.bpm.stiffness import damping_network, mass_diagonal, stiffness_network

    fixed = s.groups.get("substrate", np.zeros(s.n_particles, bool))
    free = np.repeat(~fixed, 6)
    w = np.where(free, 1.0 / np.sqrt(mass_diagonal(s)), 0.0)
    extra = np.zeros((s.n_particles, 6))
    extra[:, :3] = contact_k[:, None]
    extra = extra.ravel()
    K, C = _product(stiffness_network(s, coeffs, L0)), _product(damping_network(s, coeffs, L0))
    n = 6 * s.n_particles
    w2 = _largest_eigenvalue(lambda x: w * (K(w * x) + extra * w * x), n)
    damped = any(c.gn or c.gs or c.gr or c.gt for c in coeffs)
    c = _largest_eigenvalue(lambda x: w * C(w * x), n) if damped else 0.0
    omega = np.sqrt(w2)
    zeta = c / (2 * omega)
    return float(2 * (np.sqrt(1 + zeta**2) - zeta) / omega)
