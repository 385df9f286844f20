"""Spec sections of the atomistic workflows (seed 003): ``[tersoff]`` and ``[stability]``."""
from __future__ import annotations

from dataclasses import dataclass, field

from opalflow.spec import WorkflowSpec, check, check_name, is_number


@dataclass
class TersoffSpec:
    """Tersoff potential: which file, how its properties are evaluated, and the fit (seed 003)."""

    potential: str = "Si_zhuravlev2021.tersoff"  # a Tersoff file: a path, or a file in data/potentials/ (Table 2)
    element: str = "Si"              # the file's entry "X X X" to use
    cells: int = 2                   # properties: the diamond crystal of cells^3 conventional cells (8 atoms each)
    strain: float = 1e-4             # properties: the finite-difference strain of the constants reported
    #: properties: the same constants at these strains too (the plateau where round-off and anharmonicity are small)
    strain_scan: list[float] = field(default_factory=lambda: [1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1])
    lattice_target_A: float = 5.431  # the lattice constant a* the fit's loss aims at (eq. 13)
    #: fit: property -> target, over Table 1's (data/reference/zhuravlev2021.toml)
    targets: dict = field(default_factory=dict)
    weights: dict = field(default_factory=dict)  # fit: property -> weight in the loss (1 unless set)
    #: fit: parameters kept at the starting file's values
    fixed: list[str] = field(default_factory=lambda: ["m", "R", "D"])
    bounds: dict = field(default_factory=dict)  # fit: parameter -> [low, high] of the search box (over the defaults)
    starts: int = 16                 # fit: L-BFGS-B runs from this many random points in the box
    seed: int = 1                    # fit: seed of the random starts
    max_iter: int = 5000             # fit: iterations of each L-BFGS-B run at most
    #: fit: the best this many are checked for MD stability; the first stable one is kept
    rank_top: int = 3


@dataclass
class StabilitySpec:
    """MD stability check of a Tersoff set: 4x4x4 cells, 0.01 ns, four boundary conditions."""

    #: x y z each p (periodic) or f (free surface)
    boundaries: list[str] = field(default_factory=lambda: ["ppp", "ppf", "pff", "fff"])
    temperatures_K: list[float] = field(default_factory=lambda: [300.0, 600.0])  # initial temperatures of the NVE runs
    time_ps: float = 10.0            # length of each MD run
    timestep_fs: float = 1.0         # its time step
    cells: int = 4                   # the crystal of cells^3 conventional cells (512 atoms at 4)
    seed: int = 12345                # seed of the initial velocities
    max_drift_eV: float = 1e-3       # stable only if the NVE total energy stays within this per atom of its start
    min_fourfold: float = 0.95       # ... and at least this fraction of interior atoms keeps 4 neighbours
    max_rms_A: float = 0.5           # ... and the interior's RMS displacement from the lattice stays below this
    workers: int = 0                 # runs at once, each in its own process (0: the cores)


@dataclass
class TersoffWorkflow(WorkflowSpec):
    """The atomistic workflows (kinds tersoff_properties, tersoff_fit, tersoff_stability)."""

    tersoff: TersoffSpec = field(default_factory=TersoffSpec)
    stability: StabilitySpec = field(default_factory=StabilitySpec)

    def validate(self) -> None:
        """The [tersoff] and [stability] sections; the potential file is read and checked."""
        super().validate()
        from opalflow.tersoff.fit import DEFAULT_BOUNDS, FIT_KEYS
        from opalflow.tersoff.parameters import COLUMNS, load_parameters

        t = self.tersoff
        check_name("tersoff.element", t.element)
        load_parameters(t.potential, t.element)   # file found, entry present, values allowed
        check(1 <= t.cells <= 10, "tersoff.cells", t.cells, "must be in [1, 10] (conventional cells per edge)")
        for i, e in enumerate([t.strain, *t.strain_scan]):
            where = "tersoff.strain" if i == 0 else f"tersoff.strain_scan[{i - 1}]"
            check(1e-7 <= e <= 0.2, where, e, "must be in [1e-7, 0.2]")
        check(4.0 <= t.lattice_target_A <= 7.0, "tersoff.lattice_target_A", t.lattice_target_A,
              "must be in [4, 7] A (diamond-structure lattice constant)")
        for key, value in t.targets.items():
            check(key in FIT_KEYS, f"tersoff.targets.{key}", value, f"unknown target; allowed: {', '.join(FIT_KEYS)}")
            check(is_number(value) and value != 0, f"tersoff.targets.{key}", value, "must be a non-zero number (errors are relative)")
        for key, value in t.weights.items():
            check(key in FIT_KEYS or key == "grad", f"tersoff.weights.{key}", value,
                  f"unknown weight; allowed: grad, {', '.join(FIT_KEYS)}")
            check(is_number(value) and value >= 0, f"tersoff.weights.{key}", value, "must be a number >= 0")
        for i, name in enumerate(t.fixed):
            check(name in COLUMNS, f"tersoff.fixed[{i}]", name, f"must be a parameter: {', '.join(COLUMNS)}")
        check("m" in t.fixed, "tersoff.fixed", t.fixed, "must hold 'm' (1 or 3, not a continuous parameter)")
        for key, value in t.bounds.items():
            check(key in COLUMNS and key not in t.fixed, f"tersoff.bounds.{key}", value,
                  f"must name a free parameter: {', '.join(k for k in COLUMNS if k not in t.fixed)}")
            check(isinstance(value, list) and len(value) == 2 and all(map(is_number, value))
              and value[0] < value[1], f"tersoff.bounds.{key}", value, "must be [low, high] with low < high")
        for name in COLUMNS:
            check(name in t.fixed or name in t.bounds or name in DEFAULT_BOUNDS, "tersoff.bounds", t.bounds,
                  f"free parameter '{name}' needs bounds [low, high]")
        check(1 <= t.starts <= 10000, "tersoff.starts", t.starts, "must be in [1, 10000]")
        check(t.seed >= 0, "tersoff.seed", t.seed, "must be >= 0")
        check(1 <= t.max_iter <= 100000, "tersoff.max_iter", t.max_iter, "must be in [1, 100000]")
        check(0 <= t.rank_top <= t.starts, "tersoff.rank_top", t.rank_top,
              f"must be in [0, starts = {t.starts}] (best candidates checked for stability; 0: none)")
        s = self.stability
        check(len(s.boundaries) >= 1, "stability.boundaries", s.boundaries, "must name at least one")
        for i, b in enumerate(s.boundaries):
            check(len(b) == 3 and set(b) <= {"p", "f"}, f"stability.boundaries[{i}]", b,
                  "must be three letters p (periodic) or f (free), x y z: e.g. ppp, ppf, pff, fff")
        check(len(s.temperatures_K) >= 1, "stability.temperatures_K", s.temperatures_K, "must hold at least one")
        for i, temp in enumerate(s.temperatures_K):
            check(0 < temp <= 5000, f"stability.temperatures_K[{i}]", temp, "must be in (0, 5000] K")
        check(0 < s.time_ps <= 1000, "stability.time_ps", s.time_ps, "must be in (0, 1000] ps")
        check(0.01 <= s.timestep_fs <= 5, "stability.timestep_fs", s.timestep_fs, "must be in [0.01, 5] fs")
        check(s.time_ps * 1000 / s.timestep_fs >= 10, "stability.time_ps", s.time_ps,
              "must be at least 10 time steps")
        check(2 <= s.cells <= 20, "stability.cells", s.cells, "must be in [2, 20]")
        check(s.seed > 0, "stability.seed", s.seed, "must be > 0 (LAMMPS velocity seed)")
        check(s.max_drift_eV > 0, "stability.max_drift_eV", s.max_drift_eV, "must be > 0")
        check(0 < s.min_fourfold <= 1, "stability.min_fourfold", s.min_fourfold, "must be in (0, 1]")
        check(s.max_rms_A > 0, "stability.max_rms_A", s.max_rms_A, "must be > 0")
        check(s.workers >= 0, "stability.workers", s.workers, "must be >= 0 (MD runs at once; 0: all cores)")
