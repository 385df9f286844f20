"""What the contact-only kinds find, typed: the plate scene on one or two engines (:class:`GranularResult`) and the
single impacts on both (:class:`ImpactsResult`), each read back from its summary.json as the same class."""
from __future__ import annotations

from dataclasses import dataclass, field

from opalflow.runs.result import Result, key

PLATE, IMPACTS = "granular", "granular_impacts"


@dataclass
class PlateScene:
    """The packing under the plate (SI): its spheres, those held at the bottom, the area and height the stress and
    strain are taken over, the plate's travel, and LAMMPS's tangential damping factor x_gamma,t (decks.py)."""

    n_particles: int
    n_floor: int
    area_m2: float
    height_m: float
    plate_travel_m: float
    x_gamma_t: float


@dataclass
class CrossCheck:
    """The plate forces of LAMMPS and LIGGGHTS row by row: the largest relative difference over the rows compared
    and the step where it first passes ``tolerance`` (None: they agree)."""

    max_relative_difference: float
    tolerance: float
    rows_compared: int
    agree: bool
    first_step_over_tolerance: int | None


@dataclass(eq=False)
class GranularResult(Result):
    """Kind ``granular``: the plate's force and stress at the end on each engine, and their cross-check."""

    workflow: str = key(PLATE, default="")
    engines: list[str] = key(PLATE, default_factory=list)
    n_particles: int = key(PLATE)
    n_floor: int = key(PLATE)
    area_m2: float = key(PLATE)
    height_m: float = key(PLATE)
    plate_travel_m: float = key(PLATE)
    x_gamma_t: float = key(PLATE)
    plate_force_N: dict[str, float] = key(PLATE, default_factory=dict)
    plate_stress_Pa: dict[str, float] = key(PLATE, default_factory=dict)
    final_strain: float = key(PLATE)
    engine_s: dict[str, float] = key(PLATE, default_factory=dict)
    cross_check: CrossCheck | None = key(PLATE, optional=True)
    headline: str = key(PLATE, default="")
    wall_s: float | None = key(PLATE)

    @property
    def case(self) -> str:
        return PLATE


@dataclass
class ImpactCase:
    """One impact on both engines: its time step and length, the projectile's last velocity and spin on each
    (``final``: engine -> vx, vz, omegay), the largest difference and the verdict against the tolerance, and why
    the codes part where they do; the head-on case also its restitution on each engine."""

    case: str
    timestep_s: float
    steps: int
    contact_time_s: float
    friction: float
    rotation: bool
    max_relative_difference: float
    verdict: str
    why: str
    first_step_over_tolerance: int | None
    final: dict[str, dict[str, float]] = field(default_factory=dict)
    restitution: dict[str, float] | None = None


@dataclass(eq=False)
class ImpactsResult(Result):
    """Kind ``granular_impacts``: each case's verdict and the head-on restitution against the one asked."""

    workflow: str = key(IMPACTS, default="")
    cases: list[ImpactCase] = key(IMPACTS, default_factory=list)
    tolerance: float = key(IMPACTS)
    restitution_asked: float = key(IMPACTS)
    restitution_measured: float = key(IMPACTS)
    restitution_error: float = key(IMPACTS)
    headline: str = key(IMPACTS, default="")
    wall_s: float | None = key(IMPACTS)

    @property
    def case(self) -> str:
        return IMPACTS
