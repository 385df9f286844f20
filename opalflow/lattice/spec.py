"""Spec of the lattice scene: the ``[lattice]`` section and the analytic reference it gives."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from opalflow.bpm.methods import METHODS
from opalflow.bpm.spec import BoundarySpec, BpmWorkflow
from opalflow.materials import Material, material
from opalflow.spec import check

LATTICES = ("sc", "fcc")


@dataclass
class LatticeSpec:
    """Regular arrays of bonded spheres (kind = "lattice") for analytic checks."""

    arrangement: str = "sc"          # sc: simple cubic (touching spheres of diameter a); fcc: face-centred cubic
    spacing_nm: float = 20.0         # the cubic cell's edge a
    cells_x: int = 4                 # cells along x
    cells_y: int = 4                 # cells along y
    cells_z: int = 8                 # cells along z (the loading axis)
    periodic_z: bool = False     # periodic in z too, no substrate: the static 6 x 6 stiffness tensor


@dataclass
class LatticeWorkflow(BpmWorkflow):
    """A regular lattice (kind = "lattice") compressed by a plate."""

    lattice: LatticeSpec = field(default_factory=LatticeSpec)
    boundary: BoundarySpec = field(default_factory=BoundarySpec)

    def references(self) -> dict[str, tuple[float, str]]:
        """Simple cubic without contacts: E = E_b pi r_b^2 / a^2 (see :mod:`opalflow.lattice.scene`); pulled
        along its bonds (``compression.loading = "tension"``), every bond along z carries the same force and
        they all reach Fr_c = sigma_b pi r_b^2 at once: strength sigma_b pi r_b^2 / a^2 (Roy and Hossain's
        eq. 10.4 read backwards)."""
        if self.lattice.arrangement != "sc" or self.contacts.enabled:
            return {}
        props = material(self.material, self.materials)
        r = self.bonds.radius_factor / 2
        if self.compression.loading == "bending":
            return {"youngs_modulus_GPa": (self.flexural_modulus(props, r), "beam theory: Timoshenko's simply "
                                           "supported beam with the lattice's EI and GA (LatticeWorkflow.flexural_modulus)")}
        if self.lattice.periodic_z:      # C11 = C22 = C33, C12 = 0: E along each axis is C11
            return {"youngs_modulus_GPa": (math.pi * r**2 * props.bond_youngs_modulus_GPa,
                                           "analytic: C11 = E_b pi r_b^2 / a^2, C12 = 0 (periodic simple-cubic lattice)")}
        refs = {"youngs_modulus_specimen_GPa": (math.pi * r**2 * props.bond_youngs_modulus_GPa,
                                                "analytic: E_b pi r_b^2 / a^2 (simple-cubic lattice)")}
        if self.compression.loading == "tension" and self.bonds.breakable:
            refs["strength_MPa"] = (math.pi * r**2 * props.bond_strength_MPa,
                                    "analytic: sigma_b pi r_b^2 / a^2 (simple-cubic lattice in tension)")
        return refs

    def flexural_modulus(self, props: Material, r: float, shear: bool = True) -> float:
        """The flexural modulus E_f = F L^3 / (4 b h^3 delta) (ASTM D790) that beam theory gives a simple-cubic
        beam of n_x x n_y x n_z cells (spacing a, bond radius r_b = r a) in three-point bending over the span
        L = (n_x - 1) a between its bottom end particles: Timoshenko's mid-span deflection (Timoshenko and Gere,
        Mechanics of Materials, sec. 10.4), delta / F = L^3 / (48 EI) + L / (4 kappa G A), kappa = 5/6,
        with the lattice's own stiffnesses: EI = n_y E_b (A_b sum_k z_k^2 + n_z I_b) (the bonds along x at
        heights z_k from the mid-plane, stretched, and bent themselves; A_b = pi r_b^2, I_b = pi r_b^4 / 4; that
        is E b h^3 / 12 (1 - 1/n_z^2) plus the bonds' own), G = G_b A_b / (2 a^2) (each bond's shear spring
        G_b A_b / a, the particles turning by half the shear: C44 of the periodic lattice's static tensor, to
        round-off), A = b h.  E_b, G_b = E_b / (2 (1 + nu_b)) from the material.  ``shear`` False: Euler-Bernoulli's
        beam (the first term alone)."""
        lat = self.lattice
        a, n = lat.spacing_nm, lat.cells_z
        span, depth, width = (lat.cells_x - 1) * a, n * a, lat.cells_y * a
        E_b = props.bond_youngs_modulus_GPa
        area_b, i_b = math.pi * (r * a) ** 2, math.pi * (r * a) ** 4 / 4
        heights = [(k - (n - 1) / 2) * a for k in range(n)]
        EI = lat.cells_y * E_b * (area_b * sum(h * h for h in heights) + n * i_b)
        GA = E_b / (2 * (1 + props.bond_poisson_ratio)) * area_b / (2 * a**2) * width * depth
        compliance = span**3 / (48 * EI) + (span / (4 * 5 / 6 * GA) if shear else 0.0)
        return span**3 / (4 * width * depth**3 * compliance)

    def validate(self) -> None:
        super().validate()
        lat = self.lattice
        check(lat.arrangement in LATTICES, "lattice.arrangement", lat.arrangement,
              f"must be one of {', '.join(LATTICES)}")
        check(1e-3 <= lat.spacing_nm <= 1e5, "lattice.spacing_nm", lat.spacing_nm, "must be in [1e-3, 1e5] nm")
        if lat.periodic_z:
            check(METHODS[self.compression.method].tensor, "lattice.periodic_z", lat.periodic_z,
                  "needs compression.method = \"static\" (a sample periodic in z has no substrate to compress on)")
            check(self.boundary.sides == "periodic", "lattice.periodic_z", lat.periodic_z,
                  "needs boundary.sides = \"periodic\" (periodic in all three directions)")
        for axis in "xyz":
            n = getattr(lat, f"cells_{axis}")
            check(2 <= n <= 200, f"lattice.cells_{axis}", n, "must be in [2, 200]")
        self.boundary.validate()
