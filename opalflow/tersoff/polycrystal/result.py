"""What the polycrystal kinds find, typed: each experiment's result (:class:`TensionRun`, :class:`WaveRun`,
:class:`Measured`: a job's summary.json) and each kind's (:class:`TensionResult`, :class:`WavesResult`: the run's
summary.json, read back as the same class, the nested tables as their classes).

The references are seed 003's (Zhuravlev, Abgaryan, Reviznikov, Symmetry 13, 219 (2021), section 3): measured
polycrystalline silicon, E = 160 GPa, nu = 0.22, plate, rod and shear wave speeds 8 850, 8 290 and 5 280 m/s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from opalflow.runs.result import Result, key
from opalflow.tersoff.polycrystal.crystal import Crystal
from opalflow.tersoff.polycrystal.dynamics import Bounds, WaveSpeeds
from opalflow.version import __version__

#: seed 003, section 3: polycrystalline silicon (their ref. 30)
REFERENCE = {"youngs_modulus_GPa": 160.0, "poisson_ratio": 0.22, "wave_speed_plate_m_s": 8850.0,
             "wave_speed_rod_m_s": 8290.0, "wave_speed_shear_m_s": 5280.0}
SOURCE = ("Zhuravlev, Abgaryan, Reviznikov, Multiscale Discrete Element Modeling, Symmetry 13, 219 (2021), "
          "doi:10.3390/sym13020219, section 3")
TENSION, WAVES = "polycrystal_tension", "polycrystal_waves"


@dataclass
class Stats:
    """Mean, standard deviation (n - 1), extremes and count of one quantity over runs."""

    mean: float
    std: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, values) -> Stats:
        v = np.asarray(values, dtype=float)
        return cls(float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0, float(v.min()), float(v.max()), len(v))


@dataclass
class Realised:
    """E along x and nu of a finite set of orientations, by one of the two averages."""

    E_GPa: float
    nu: float


@dataclass
class TensionRun:
    """One tension experiment (a mesh and an orientation seed): its moduli, the bounds of the orientations it drew,
    the curve (columns in ``curve_columns``) and its cost."""

    cubes: int
    cube_nm: float
    seed: int
    elements: int
    edge_nm: float
    method: str
    timestep_ps: float
    damping_per_ps: float
    deform_steps: int
    macro_steps: int
    evaluations: int
    youngs_modulus_GPa: float
    poisson_ratio: float
    bounds_realised: dict[str, Realised]
    wall_s: float
    curve_columns: list[str]
    curve: list
    s_per_macro_step: float | None = None


@dataclass
class Measured(WaveSpeeds):
    """E and nu of the same potential by a static tension, and the wave speeds they imply."""

    youngs_modulus_GPa: float = 0.0
    poisson_ratio: float = 0.0
    elements: int = 0
    seed: int = 0
    wall_s: float = 0.0


@dataclass
class WaveFront:
    """One wave experiment's front: its speed (least squares over the stations used), the column and the piston,
    and what it took."""

    experiment: str
    elements: int
    cubes: list[int]
    cube_nm: float
    length_nm: float
    lateral: str
    piston_m_s: float
    timestep_ps: float
    macro_steps: int
    evaluations: int
    speed_m_s: float
    speed_stderr_m_s: float
    stations_used: int
    wall_s: float
    s_per_macro_step: float


@dataclass
class WaveRun(WaveFront):
    """One wave experiment as its job keeps it: the front and its curves (times, stations, arrival times, the
    section velocity profile)."""

    times_ps: list
    stations_nm: list
    arrival_ps: list
    profile: list


@dataclass
class RelaxationComparison:
    """Both steady states of eq. 8 (preconditioned Newton minimisation, damped MD) on ``elements`` elements strained
    by ``strain_rms`` in random directions: their cost and how far their stresses differ."""

    elements: int
    strain_rms: float
    minimize_evaluations: int
    minimize_s: float
    md_steps: int
    md_s: float
    max_stress_difference_GPa: float
    max_stress_GPa: float


@dataclass
class LammpsCheck:
    """The batched Tersoff (JAX) against LAMMPS ``pair_style tersoff`` on ``samples`` random samples (strain up to
    ``strain``, thermal displacements ``displacement_A``): the largest relative differences."""

    samples: int
    strain: float
    displacement_A: float
    max_relative_energy: float
    max_relative_forces: float
    max_relative_virial: float


@dataclass
class TensionExperiment:
    """One mesh of a tension run over its orientation seeds."""

    elements: int
    cubes: int
    cube_nm: float
    edge_nm: float
    youngs_modulus_GPa: Stats
    poisson_ratio: Stats
    wall_s: Stats
    s_per_macro_step: Stats | None
    inside_realised_bounds: bool


@dataclass
class WaveExperiment(WaveFront):
    """One wave of a waves run: its front (:class:`WaveRun` without the curves), and its errors against the
    reference and against the speeds of the measured moduli."""

    error_vs_reference: float
    error_vs_measured_moduli: float


@dataclass(eq=False)
class PolycrystalResult(Result):
    """What both polycrystal kinds give: the single crystal, its bounds, the check against LAMMPS."""

    bounds: Bounds = key(TENSION, WAVES)
    single_crystal: Crystal = key(TENSION, WAVES)
    density_kg_m3: float = key(TENSION, WAVES)
    lammps_check: LammpsCheck | None = key(TENSION, WAVES)
    reference: dict = key(TENSION, WAVES, default_factory=lambda: REFERENCE | {"source": SOURCE})
    potential: str = key(TENSION, WAVES, default="")
    opalflow_version: str = key(TENSION, WAVES, default=__version__)
    spec: dict | None = key(TENSION, WAVES)
    headline: str = key(TENSION, WAVES, default="")
    wall_s: float | None = key(TENSION, WAVES)


@dataclass(eq=False)
class TensionResult(PolycrystalResult):
    """Kind ``polycrystal_tension``: E and nu over every mesh and seed, each mesh's spread."""

    youngs_modulus_GPa: float = key(TENSION)
    poisson_ratio: float = key(TENSION)
    youngs_modulus: Stats = key(TENSION)
    poisson: Stats = key(TENSION)
    experiments: list[TensionExperiment] = key(TENSION, default_factory=list)
    error_vs_reference: dict = key(TENSION, default_factory=dict)
    inside_bounds: bool = key(TENSION)
    relaxation_comparison: RelaxationComparison = key(TENSION)
    method: str = key(TENSION, default="")

    @property
    def case(self) -> str:
        return TENSION


@dataclass(eq=False)
class WavesResult(PolycrystalResult):
    """Kind ``polycrystal_waves``: each wave's speed, and the moduli measured on the same potential."""

    measured_moduli: Measured = key(WAVES)
    experiments: dict[str, WaveExperiment] = key(WAVES, default_factory=dict)
    wave_speed_plate_m_s: float | None = key(WAVES, optional=True)
    wave_speed_rod_m_s: float | None = key(WAVES, optional=True)
    wave_speed_shear_m_s: float | None = key(WAVES, optional=True)

    @property
    def case(self) -> str:
        return WAVES
