"""Atomic samples of the polycrystal's elements: batched Tersoff, relaxation, stress (seed 003, eqs. 6-9).

Each tetrahedral element carries a periodic 64-atom diamond sample (2 x 2 x 2 conventional
cells) whose lattice is turned by the element's rotation Q.  The sample's cell follows the
element (eqs. 6-7): with B = 2 a0 I the reference cell and D_e the element's deformation
tensor (eq. 5), the cell is H = D_e Q B and an atom with fractional position s sits at H s.
The atoms are then brought to steady state (eq. 8) and the stress of the cell is the virial
(eq. 9).

All samples are evaluated at once: one JAX function of the positions of every atom of every
sample (shape (E, N, 3)) and of the cells (E, 3, 3).  The neighbour lists are fixed: atom i's
candidates are the K atoms within ``1.15 (R + D)`` of it in the reference crystal, each with
its cell-image offset n_ik, so the bond vector r_ik = x_j - x_i + H n_ik needs no search and
stays exact while no atom outside the list comes within R + D (:func:`Samples.check_strain`
keeps the deformation inside that).  The energy is :func:`opalflow.tersoff.model.site_energies`,
the same expression the fit differentiates; it equals LAMMPS ``pair_style tersoff`` to round-off
(tests/test_polycrystal.py).

Units: metal (eV, Angstrom, ps, amu); stresses returned in GPa, tension positive
(sigma = -P of LAMMPS; eq. 9 writes the virial with the opposite sign convention).

Steady state, two ways (``relaxation``):
- ``"minimize"``: energy minimisation at 0 K by Newton iterations with a fixed preconditioner,
  the pseudo-inverse of the unstrained sample's Hessian turned into each element's frame,
  x <- x + Q H0^+ Q^T f(x), until the largest atomic force is below ``force_tol``;
- ``"md"``: eq. 8 integrated by velocity Verlet (eq. 4) with a viscous damping of the atomic
  velocities until the same force tolerance; the kinetic term of eq. 9 is kept.
Both find the same internal relaxation (the Kleinman shift of the sublattices that turns
C44^0 into C44); the minimiser needs a few force evaluations where damped MD needs hundreds.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import jax
import numpy as np

from opalflow.tersoff.model import EV_PER_A3_GPA, site_energies
from opalflow.tersoff.properties import SI_MASS

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

CELLS = 2                        # conventional cells per edge of a sample: 8 * 2^3 = 64 atoms
LIST_FACTOR = 1.15               # fixed-list radius / (R + D)
AMU_A_PS2_PER_EV_A = 9648.53321  # 1 eV/A / amu in A/ps^2
AMU_A3_KG_M3 = 1660.53907        # 1 amu/A^3 in kg/m^3


def diamond_fractional(cells: int = CELLS) -> np.ndarray:
    """Fractional positions (N, 3) of the cells^3 conventional diamond cells, in a fixed order."""
    fcc = np.array([[0, 0, 0], [0, .5, .5], [.5, 0, .5], [.5, .5, 0]])
    basis = np.concatenate([fcc, fcc + 0.25])
    pts = [(basis + np.array(c)) / cells for c in itertools.product(range(cells), repeat=3)]
    return np.concatenate(pts)


def neighbor_lists(frac: np.ndarray, cell: float, radius: float):
    """Fixed neighbour lists of a cubic periodic sample of edge ``cell`` (A).

    Returns ``j`` (N, K) neighbour indices, ``shift`` (N, K, 3) integer cell offsets (the bond
    vector is H (s_j + shift - s_i)), ``reverse`` (N, K) flat indices i*K + k of the bonds that
    point *to* each atom (each atom is the neighbour of K others in a perfect crystal), and
    ``outside``, the distance of the nearest atom left out (A).
    """
    n = len(frac)
    images = np.array(list(itertools.product((-1, 0, 1), repeat=3)), dtype=float)
    d = (frac[None, :, None, :] + images[None, None] - frac[:, None, None, :]) * cell   # (N, N, 27, 3)
    r = np.linalg.norm(d, axis=-1)
    r[np.arange(n), np.arange(n), 13] = np.inf            # self, image (0, 0, 0)
    inside = r <= radius
    counts = inside.reshape(n, -1).sum(1)
    if len(set(counts)) != 1:
        raise ValueError(f"neighbour counts differ between atoms ({sorted(set(counts))}): not a perfect crystal")
    k = int(counts[0])
    if k == 0:
        raise ValueError(f"no neighbour within {radius:.3f} A")
    j = np.zeros((n, k), dtype=np.int64)
    shift = np.zeros((n, k, 3))
    for i in range(n):
        jj, ii = np.nonzero(inside[i])
        order = np.lexsort((ii, jj))
        j[i], shift[i] = jj[order], images[ii[order]]
    flat = {(i, int(j[i, q]), tuple(shift[i, q])): i * k + q for i in range(n) for q in range(k)}
    reverse = np.array([[flat[(int(j[i, q]), i, tuple(-shift[i, q]))] for q in range(k)] for i in range(n)])
    outside = float(r[~inside].min())
    return j, shift, reverse, outside


def random_rotations(count: int, seed: int) -> np.ndarray:
    """``count`` rotations uniform on SO(3) (Shoemake's uniform quaternions), (count, 3, 3)."""
    u1, u2, u3 = np.random.default_rng(seed).random((3, count))
    q = np.stack([np.sqrt(1 - u1) * np.sin(2 * np.pi * u2), np.sqrt(1 - u1) * np.cos(2 * np.pi * u2),
                  np.sqrt(u1) * np.sin(2 * np.pi * u3), np.sqrt(u1) * np.cos(2 * np.pi * u3)], axis=1)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], axis=1)


@dataclass
class Evaluation:
    """Forces (E, N, 3) in eV/A, energies (E,) in eV and stresses (E, 3, 3) in GPa of all samples."""

    forces: np.ndarray
    energy: np.ndarray
    stress: np.ndarray

    @property
    def max_force(self) -> float:
        return float(np.sqrt((self.forces ** 2).sum(-1)).max())


class Samples:
    """The batched Tersoff samples of a set of elements (one parameter set, one lattice constant a0)."""

    def __init__(self, params: np.ndarray, cutoff: float, a0: float, cells: int = CELLS):
        self.params = jnp.asarray(params, dtype=float)
        self.a0, self.cells = a0, cells
        self.frac = diamond_fractional(cells)
        self.n = len(self.frac)
        edge = cells * a0
        self.j, shift, self.reverse, self.outside = neighbor_lists(self.frac, edge, LIST_FACTOR * cutoff)
        self.k = self.j.shape[1]
        self.cutoff = cutoff
        self.offset = jnp.asarray(shift)                        # (N, K, 3) cell offsets
        self.volume0 = edge ** 3
        self.mass = SI_MASS
        self.density_kg_m3 = self.n * SI_MASS / self.volume0 * AMU_A3_KG_M3
        self._evaluate = jax.jit(self._evaluate_all)
        self._hessian_pinv = None

    def _bonds(self, x, H):
        """r_ik = x_j - x_i + H n_ik for every sample at once: (E, N, K, 3)."""
        return x[:, self.j] - x[:, :, None] + jnp.einsum("eab,ikb->eika", H, self.offset)

    def _evaluate_all(self, x, H):
        rv = self._bonds(x, H)
        energy = jnp.sum(site_energies(self.params, rv), axis=1)
        g = jax.grad(lambda b: jnp.sum(site_energies(self.params, b)))(rv)   # dE/dr_ik, (E, N, K, 3)
        flat = g.reshape(g.shape[0], -1, 3)
        forces = g.sum(2) - flat[:, self.reverse].sum(2)     # f_i = sum_k g_ik - sum_(i'k -> i) g_i'k
        volume = jnp.abs(jnp.linalg.det(H))
        virial = jnp.einsum("enka,enkb->eab", rv, g)          # sum r_ik (x) dE/dr_ik
        return forces, energy, virial / volume[:, None, None] * EV_PER_A3_GPA

    # ----- geometry -----
    def reference_cells(self, rotations: np.ndarray) -> np.ndarray:
        """Cells Q B of unstrained samples, (E, 3, 3): columns are the cell vectors."""
        return rotations * (self.cells * self.a0)

    def positions(self, cells: np.ndarray, frac: np.ndarray | None = None) -> np.ndarray:
        """Atom positions H s (eq. 7); s defaults to the perfect crystal for every sample."""
        s = np.broadcast_to(self.frac, (len(cells), self.n, 3)) if frac is None else frac
        return np.einsum("eab,enb->ena", cells, s)

    def check_strain(self, deformation: np.ndarray) -> None:
        """Refuse deformations under which an atom outside the fixed lists could reach the cutoff.

        The nearest unlisted atom sits at ``outside`` in the reference crystal; under D it is at
        least sigma_min(D) * outside away, less twice the largest relaxation displacement (0.2 A
        allowed).  That must stay beyond R + D.
        """
        smin = np.linalg.svd(deformation, compute_uv=False)[..., -1].min()
        if smin * self.outside - 0.4 <= self.cutoff:
            raise RuntimeError(f"element deformation too large for the fixed neighbour lists: smallest "
                               f"stretch {smin:.4f} brings the next shell ({self.outside:.3f} A) within the cutoff "
                               f"{self.cutoff:.3f} A")

    # ----- evaluation -----
    def evaluate(self, x: np.ndarray, cells: np.ndarray) -> Evaluation:
        f, e, s = self._evaluate(jnp.asarray(x), jnp.asarray(cells))
        return Evaluation(np.asarray(f), np.asarray(e), np.asarray(s))

    def hessian_pinv(self) -> np.ndarray:
        """Pseudo-inverse (3N x 3N, A^2/eV) of the unstrained sample's Hessian in the crystal frame.

        The three translations are its null space; they are projected out (pinv), so a step
        H0^+ f moves no sample's centre.
        """
        if self._hessian_pinv is None:
            cell = jnp.eye(3)[None] * (self.cells * self.a0)
            x0 = jnp.asarray(self.positions(np.asarray(cell))[0].ravel())
            energy = lambda v: jnp.sum(site_energies(self.params, self._bonds(v.reshape(1, self.n, 3), cell)))  # noqa: E731
            self._hessian_pinv = np.linalg.pinv(np.asarray(jax.hessian(energy)(x0)), rcond=1e-10)
        return self._hessian_pinv


@dataclass
class Relaxed:
    """Steady state of all samples: positions (E, N, 3), the evaluation there, and its cost."""

    x: np.ndarray
    evaluation: Evaluation
    evaluations: int


def relax_minimize(samples: Samples, x: np.ndarray, cells: np.ndarray, rotations: np.ndarray,
                   force_tol: float = 1e-4, max_iter: int = 50) -> Relaxed:
    """Energy minimisation of every sample in its fixed cell (0 K steady state of eq. 8).

    Newton iterations with the unstrained Hessian as a fixed preconditioner, turned into each
    sample's frame: x <- x + Q H0^+ Q^T f(x).  Near the reference crystal the error shrinks by
    about the relative change of the Hessian (the strain) per iteration.  Stops when the largest
    atomic force is below ``force_tol`` (eV/A); raises if ``max_iter`` iterations do not get there.
    """
    pinv = samples.hessian_pinv()
    e, n = x.shape[:2]
    for it in range(1, max_iter + 1):
        ev = samples.evaluate(x, cells)
        if ev.max_force <= force_tol:
            return Relaxed(x, ev, it)
        local = np.einsum("eba,enb->ena", rotations, ev.forces).reshape(e, 3 * n)   # Q^T f
        step = (local @ pinv).reshape(e, n, 3)
        x = x + np.einsum("eab,enb->ena", rotations, step)
    raise RuntimeError(f"sample relaxation: largest force {ev.max_force:.3g} eV/A after {max_iter} "
                       f"Newton iterations (tolerance {force_tol:g}): the elements are strained too far")


def relax_md(samples: Samples, x: np.ndarray, cells: np.ndarray, force_tol: float = 1e-4,
             timestep_ps: float = 0.001, damping_per_ps: float = 20.0, max_steps: int = 20000,
             v: np.ndarray | None = None) -> tuple[Relaxed, np.ndarray]:
    """Damped molecular dynamics of every sample in its fixed cell to steady state (eq. 8).

    Velocity Verlet (eq. 4) on the atoms with a viscous force -gamma m v (gamma =
    ``damping_per_ps``), from velocities ``v`` (zero by default), until the largest force is
    below ``force_tol`` (eV/A).  The stress keeps eq. 9's kinetic term -(1/V) sum m (v - <v>)(v - <v>)
    (GPa, tension positive).  Returns the state and the velocities.
    """
    v = np.zeros_like(x) if v is None else v
    acc = AMU_A_PS2_PER_EV_A / samples.mass
    ev = samples.evaluate(x, cells)
    dt, decay = timestep_ps, np.exp(-damping_per_ps * timestep_ps)
    for step in range(1, max_steps + 1):
        if ev.max_force <= force_tol:
            break
        v = (v + 0.5 * dt * acc * ev.forces) * decay
        x = x + dt * v
        ev = samples.evaluate(x, cells)
        v = v + 0.5 * dt * acc * ev.forces
    else:
        raise RuntimeError(f"damped MD: largest force {ev.max_force:.3g} eV/A after {max_steps} steps")
    dv = v - v.mean(axis=1, keepdims=True)
    volume = np.abs(np.linalg.det(cells))
    kinetic = np.einsum("ena,enb->eab", dv, dv) * samples.mass / AMU_A_PS2_PER_EV_A / volume[:, None, None]
    ev.stress = ev.stress - kinetic * EV_PER_A3_GPA
    return Relaxed(x, ev, step), v
