"""Macro dynamics of the tetrahedral elements driven by their atomic samples (seed 003, eqs. 4-11).

One macro step: each element's deformation tensor D_e = (r1 - r0 | r2 - r0 | r3 - r0)
(r1* - r0* | ...)^-1 (eq. 5) is given to its sample (eqs. 6-7: the cell becomes D_e Q B and the
atoms keep their fractional positions, so the previous steady state is the starting point),
the samples are brought to steady state (eq. 8) and give the element stresses S_e (eqs. 9-10),
the stresses give forces on the vertices (eq. 11), and the vertices move by velocity Verlet
(eq. 4).

Vertex forces: a face with area vector n (outward, eq. 11) carries the force S_e n, split to
its three vertices by area, one third each; summed over the three faces that meet at a vertex
this is f_a = -V_e S_e grad N_a, the nodal force of a constant-stress tetrahedron, computed here
as the columns of -V_e S_e Ds^-T (Ds = current shape matrix) for vertices 1-3 and minus their
sum for vertex 0.  Masses: each element gives a quarter of its mass (sample density x
reference volume) to each vertex.

Units: nm, ps, GPa, nN (1 GPa nm^2 = 1 nN); a (nm/ps^2) = 1e3 F (nN) / (rho (kg/m^3) V (nm^3)).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from opalflow.tersoff.polycrystal.mesh import Mesh
from opalflow.tersoff.polycrystal.samples import Samples, relax_md, relax_minimize

ACCEL = 1e3          # nm/ps^2 per nN / (kg/m^3 nm^3)
M_PER_S = 1e3        # 1 nm/ps in m/s


def cubic_stiffness(c11: float, c12: float, c44: float) -> np.ndarray:
    """The fourth-order stiffness tensor (3, 3, 3, 3) of a cubic crystal in its own axes (GPa)."""
    d = np.eye(3)
    c = (c12 * np.einsum("ij,kl->ijkl", d, d) + c44 * (np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d)))
    for i in range(3):
        c[i, i, i, i] += c11 - c12 - 2.0 * c44
    return c


def rotated_stiffness(c: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """C'_ijkl = Q_ia Q_jb Q_kc Q_ld C_abcd for each rotation, (E, 3, 3, 3, 3)."""
    return np.einsum("eia,ejb,ekc,eld,abcd->eijkl", rotations, rotations, rotations, rotations, c, optimize=True)


@dataclass
class WaveSpeeds:
    """Plate (P wave), rod and shear wave speeds (m/s) of an isotropic solid."""

    wave_speed_plate_m_s: float
    wave_speed_rod_m_s: float
    wave_speed_shear_m_s: float

    def of(self, wave: str) -> float:
        """The speed of the ``plate``, ``rod`` or ``shear`` wave."""
        return getattr(self, f"wave_speed_{wave}_m_s")


@dataclass
class Isotropic(WaveSpeeds):
    """An isotropic average of a cubic crystal: moduli (GPa), Poisson ratio and the wave speeds they imply."""

    B_GPa: float = 0.0
    G_GPa: float = 0.0
    E_GPa: float = 0.0
    nu: float = 0.0


@dataclass
class Bounds:
    """The Voigt (uniform strain), Reuss (uniform stress) and Hill averages of a cubic crystal."""

    voigt: Isotropic
    reuss: Isotropic
    hill: Isotropic


def polycrystal_bounds(c11: float, c12: float, c44: float, density_kg_m3: float) -> Bounds:
    """Voigt, Reuss and Hill averages of a cubic crystal and the wave speeds they imply.

    B = (C11 + 2 C12)/3; G_V = (C11 - C12 + 3 C44)/5 (Voigt 1928), G_R = 5 (C11 - C12) C44 /
    (4 C44 + 3 (C11 - C12)) (Reuss 1929), G_H = (G_V + G_R)/2 (Hill 1952); E = 9BG/(3B + G),
    nu = (3B - 2G)/(2(3B + G)).  Speeds: plate (P wave) sqrt((B + 4G/3)/rho), rod sqrt(E/rho),
    shear sqrt(G/rho) (m/s).
    """
    bulk = (c11 + 2.0 * c12) / 3.0
    g_voigt = (c11 - c12 + 3.0 * c44) / 5.0
    g_reuss = 5.0 * (c11 - c12) * c44 / (4.0 * c44 + 3.0 * (c11 - c12))

    def average(g: float) -> Isotropic:
        e, nu = 9.0 * bulk * g / (3.0 * bulk + g), (3.0 * bulk - 2.0 * g) / (2.0 * (3.0 * bulk + g))
        return Isotropic(**dataclasses.asdict(speeds(e, nu, density_kg_m3)), B_GPa=bulk, G_GPa=g, E_GPa=e, nu=nu)

    return Bounds(average(g_voigt), average(g_reuss), average(0.5 * (g_voigt + g_reuss)))


def speeds(e_gpa: float, nu: float, density_kg_m3: float) -> WaveSpeeds:
    """Plate (P wave), rod and shear wave speeds (m/s) of an isotropic solid with E (GPa) and nu."""
    m = e_gpa * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))
    g = e_gpa / (2.0 * (1.0 + nu))
    return WaveSpeeds(*(float(np.sqrt(v * 1e9 / density_kg_m3)) for v in (m, e_gpa, g)))


class Polycrystal:
    """Vertices, elements with their samples, and the state of the macro dynamics."""

    def __init__(self, mesh: Mesh, samples: Samples, rotations: np.ndarray, constants: tuple[float, float, float],
                 relaxation: str = "minimize", force_tol: float = 1e-4):
        self.mesh, self.samples, self.rotations = mesh, samples, rotations
        self.relaxation, self.force_tol = relaxation, force_tol
        self.dm_inv = np.linalg.inv(mesh.shape_matrices(mesh.vertices))
        self.volume0 = mesh.volumes()
        if (self.volume0 <= 0).any():
            raise ValueError("mesh has an inverted element")
        self.density = samples.density_kg_m3
        self.mass = np.bincount(mesh.tets.ravel(), np.repeat(self.density * self.volume0 / 4.0, 4),
                                minlength=len(mesh.vertices))          # kg/m^3 nm^3
        self.stiffness_tensors = rotated_stiffness(cubic_stiffness(*constants), rotations)
        self.x = mesh.vertices.copy()
        self.v = np.zeros_like(self.x)
        self.box = mesh.box.copy()
        self.cells_ref = samples.reference_cells(rotations)
        self.cells = self.cells_ref.copy()
        self.atoms = samples.positions(self.cells)
        self.atom_v = np.zeros_like(self.atoms) if relaxation == "md" else None
        self.evaluations = 0
        self.stress = np.zeros((mesh.elements, 3, 3))
        self.f = None
        self.residual = np.inf

    # ----- samples -> stresses -> vertex forces -----
    def deformation(self) -> tuple[np.ndarray, np.ndarray]:
        """D_e of every element (eq. 5) and the current shape matrices Ds."""
        ds = self.mesh.shape_matrices(self.x, self.box)
        return ds @ self.dm_inv, ds

    def element_stresses(self, deformation: np.ndarray) -> np.ndarray:
        """Steady-state sample stresses (GPa) for the element deformations (eqs. 6-10)."""
        self.samples.check_strain(deformation)
        cells = deformation @ self.cells_ref
        atoms = np.einsum("eab,ebc,enc->ena", cells, np.linalg.inv(self.cells), self.atoms)   # same fractional positions
        if self.relaxation == "md":
            relaxed, self.atom_v = relax_md(self.samples, atoms, cells, self.force_tol, v=self.atom_v)
        else:
            relaxed = relax_minimize(self.samples, atoms, cells, self.rotations, self.force_tol)
        self.atoms, self.cells = relaxed.x, cells
        self.evaluations += relaxed.evaluations
        return relaxed.evaluation.stress

    def forces(self) -> np.ndarray:
        """Net vertex forces (V, 3; nN) of the current configuration; sets stress and residual."""
        deformation, ds = self.deformation()
        self.stress = self.element_stresses(deformation)
        volume = np.linalg.det(ds) / 6.0
        cols = -volume[:, None, None] * self.stress @ np.linalg.inv(ds).transpose(0, 2, 1)   # (E, 3, 3): f_1..f_3
        fe = np.empty((len(ds), 4, 3))
        fe[:, 1:] = cols.transpose(0, 2, 1)
        fe[:, 0] = -fe[:, 1:].sum(1)
        f = np.stack([np.bincount(self.mesh.tets.ravel(), fe[..., a].ravel(), minlength=len(self.x))
                      for a in range(3)], axis=1)
        scale = np.sqrt((fe ** 2).sum())
        self.residual = float(np.sqrt((f ** 2).sum()) / scale) if scale > 0 else 0.0
        self.f = f
        return f

    # ----- linear elasticity of the mesh with the potential's single-crystal constants -----
    def element_stiffness(self) -> np.ndarray:
        """K_e (E, 12, 12; nN/nm) of the constant-strain tetrahedra with each element's rotated C."""
        grad = np.empty((self.mesh.elements, 4, 3))
        grad[:, 1:] = self.dm_inv                        # rows of Dm^-1: grad N_1..N_3
        grad[:, 0] = -self.dm_inv.sum(1)
        k = np.einsum("e,eaj,eijkl,ebl->eaibk", self.volume0, grad, self.stiffness_tensors, grad, optimize=True)
        return k.reshape(-1, 12, 12)

    def stable_timestep(self, safety: float) -> float:
        """safety x 2 / omega_max (ps), omega_max bounded by the largest element eigenvalue.

        Irons and Treharne (1971): with lumped masses the largest eigenfrequency of the mesh is at
        most the largest of each element alone, omega_e^2 = lambda_max(K_e) / (rho V_e / 4).
        """
        lam = np.linalg.eigvalsh(self.element_stiffness())[:, -1]
        omega2 = ACCEL * lam / (self.density * self.volume0 / 4.0)
        return safety * 2.0 / float(np.sqrt(omega2.max()))

    def stiffness_matrix(self) -> sp.csr_matrix:
        """Assembled K (3V x 3V) of :meth:`element_stiffness`."""
        ke = self.element_stiffness()
        dof = (3 * self.mesh.tets[:, :, None] + np.arange(3)).reshape(-1, 12)
        rows = np.repeat(dof, 12, axis=1).ravel()
        cols = np.tile(dof, (1, 12)).ravel()
        n = 3 * len(self.x)
        return sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(n, n))

    # ----- integrators -----
    def verlet(self, dt: float, damping: float = 0.0, fixed: np.ndarray | None = None,
               fixed_velocity: np.ndarray | None = None) -> None:
        """One velocity-Verlet step (eq. 4) with viscous damping -damping m v (1/ps); where the
        boolean mask ``fixed`` (V, 3) is set, the velocity component is ``fixed_velocity`` (V, 3)."""
        if self.f is None:
            self.forces()
        acc = ACCEL / self.mass[:, None]
        decay = np.exp(-0.5 * damping * dt)
        self.v = (self.v + 0.5 * dt * acc * self.f) * decay
        if fixed is not None:
            self.v[fixed] = fixed_velocity[fixed]
        self.x += dt * self.v
        self.forces()
        self.v = (self.v + 0.5 * dt * acc * self.f) * decay
        if fixed is not None:
            self.v[fixed] = fixed_velocity[fixed]

    def solve_static(self, tol: float, max_iter: int = 50) -> int:
        """Equilibrium of the vertices for the current box by modified Newton iterations.

        The tangent is the mesh's elastic stiffness with the potential's relaxed single-crystal
        constants (fixed, factorised once), shifted by 1e-6 of its largest element eigenvalue
        times the lumped mass so the rigid-body modes are not singular; the residual is always the
        true one from the samples.  Returns the iterations; stops at residual <= tol.
        """
        if not hasattr(self, "_factor"):
            k = self.stiffness_matrix()
            shift = 1e-6 * float(np.abs(k.diagonal()).max() / self.mass.min())
            m = sp.diags(np.repeat(self.mass, 3) * shift)
            self._factor = spla.splu((k + m).tocsc())
        for it in range(1, max_iter + 1):
            f = self.forces()
            if self.residual <= tol:
                return it
            self.x += self._factor.solve(f.ravel()).reshape(-1, 3)
        raise RuntimeError(f"static solve: residual {self.residual:.3g} after {max_iter} iterations")

    def mean_stress(self) -> np.ndarray:
        """Volume average of the element stresses (3, 3; GPa)."""
        deformation, ds = self.deformation()
        volume = np.linalg.det(ds) / 6.0
        return np.einsum("e,eab->ab", volume, self.stress) / volume.sum()

    def volume(self) -> float:
        return float(self.mesh.volumes(self.x, self.box).sum())
