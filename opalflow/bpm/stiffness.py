"""The linearised bond network: stiffness and damping of ``bond_style bpm/rotational`` at the reference
state, 6 degrees of freedom per particle (displacement u and small rotation theta).

Derived from LAMMPS's own BondBPMRotational (src/BPM/bond_bpm_rotational.cpp, 22 Jul 2025):
``elastic_forces`` and ``damping_forces`` expanded to first order about the reference state (bond
vector R = L n with n pointing from particle j to particle i, i the lower atom id; quaternions at
rest).  With du = u_i - u_j, P = I - n n^T and, for ``normalize yes``, a_r = kr / L, a_s = ks / L:

- ``Fr = Kr (r - r0)`` along rb / r                           -> a_r n n^T du
- ``Fs = Ks r gamma s`` (rb = bond vector in j's frame)        -> a_s (P du + L n x theta_j)
- ``Fsp = -Ks r theta / 2 (cos phi, sin phi, 0)`` (rotated by mq) -> a_s L / 2 n x (theta_i - theta_j)
- ``Ts = Ks r^2 gamma t / 2``                                   -> a_s L / 2 n x (P du + L n x theta_j)
- ``Tsp = Ks r^2 theta / 4 (sin phi, -cos phi, 0)``             -> -a_s L^2 / 4 P (theta_i - theta_j)
- ``Tb = Kb theta (-sin phi, cos phi, 0)``, ``Tt = Kt psi z``  -> B (theta_i - theta_j),
  B = kb P + kt n n^T

so the bond force F (``force1on2``) and the shear torque Ts are

    F  = a_r n n^T du + a_s P du + a_s L / 2 n x (theta_i + theta_j)
    Ts = a_s L / 2 n x du - a_s L^2 / 4 P (theta_i + theta_j)

and ``compute`` applies f_i -= F, f_j += F, tau_i += Ts - B dtheta, tau_j += Ts + B dtheta.  A rigid
motion of the pair gives no force; the 12 x 12 matrix is symmetric (checked in tests/test_stiffness.py
against LAMMPS's forces and torques for small random displacements and rotations).  The smoothing
factor 1 - B^4 of ``smooth yes`` is 1 to fourth order and leaves the linearisation unchanged.

``damping_forces`` has the same form in the velocities, with a_r = gamma_n, a_s = gamma_s,
B = gamma_r L / 2 P + gamma_t / 2 n n^T.

``bond_style bpm/spring`` (BondBPMSpring::compute: a central force k (r0 - r), / r0 with ``normalize
yes``, and a damping gamma (v_ij . r) / r along the bond) is the special case a_r = k (/ L), a_s = bend
= twist = 0 (damping: a_r = gamma): force only, no torque, so a spring network has no rotational
stiffness at all (:func:`spring_network`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from opalflow.materials import BondCoefficients
from opalflow.structure import Structure


@dataclass
class BondNetwork:
    """Linear bonds between particles i and j (i < j): unit vector n = (x_i - x_j) / L and the four
    coefficients of the linearised bond (see the module docstring)."""

    n_particles: int
    i: np.ndarray
    j: np.ndarray
    n: np.ndarray
    L: np.ndarray
    a_r: np.ndarray
    a_s: np.ndarray
    bend: np.ndarray
    twist: np.ndarray

    def bond_forces(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None = None) -> np.ndarray:
        """The force F of each bond (M, 3), LAMMPS's ``force1on2``: -F on particle i, +F on j.  ``stretch``
        (M, 3) adds to each bond's u_i - u_j (a macroscopic strain through the periodic images)."""
        i, j, n = self.i, self.j, self.n
        du = u[i] - u[j] if stretch is None else u[i] - u[j] + stretch
        n_du = np.einsum("ij,ij->i", n, du)[:, None]
        return (self.a_r[:, None] - self.a_s[:, None]) * n_du * n + self.a_s[:, None] * du \
            + (0.5 * self.a_s * self.L)[:, None] * np.cross(n, theta[i] + theta[j])

    def energy_parts(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None = None) -> dict:
        """The strain energy of the bonds split by deformation mode (totals, in the network's units):
        stretching 1/2 a_r (n . du)^2, shear 1/2 a_s |s|^2 with s = P du + L/2 n x (theta_i + theta_j) (the
        shear force is a_s s and the shear torque L/2 n x a_s s), bending 1/2 kb |P dtheta|^2 and twisting
        1/2 kt (n . dtheta)^2; they sum to 1/2 x^T K x (module docstring)."""
        i, j, n = self.i, self.j, self.n
        du = u[i] - u[j] if stretch is None else u[i] - u[j] + stretch
        n_du = np.einsum("ij,ij->i", n, du)
        shear = du - n_du[:, None] * n + (0.5 * self.L)[:, None] * np.cross(n, theta[i] + theta[j])
        d_t = theta[i] - theta[j]
        n_dt = np.einsum("ij,ij->i", n, d_t)
        return {"stretching": float(0.5 * np.sum(self.a_r * n_du**2)),
                "shear": float(0.5 * np.sum(self.a_s * np.einsum("ij,ij->i", shear, shear))),
                "bending": float(0.5 * np.sum(self.bend * (np.einsum("ij,ij->i", d_t, d_t) - n_dt**2))),
                "twisting": float(0.5 * np.sum(self.twist * n_dt**2))}

    def part(self, sel: slice) -> "BondNetwork":
        """The bonds in ``sel`` (views, no copies)."""
        return BondNetwork(self.n_particles, self.i[sel], self.j[sel], self.n[sel], self.L[sel], self.a_r[sel],
                           self.a_s[sel], self.bend[sel], self.twist[sel])

    def forces(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None = None,
               chunk: int = 2_000_000) -> tuple[np.ndarray, np.ndarray]:
        """Forces and torques (N, 3) of the bonds for displacements u and rotations theta (N, 3) (and a
        per-bond ``stretch``, see bond_forces): minus the stiffness (or damping) matrix times (u, theta);
        ``chunk`` bonds at a time."""
        f = np.zeros((self.n_particles, 3))
        tau = np.zeros((self.n_particles, 3))
        for start in range(0, len(self.L), chunk):
            sel = slice(start, start + chunk)
            b = self.part(sel)
            i, j, n, L = b.i, b.j, b.n, b.L
            extra = None if stretch is None else stretch[sel]
            du = u[i] - u[j] if extra is None else u[i] - u[j] + extra
            sum_t = theta[i] + theta[j]
            d_t = theta[i] - theta[j]
            half = (0.5 * b.a_s * L)[:, None]
            F = b.bond_forces(u, theta, extra)
            n_st = np.einsum("ij,ij->i", n, sum_t)[:, None]
            Ts = half * np.cross(n, du) - (0.5 * half * L[:, None]) * (sum_t - n_st * n)
            n_dt = np.einsum("ij,ij->i", n, d_t)[:, None]
            Bd = b.bend[:, None] * (d_t - n_dt * n) + b.twist[:, None] * n_dt * n
            for k in range(3):
                f[:, k] += np.bincount(j, F[:, k], self.n_particles) - np.bincount(i, F[:, k], self.n_particles)
                tau[:, k] += np.bincount(i, Ts[:, k] - Bd[:, k], self.n_particles) \
                    + np.bincount(j, Ts[:, k] + Bd[:, k], self.n_particles)
        return f, tau

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """The matrix times x = (u_1, theta_1, u_2, theta_2, ...) (6 per particle)."""
        x = x.reshape(self.n_particles, 6)
        f, tau = self.forces(x[:, :3], x[:, 3:])
        return -np.hstack([f, tau]).ravel()


def _geometry(s: Structure, L0: np.ndarray | None):
    i = np.minimum(s.bonds[:, 0], s.bonds[:, 1])
    j = np.maximum(s.bonds[:, 0], s.bonds[:, 1])
    d = s.minimum_image(s.positions[i] - s.positions[j])
    L = np.linalg.norm(d, axis=1) if L0 is None else L0
    return i, j, d / np.linalg.norm(d, axis=1)[:, None], L


def per_bond(s: Structure, coeffs: list[BondCoefficients], name: str) -> np.ndarray:
    """The coefficient ``name`` of each bond of ``s`` (its type, 1-based into ``coeffs``)."""
    return np.array([getattr(c, name) for c in coeffs], float)[s.bond_types - 1]


def stiffness_network(s: Structure, coeffs: list[BondCoefficients], L0: np.ndarray | None = None) -> BondNetwork:
    """The tangent stiffness of ``s``'s bonds (types 1-based into ``coeffs``; ``normalize yes``)."""
    i, j, n, L = _geometry(s, L0)
    pick = lambda name: per_bond(s, coeffs, name)  # noqa: E731
    return BondNetwork(s.n_particles, i, j, n, L, pick("kr") / L, pick("ks") / L, pick("kb"), pick("kt"))


def damping_network(s: Structure, coeffs: list[BondCoefficients], L0: np.ndarray | None = None) -> BondNetwork:
    """The bond damping matrix of ``s`` (BondBPMRotational::damping_forces, linear in the velocities)."""
    i, j, n, L = _geometry(s, L0)
    pick = lambda name: per_bond(s, coeffs, name)  # noqa: E731
    return BondNetwork(s.n_particles, i, j, n, L, pick("gn"), pick("gs"), 0.5 * pick("gr") * L, 0.5 * pick("gt"))


def mass_diagonal(s: Structure) -> np.ndarray:
    """Mass and moment of inertia of each particle (solid spheres), 6 per particle, as K's dofs."""
    m = s.densities * np.pi / 6 * s.diameters**3
    inertia = 0.1 * m * s.diameters**2
    return np.repeat(np.column_stack([m, inertia]), 3, axis=1).ravel()


def spring_network(s: Structure, k: np.ndarray, *, normalize: bool = True, L0: np.ndarray | None = None) -> BondNetwork:
    """The tangent stiffness of ``bond_style bpm/spring`` bonds with spring constant ``k`` per bond type
    (1-based types of ``s.bond_types``), or of their damping when ``k`` holds the gammas and
    ``normalize`` is False: a_r = k / L (``normalize yes``) or k along the bond, nothing else."""
    i, j, n, L = _geometry(s, L0)
    a_r = np.asarray(k, float)[s.bond_types - 1] / (L if normalize else 1.0)
    zero = np.zeros(len(L))
    return BondNetwork(s.n_particles, i, j, n, L, a_r, zero, zero, zero)
