"""Spec of the lattice scene: the ``[lattice]`` section and the analytic reference it gives."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from opalflow.bpm.spec import BoundarySpec, BpmWorkflow
from opalflow.materials import material
from opalflow.spec import check

LATTICES = ("sc", "fcc")


@dataclass
class LatticeSpec:
    """Regular arrays of bonded spheres (kind = "lattice") for analytic checks."""

    arrangement: str = "sc"
    spacing_nm: float = 20.0
    cells_x: int = 4
    cells_y: int = 4
    cells_z: int = 8
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
        if self.lattice.periodic_z:      # C11 = C22 = C33, C12 = 0: E along each axis is C11
            return {"youngs_modulus_GPa": (math.pi * r**2 * props["bond_youngs_modulus_GPa"],
                                           "analytic: C11 = E_b pi r_b^2 / a^2, C12 = 0 (periodic simple-cubic lattice)")}
        refs = {"youngs_modulus_specimen_GPa": (math.pi * r**2 * props["bond_youngs_modulus_GPa"],
                                                "analytic: E_b pi r_b^2 / a^2 (simple-cubic lattice)")}
        if self.compression.loading == "tension" and self.bonds.breakable:
            refs["strength_MPa"] = (math.pi * r**2 * props["bond_strength_MPa"],
                                    "analytic: sigma_b pi r_b^2 / a^2 (simple-cubic lattice in tension)")
        return refs

    def validate(self) -> None:
        super().validate()
        lat = self.lattice
        check(lat.arrangement in LATTICES, "lattice.arrangement", lat.arrangement,
              f"must be one of {', '.join(LATTICES)}")
        check(1e-3 <= lat.spacing_nm <= 1e5, "lattice.spacing_nm", lat.spacing_nm, "must be in [1e-3, 1e5] nm")
        if lat.periodic_z:
            check(self.compression.method == "static", "lattice.periodic_z", lat.periodic_z,
                  "needs compression.method = \"static\" (a sample periodic in z has no substrate to compress on)")
            check(self.boundary.sides == "periodic", "lattice.periodic_z", lat.periodic_z,
                  "needs boundary.sides = \"periodic\" (periodic in all three directions)")
        for axis in "xyz":
            n = getattr(lat, f"cells_{axis}")
            check(2 <= n <= 200, f"lattice.cells_{axis}", n, "must be in [2, 200]")
        self.boundary.validate()
