"""Spec of the polycrystal workflows (kinds ``polycrystal_tension`` and ``polycrystal_waves``, seed 003).

Sections: ``[tersoff]`` (the potential; any ``.tersoff`` file), ``[samples]`` (the atomic
samples: orientation seeds, relaxation), ``[tension]`` and ``[waves]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from opalflow.spec import WorkflowSpec, check
from opalflow.tersoff.spec import TersoffSpec

SAMPLE_RELAXATIONS = ("minimize", "md")
WAVES = ("plate", "rod", "shear")
TENSION_METHODS = ("dynamic", "static")


@dataclass
class SamplesSpec:
    """The 64-atom samples: one uniformly random orientation per element from each seed."""

    #: each experiment once per seed of the elements' random orientations
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    relaxation: str = "minimize"          # minimize: preconditioned Newton; md: damped MD (eq. 8)
    force_tol_eV_A: float = 1e-4          # steady state: largest atomic force below this
    lammps_check: int = 4                 # samples compared with LAMMPS pair_style tersoff (0: none)


@dataclass
class TensionSpec:
    """Uniaxial tension, periodic along x, free sides (seed 003, section 3, Figs. 3-4)."""

    cubes: list[int] = field(default_factory=lambda: [4, 4, 8])         # cubes per edge of each experiment
    #: cube edge of each experiment (six tetrahedra a cube)
    cube_nm: list[float] = field(default_factory=lambda: [5.0, 10.0, 10.0])
    method: str = "dynamic"               # dynamic: deformation + damped relaxation steps; static: Newton
    max_strain: float = 0.0015            # the tension stops at this strain
    strain_step: float = 0.0005           # strain of each deformation phase (one curve point)
    strain_rate_per_ns: float = 0.05      # during the deformation steps
    residual_tol: float = 1e-4            # relaxation ends at |net vertex forces| / |element forces| below this
    damping: float = 1.0                  # viscous damping, in units of pi c_L / (longest edge)
    timestep_safety: float = 0.5          # dt = safety x 2 / omega_max
    max_relax_steps: int = 5000           # a relaxation taking more steps than this stops the run with an error


@dataclass
class WavesSpec:
    """Waves from a piston on the end face z = 0 of a column (seed 003, Figs. 5-7)."""

    #: plate (periodic sides), rod (free sides), shear (transverse piston)
    experiments: list[str] = field(default_factory=lambda: ["plate", "rod", "shear"])
    cubes: list[int] = field(default_factory=lambda: [4, 4, 40])          # 3840 elements
    cube_nm: float = 5.0                  # cube edge (six tetrahedra a cube)
    piston_m_s: float = 10.0              # the end face's prescribed velocity
    timestep_safety: float = 0.5          # dt = safety x 2 / omega_max
    travel: float = 0.9                   # run until a wave at the Voigt speed has crossed this fraction
    fit_range: list[float] = field(default_factory=lambda: [0.2, 0.8])   # stations used in the speed fit
    seed: int = 1                         # seed of the elements' random orientations


@dataclass
class PolycrystalWorkflow(WorkflowSpec):
    """What both polycrystal kinds read: the potential and the samples."""

    tersoff: TersoffSpec = field(default_factory=TersoffSpec)
    samples: SamplesSpec = field(default_factory=SamplesSpec)

    def validate(self) -> None:
        super().validate()
        from opalflow.spec import check_name
        s = self.samples
        check_name("tersoff.element", self.tersoff.element)
        check(1 <= len(s.seeds) <= 100, "samples.seeds", s.seeds, "must hold 1 to 100 seeds")
        for i, seed in enumerate(s.seeds):
            check(isinstance(seed, int) and seed >= 0, f"samples.seeds[{i}]", seed, "must be an integer >= 0")
        check(s.relaxation in SAMPLE_RELAXATIONS, "samples.relaxation", s.relaxation, f"must be one of {', '.join(SAMPLE_RELAXATIONS)}")
        check(1e-8 <= s.force_tol_eV_A <= 1e-2, "samples.force_tol_eV_A", s.force_tol_eV_A, "must be in [1e-8, 1e-2] eV/A")
        check(0 <= s.lammps_check <= 100, "samples.lammps_check", s.lammps_check, "must be in [0, 100]")

    def crystal(self):
        """The potential's single crystal (SpecError if the file fails its stability check)."""
        from opalflow.tersoff.parameters import load_parameters
        from opalflow.tersoff.polycrystal.crystal import single_crystal
        return single_crystal(load_parameters(self.tersoff.potential, self.tersoff.element), self.tersoff.potential)


@dataclass
class TensionWorkflow(PolycrystalWorkflow):
    """Kind polycrystal_tension: E and Poisson's ratio."""

    tension: TensionSpec = field(default_factory=TensionSpec)

    def validate(self) -> None:
        super().validate()
        t = self.tension
        check(1 <= len(t.cubes) <= 20, "tension.cubes", t.cubes, "must hold 1 to 20 experiments")
        check(len(t.cube_nm) == len(t.cubes), "tension.cube_nm", t.cube_nm,
              f"must hold one edge per experiment ({len(t.cubes)}, as tension.cubes)")
        for i, n in enumerate(t.cubes):
            check(isinstance(n, int) and 2 <= n <= 40, f"tension.cubes[{i}]", n,
                  "must be an integer element count per edge in [2, 40] (6 n^3 tetrahedra; non-positive counts "
                  "make no mesh)")
        for i, h in enumerate(t.cube_nm):
            check(1.0 <= h <= 1e6, f"tension.cube_nm[{i}]", h, "must be in [1, 1e6] nm (an element holds a "
                  "1.1 nm sample)")
        check(t.method in TENSION_METHODS, "tension.method", t.method, f"must be one of {', '.join(TENSION_METHODS)}")
        check(0 < t.max_strain <= 0.02, "tension.max_strain", t.max_strain, "must be in (0, 0.02] (elastic range)")
        check(0 < t.strain_step <= t.max_strain, "tension.strain_step", t.strain_step,
              f"must be in (0, max_strain = {t.max_strain:g}]")
        check(t.max_strain / t.strain_step <= 200, "tension.strain_step", t.strain_step,
              "must give at most 200 curve points up to max_strain")
        check(t.strain_rate_per_ns > 0, "tension.strain_rate_per_ns", t.strain_rate_per_ns, "must be > 0")
        check(1e-8 <= t.residual_tol <= 1e-1, "tension.residual_tol", t.residual_tol, "must be in [1e-8, 0.1]")
        check(0 < t.damping <= 100, "tension.damping", t.damping, "must be in (0, 100]")
        check(0 < t.timestep_safety <= 0.9, "tension.timestep_safety", t.timestep_safety, "must be in (0, 0.9]")
        check(1 <= t.max_relax_steps <= 1_000_000, "tension.max_relax_steps", t.max_relax_steps, "must be in [1, 1e6]")
        from opalflow.tersoff.polycrystal.crystal import quasi_static_rate
        limit = quasi_static_rate(self.crystal(), t.strain_step, max(n * h for n, h in zip(t.cubes, t.cube_nm)))
        check(t.strain_rate_per_ns <= limit, "tension.strain_rate_per_ns", t.strain_rate_per_ns,
              f"must be <= {limit:.4g} per ns for quasi-static loading (each strain step of {t.strain_step:g} "
              f"takes at least the time a longitudinal wave needs to cross the largest sample)")


@dataclass
class WavesWorkflow(PolycrystalWorkflow):
    """Kind polycrystal_waves: plate, rod and shear wave speeds."""

    waves: WavesSpec = field(default_factory=WavesSpec)

    def validate(self) -> None:
        super().validate()
        w = self.waves
        check(1 <= len(w.experiments) <= 3 and len(set(w.experiments)) == len(w.experiments),
              "waves.experiments", w.experiments, f"must name 1 to 3 of {', '.join(WAVES)}, each once")
        for i, name in enumerate(w.experiments):
            check(name in WAVES, f"waves.experiments[{i}]", name, f"must be one of {', '.join(WAVES)}")
        check(len(w.cubes) == 3, "waves.cubes", w.cubes, "must be [nx, ny, nz] (the wave runs along z)")
        for i, n in enumerate(w.cubes):
            check(isinstance(n, int) and 1 <= n <= 400, f"waves.cubes[{i}]", n,
                  "must be an integer element count in [1, 400] (non-positive counts make no mesh)")
        check(w.cubes[2] >= 10, "waves.cubes[2]", w.cubes[2], "must be >= 10 (stations along the wave)")
        check(1.0 <= w.cube_nm <= 1e6, "waves.cube_nm", w.cube_nm, "must be in [1, 1e6] nm")
        check(0 < w.piston_m_s <= 100, "waves.piston_m_s", w.piston_m_s,
              "must be in (0, 100] m/s (strain v/c stays below 1 %)")
        check(0 < w.timestep_safety <= 0.9, "waves.timestep_safety", w.timestep_safety, "must be in (0, 0.9]")
        check(0.3 <= w.travel <= 1.0, "waves.travel", w.travel, "must be in [0.3, 1]")
        check(len(w.fit_range) == 2 and 0 <= w.fit_range[0] < w.fit_range[1] <= w.travel, "waves.fit_range",
              w.fit_range, f"must be [low, high] with 0 <= low < high <= travel = {w.travel:g}")
        check(isinstance(w.seed, int) and w.seed >= 0, "waves.seed", w.seed, "must be an integer >= 0")
        self.crystal()
