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

from opalflow.jit import njit
from opalflow.linalg.direct import in_parts
from opalflow.materials import BondCoefficients
from opalflow.structure import Structure


#: :meth:`BondNetwork.bond_forces` by numpy up to this many bonds, by the numba kernel above
NUMPY_MAX_BONDS = 200_000
#: :meth:`BondNetwork.energy_parts` sums this many bonds at a time
ENERGY_CHUNK = 1 << 20
#: :meth:`BondNetwork.matvec` runs on threads from this many bonds (fewer: the threads' start costs more than
#: their share; the paper's d = 30 nm sample, 1.8 M bonds: 45-50 ms a product on one thread, 26 on two)
PARTS_MIN_BONDS = 100_000
#: an empty (0, 3) array: no per-bond stretch, no per-bond forces kept (the kernel's "none")
_NO_ROWS = np.zeros((0, 3))
#: an empty bool array: every bond counts (the kernel's "no mask")
_NO_MASK = np.zeros(0, bool)
#: the parts of K x that :meth:`BondNetwork.matvec` forms: all of it; the translations' rows from the rotations
#: alone (K_ut theta: the first product of the block Gauss-Seidel preconditioner,
#: opalflow.bpm.static.block_amg_preconditioner); the rotations' rows (K_tu u + K_tt theta: its second).  A part
#: skips the work of the rest (the paper's 17.5 M bonds: bench/results/paper_scale.json, ``kernels``)
BLOCKS = {"all": 0, "ut": 1, "t": 2}


def bond_force(xp, n, L, a_r, a_s, du, st):
    """F = a_r n n^T du + a_s P du + a_s L / 2 n x st of each bond (the module docstring; rows of bonds, st =
    theta_i + theta_j), in array module ``xp`` (numpy, or jax.numpy for the JAX operator)."""
    a_r, a_s = a_r[:, None], a_s[:, None]
    return (a_r - a_s) * xp.sum(n * du, axis=1, keepdims=True) * n + a_s * du + 0.5 * a_s * L[:, None] * xp.cross(n, st)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows a x b of (M, 3) arrays (numpy's cross moves axes for every call: 3x slower at these sizes)."""
    out = np.empty(a.shape, np.result_type(a, b))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


@dataclass
class EnergyParts:
    """The bonds' strain energy by deformation mode (:meth:`BondNetwork.energy_parts`: totals in the network's
    units), or its fractions of the whole (:meth:`fractions`)."""

    stretching: float
    shear: float
    bending: float
    twisting: float

    def __add__(self, other: EnergyParts) -> EnergyParts:
        return EnergyParts(self.stretching + other.stretching, self.shear + other.shear,
                           self.bending + other.bending, self.twisting + other.twisting)

    @property
    def total(self) -> float:
        return self.stretching + self.shear + self.bending + self.twisting

    def fractions(self) -> EnergyParts | None:
        """Each mode's share of the whole (None where there is no energy)."""
        total = self.total
        return None if total <= 0 else EnergyParts(self.stretching / total, self.shear / total,
                                                   self.bending / total, self.twisting / total)


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

    def bond_forces(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None = None,
                    threads: int = 1) -> np.ndarray:
        """The force F of each bond (M, 3), LAMMPS's ``force1on2``: -F on particle i, +F on j.  ``stretch``
        (M, 3) adds to each bond's u_i - u_j (a macroscopic strain through the periodic images).  Up to
        NUMPY_MAX_BONDS bonds numpy's gathers and cross product of the module docstring's F (a small sample's
        static run then never imports numba: 0.5 s of its 1.2); above, the numba pass of :func:`_bond_loads`
        (0.05 s at 1.8 M bonds where numpy's took 0.2), on ``threads`` threads.  The two agree
        (tests/test_stiffness.py)."""
        if len(self.L) <= NUMPY_MAX_BONDS:
            du = u[self.i] - u[self.j] + (0.0 if stretch is None else stretch)
            return bond_force(np, self.n, self.L, self.a_r, self.a_s, du, theta[self.i] + theta[self.j])
        F = np.empty((len(self.L), 3))
        self._loads(np.hstack([u, theta]), _NO_ROWS if stretch is None else stretch, F, threads)
        return F

    def energy_parts(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None = None) -> EnergyParts:
        """The strain energy of the bonds split by deformation mode (totals, in the network's units):
        stretching 1/2 a_r (n . du)^2, shear 1/2 a_s |s|^2 with s = P du + L/2 n x (theta_i + theta_j) (the
        shear force is a_s s and the shear torque L/2 n x a_s s), bending 1/2 kb |P dtheta|^2 and twisting
        1/2 kt (n . dtheta)^2; they sum to 1/2 x^T K x (module docstring).  The first two from the bond force
        F = a_r (n . du) n + a_s s (:meth:`bond_forces`): (n . F)^2 / (2 a_r) and |P F|^2 / (2 a_s).  Summed over
        ENERGY_CHUNK bonds at a time: numpy's temporaries stay small and are reused (the paper's 17.5 M bonds
        4.5 s in one piece into fresh memory, 6.4 s in its static run, 2.1 s in pieces; pieces of 0.1 or 0.2 M
        bonds 3.0-3.3 s)."""
        parts = EnergyParts(0.0, 0.0, 0.0, 0.0)
        for start in range(0, len(self.L), ENERGY_CHUNK):
            sel = slice(start, start + ENERGY_CHUNK)
            parts = parts + self.part(sel)._energy_parts(u, theta, None if stretch is None else stretch[sel])
        return parts

    def _energy_parts(self, u: np.ndarray, theta: np.ndarray, stretch: np.ndarray | None) -> EnergyParts:
        n = self.n
        F = self.bond_forces(u, theta, stretch)
        Fr = np.einsum("ij,ij->i", n, F)
        Fs = F - Fr[:, None] * n
        d_t = theta[self.i] - theta[self.j]
        n_dt = np.einsum("ij,ij->i", n, d_t)

        def over(a, b):         # (a bond of zero stiffness carries nothing)
            return float(np.sum(np.divide(a, b, out=np.zeros_like(a), where=b > 0)))
        return EnergyParts(0.5 * over(Fr**2, self.a_r), 0.5 * over(np.einsum("ij,ij->i", Fs, Fs), self.a_s),
                           float(0.5 * np.sum(self.bend * (np.einsum("ij,ij->i", d_t, d_t) - n_dt**2))),
                           float(0.5 * np.sum(self.twist * n_dt**2)))

    def part(self, sel: slice) -> "BondNetwork":
        """The bonds in ``sel`` (views, no copies)."""
        return BondNetwork(self.n_particles, self.i[sel], self.j[sel], self.n[sel], self.L[sel], self.a_r[sel],
                           self.a_s[sel], self.bend[sel], self.twist[sel])

    def forces(self, u: np.ndarray, theta: np.ndarray,
               stretch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Forces and torques (N, 3) of the bonds for displacements u and rotations theta (N, 3) (and a
        per-bond ``stretch``, see bond_forces): minus the stiffness (or damping) matrix times (u, theta)."""
        out = self._loads(np.hstack([u, theta]), _NO_ROWS if stretch is None else stretch)
        return -out[:, :3], -out[:, 3:]

    def matvec(self, x: np.ndarray, threads: int = 1, alive: np.ndarray | None = None,
               block: str = "all") -> np.ndarray:
        """The matrix times x = (u_1, theta_1, u_2, theta_2, ...) (6 per particle), over ``threads`` shares of the
        bonds at once above :data:`PARTS_MIN_BONDS` (:meth:`_loads`); ``alive`` (M,) bool: the bonds it holds
        false left out (broken: the quasi-static re-solves keep no copy of the network with them zeroed);
        ``block`` (:data:`BLOCKS`): all of K x, or the rows of one block of K alone (the rest of the result 0)."""
        return self._loads(np.reshape(x, (self.n_particles, 6)), _NO_ROWS, threads=threads,
                           alive=_NO_MASK if alive is None else alive, block=BLOCKS[block]).ravel()

    def _loads(self, x: np.ndarray, stretch: np.ndarray, force: np.ndarray = _NO_ROWS, threads: int = 1,
               alive: np.ndarray | None = None, block: int = 0) -> np.ndarray:
        """K x (N, 6) for x (N, 6) through :func:`_bond_loads` (each bond's F into ``force`` where it has rows;
        the bonds ``alive`` holds false, where it has rows, left out; ``block`` a value of :data:`BLOCKS`).  With
        ``threads`` > 1 (and :data:`PARTS_MIN_BONDS` bonds) each thread takes a contiguous share of the bonds into
        a sum of its own, added in share order (the same threads, the same digits)."""
        alive = _NO_MASK if alive is None else alive
        n, m = self.n_particles, len(self.L)
        parts = threads if m >= PARTS_MIN_BONDS else 1
        x, stretch = np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(stretch, dtype=float)
        outs = [np.zeros((n, 6)) for _ in range(parts)]
        at = np.linspace(0, m, parts + 1).astype(np.int64)

        def share(k):
            b = slice(at[k], at[k + 1])
            _bond_loads(self.i[b], self.j[b], self.n[b], self.L[b], self.a_r[b], self.a_s[b], self.bend[b],
                        self.twist[b], x, stretch[b] if len(stretch) else stretch, outs[k],
                        force[b] if len(force) else force, alive[b] if len(alive) else alive, block)
        in_parts(share, parts)
        for more in outs[1:]:
            outs[0] += more
        return outs[0]


@njit(cache=True, nogil=True)
def _bond_loads(i, j, n, L, a_r, a_s, bend, twist, x, stretch, out, force, alive, block):
    """out += K x, (N, 6): each bond's F and Ts of the module docstring (du plus ``stretch`` where it has
    rows) and B dtheta, f_i -= F, f_j += F, tau_i += Ts - B dtheta, tau_j += Ts + B dtheta, negated; F also
    into ``force`` (M, 3) where it has rows; the bonds ``alive`` holds false skipped where it has rows; ``block``
    (:data:`BLOCKS`) 1: the translations' rows from the rotations alone, 2: the rotations' rows alone.  One pass
    over the bonds (the matrix-free product of the static and quasi-static solvers: ~10x numpy's and JAX's
    gathers and scatters on a CPU)."""
    with_stretch = stretch.shape[0] > 0
    keep = force.shape[0] > 0
    masked = alive.shape[0] > 0
    du, st, dt = np.empty(3), np.empty(3), np.empty(3)
    for b in range(len(L)):
        if masked and not alive[b]:
            continue
        p, q = i[b], j[b]
        nx, ny, nz = n[b, 0], n[b, 1], n[b, 2]
        half = 0.5 * a_s[b] * L[b]
        for k in range(3):
            st[k] = x[p, 3 + k] + x[q, 3 + k]
        ns0, ns1, ns2 = ny * st[2] - nz * st[1], nz * st[0] - nx * st[2], nx * st[1] - ny * st[0]    # n x st
        if block == 1:                       # K_ut theta: the shear force of the rotations alone
            out[p, 0] += half * ns0
            out[p, 1] += half * ns1
            out[p, 2] += half * ns2
            out[q, 0] -= half * ns0
            out[q, 1] -= half * ns1
            out[q, 2] -= half * ns2
            continue
        for k in range(3):
            du[k] = x[p, k] - x[q, k] + (stretch[b, k] if with_stretch else 0.0)
            dt[k] = x[p, 3 + k] - x[q, 3 + k]
        n_du = nx * du[0] + ny * du[1] + nz * du[2]
        n_st = nx * st[0] + ny * st[1] + nz * st[2]
        n_dt = nx * dt[0] + ny * dt[1] + nz * dt[2]
        nd0, nd1, nd2 = ny * du[2] - nz * du[1], nz * du[0] - nx * du[2], nx * du[1] - ny * du[0]    # n x du
        h2 = 0.5 * half * L[b]
        T0 = half * nd0 - h2 * (st[0] - n_st * nx)
        T1 = half * nd1 - h2 * (st[1] - n_st * ny)
        T2 = half * nd2 - h2 * (st[2] - n_st * nz)
        B0 = bend[b] * (dt[0] - n_dt * nx) + twist[b] * n_dt * nx
        B1 = bend[b] * (dt[1] - n_dt * ny) + twist[b] * n_dt * ny
        B2 = bend[b] * (dt[2] - n_dt * nz) + twist[b] * n_dt * nz
        out[p, 3] -= T0 - B0
        out[p, 4] -= T1 - B1
        out[p, 5] -= T2 - B2
        out[q, 3] -= T0 + B0
        out[q, 4] -= T1 + B1
        out[q, 5] -= T2 + B2
        if block == 2:
            continue
        c = (a_r[b] - a_s[b]) * n_du
        F0 = c * nx + a_s[b] * du[0] + half * ns0
        F1 = c * ny + a_s[b] * du[1] + half * ns1
        F2 = c * nz + a_s[b] * du[2] + half * ns2
        if keep:
            force[b, 0], force[b, 1], force[b, 2] = F0, F1, F2
        out[p, 0] += F0
        out[p, 1] += F1
        out[p, 2] += F2
        out[q, 0] -= F0
        out[q, 1] -= F1
        out[q, 2] -= F2


def _geometry(s: Structure, L0: np.ndarray | None):
    """(i, j, n, L) of ``s``'s bonds, i < j (i and j contiguous copies, not views of the structure's bond
    columns: the bond operator's kernels read them with a unit stride)."""
    i, j = np.minimum(s.bonds[:, 0], s.bonds[:, 1]), np.maximum(s.bonds[:, 0], s.bonds[:, 1])
    d = s.bond_vectors()                                # x[b1] - x[b0], so x[i] - x[j] where b1 < b0
    np.negative(d, out=d, where=(s.bonds[:, 0] < s.bonds[:, 1])[:, None])   # and its negative where b0 < b1
    length = np.linalg.norm(d, axis=1)
    return i, j, d / length[:, None], length if L0 is None else L0


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
