"""Specs of the contact-only kinds: "granular" (a packing compressed by a plate) and "granular_impacts"."""
from __future__ import annotations

from dataclasses import dataclass, field

from opalflow.spec import WorkflowSpec, check

ENGINES = ("lammps", "liggghts", "both")


@dataclass
class GranularPackingSpec:
    """Dense random packing (opalflow.packing) in a box periodic in x and y; the bottom layer is held."""

    box_diameters: float = 6.0          # box edge in mean diameters (x, y and the height)
    diameter_m: float = 1e-3            # mean particle diameter
    diameter_std: float = 0.1           # relative
    solid_fraction: float = 0.6         # volume fraction of the packing
    seed: int = 3                       # random seed of the packing


@dataclass
class GranularMaterialSpec:
    """Hertz-Mindlin contact properties of the particles (the plate has the same)."""

    youngs_modulus_Pa: float = 5e7      # Young's modulus of the particles (Hertz)
    poisson_ratio: float = 0.25         # their Poisson's ratio (Hertz, Mindlin)
    restitution: float = 0.5            # coefficient of restitution of a contact (its damping)
    friction: float = 0.5               # Coulomb friction coefficient
    density_kg_m3: float = 2500.0       # particle density


@dataclass
class GranularPlateSpec:
    """The plate: a flat wall moving down onto the packing at constant speed."""

    speed_m_s: float = 0.01             # its speed
    steps: int = 20000                  # time steps run
    timestep_s: float = 2e-6            # the time step (both engines)
    output_every: int = 200             # a point of the force curve every this many steps


@dataclass
class GranularWorkflow(WorkflowSpec):
    """An unbonded packing compressed by a plate; ``engine``: lammps, liggghts or both (a cross-check)."""

    engine: str = "lammps"              # lammps, liggghts, or both (the same deck on each, compared)
    #: the spheres rotate (fix nve/sphere); false: translations only (fix nve), where the tangential
    #: contact model of LAMMPS and LIGGGHTS is the same (opalflow/granular/decks.py)
    rotation: bool = True
    packing: GranularPackingSpec = field(default_factory=GranularPackingSpec)
    material: GranularMaterialSpec = field(default_factory=GranularMaterialSpec)
    plate: GranularPlateSpec = field(default_factory=GranularPlateSpec)

    def validate(self) -> None:
        super().validate()
        check(self.engine in ENGINES, "engine", self.engine, f"must be one of {', '.join(ENGINES)}")
        k, m, p = self.packing, self.material, self.plate
        check(3 <= k.box_diameters <= 40, "packing.box_diameters", k.box_diameters, "must be in [3, 40]")
        check(1e-7 <= k.diameter_m <= 1.0, "packing.diameter_m", k.diameter_m, "must be in [1e-7, 1] m")
        check(0 <= k.diameter_std <= 0.3, "packing.diameter_std", k.diameter_std, "must be in [0, 0.3] (relative)")
        check(0.05 <= k.solid_fraction <= 0.64, "packing.solid_fraction", k.solid_fraction, "must be in [0.05, 0.64]")
        check(k.seed >= 0, "packing.seed", k.seed, "must be >= 0")
        _check_material(m)
        check(0 < p.speed_m_s <= 10, "plate.speed_m_s", p.speed_m_s, "must be in (0, 10] m/s")
        check(100 <= p.steps <= 10**8, "plate.steps", p.steps, "must be in [100, 1e8]")
        check(0 < p.timestep_s <= 1e-3, "plate.timestep_s", p.timestep_s, "must be in (0, 1e-3] s")
        check(1 <= p.output_every <= p.steps, "plate.output_every", p.output_every, "must be in [1, plate.steps]")


@dataclass
class ImpactSpec:
    """One sphere thrown at a held sphere of the same size (Chung and Ooi's single-impact benchmarks)."""

    diameter_m: float = 1e-3            # both spheres' diameter
    speed_m_s: float = 0.1              # the thrown sphere's speed
    angle_deg: float = 30.0             # between the velocity and the line of centres at contact (oblique cases)
    steps_per_contact: int = 200        # time step = Hertz contact time / this


@dataclass
class ImpactsWorkflow(WorkflowSpec):
    """Single impacts run on LAMMPS and LIGGGHTS: where the two contact laws agree and where they part."""

    impact: ImpactSpec = field(default_factory=ImpactSpec)
    material: GranularMaterialSpec = field(default_factory=GranularMaterialSpec)

    def validate(self) -> None:
        super().validate()
        i, m = self.impact, self.material
        check(1e-7 <= i.diameter_m <= 1.0, "impact.diameter_m", i.diameter_m, "must be in [1e-7, 1] m")
        check(0 < i.speed_m_s <= 100, "impact.speed_m_s", i.speed_m_s, "must be in (0, 100] m/s")
        check(1 <= i.angle_deg <= 80, "impact.angle_deg", i.angle_deg, "must be in [1, 80] degrees")
        check(20 <= i.steps_per_contact <= 10**5, "impact.steps_per_contact", i.steps_per_contact,
              "must be in [20, 1e5]")
        _check_material(m)


def _check_material(m: GranularMaterialSpec) -> None:
    check(1e3 <= m.youngs_modulus_Pa <= 1e12, "material.youngs_modulus_Pa", m.youngs_modulus_Pa,
          "must be in [1e3, 1e12] Pa")
    check(-0.99 < m.poisson_ratio < 0.5, "material.poisson_ratio", m.poisson_ratio, "must be in (-0.99, 0.5)")
    check(0 < m.restitution <= 1, "material.restitution", m.restitution, "must be in (0, 1]")
    check(0 <= m.friction <= 1e6, "material.friction", m.friction, "must be in [0, 1e6] (0: frictionless)")
    check(1 <= m.density_kg_m3 <= 1e5, "material.density_kg_m3", m.density_kg_m3, "must be in [1, 1e5]")
