"""Regular arrays of bonded spheres: simple cubic and FCC (analytic checks, calibration).

Simple cubic with spacing a: spheres of diameter a touching their 6 nearest
neighbours; with bonds to those 6 (cutoff 1.2 a < sqrt(2) a) and no contacts, a
uniaxial compression along z with periodic x and y strains only the z bonds, so

    E = k_axial L0 / a^2 = E_b pi r_b^2 / a^2       (k_axial = E_b A / L0, L0 = a)

which is pi/4 E_b for r_b = a/2.  FCC with cubic cell a: diameter a / sqrt(2),
12 neighbours.  The bottom layer is the fixed substrate, or, with ``lattice.periodic_z``, the lattice is
periodic in all three directions (no substrate) for the static stiffness tensor; a beam in three-point
bending (``compression.loading = "bending"``) has none either.
"""
from __future__ import annotations

import math

import numpy as np

from opalflow.bpm.bonds import bond_types_by_material, find_bonds
from opalflow.bpm.loading import LOADINGS
from opalflow.bpm.scene import Scene
from opalflow.lattice.spec import LatticeWorkflow
from opalflow.materials import material
from opalflow.structure import Structure, quantize
from opalflow.units import density_to_nano


def lattice_sites(arrangement: str, a: float, nx: int, ny: int, nz: int) -> tuple[np.ndarray, float]:
    """Sites (nm) and sphere diameter of an sc or fcc lattice with cubic cell a."""
    basis = {"sc": [(0, 0, 0)], "fcc": [(0, 0, 0), (0.5, 0.5, 0), (0.5, 0, 0.5), (0, 0.5, 0.5)]}[arrangement]
    cells = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    sites = (cells[:, None, :] + np.array(basis)[None, :, :]).reshape(-1, 3) + 0.25
    diameter = a if arrangement == "sc" else a / math.sqrt(2)
    return sites * a, diameter


def build_lattice(spec: LatticeWorkflow, progress=None) -> Structure:
    lat = spec.lattice
    a = lat.spacing_nm
    x, d = lattice_sites(lat.arrangement, a, lat.cells_x, lat.cells_y, lat.cells_z)
    box = np.array([lat.cells_x * a, lat.cells_y * a, lat.cells_z * a])
    periodic = np.array([spec.boundary.sides == "periodic"] * 2 + [lat.periodic_z])
    x = quantize(x, box, periodic)
    diameters = np.full(len(x), d)
    held = not lat.periodic_z and LOADINGS[spec.compression.loading].substrate     # (a beam in bending has none)
    substrate = x[:, 2] < x[:, 2].min() + 0.5 * d if held else np.zeros(len(x), bool)
    types = np.where(substrate, 2, 1).astype(np.int32)
    bonds = find_bonds(x, diameters, box, periodic, spec.bonds.cutoff_factor, spec.bonds.min_length_factor)
    rho = density_to_nano(material(spec.material, spec.materials).density_kg_m3)
    return Structure(positions=x, diameters=diameters, types=types, densities=np.full(len(x), rho),
                     box_lo=np.zeros(3), box_hi=box, periodic=periodic, bonds=bonds,
                     bond_types=bond_types_by_material(bonds, np.zeros(len(x), bool)),
                     type_names=[spec.material, "substrate"], bond_type_names=[spec.material],
                     groups={"substrate": substrate},
                     meta={"solid_fraction": float(len(x) * math.pi / 6 * d**3 / np.prod(box))})


SCENE = Scene(build=build_lattice)
