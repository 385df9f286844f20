"""The result of a Tersoff workflow, every mode's (``properties``, ``stability``, ``fit``): one class for the keys
of summary.json (:class:`opalflow.runs.result.Result`).

The properties are those of Zhuravlev et al. Table 1 (seed 003): the lattice constant a0, the cohesive energy
E_c and the moduli B, C' = (C11 - C12) / 2, C11, C12, C44^0 (unrelaxed) and C44 (atoms relaxed), by central
second differences of the LAMMPS energy (eq. 16).
"""
from __future__ import annotations

from dataclasses import dataclass

from opalflow.runs.result import Result, key
from opalflow.tersoff.stability import BoundaryResult
from opalflow.version import __version__

PROPERTIES, STABILITY, FIT = "properties", "stability", "fit"
MEASURED = (PROPERTIES, FIT)                      # the properties measured by LAMMPS
ALL = (PROPERTIES, STABILITY, FIT)


@dataclass
class PropertyError:
    """One property against Table 1: its target (the fit's, absolute and relative error) and the authors' own
    evaluation of Table 2's set (the difference)."""

    value: float
    target: float
    error_vs_target: float
    relative_error_vs_target: float
    paper_calculated: float
    difference_vs_paper: float


@dataclass
class ScanRow:
    """One strain size of the central difference (eq. 16): each modulus's error against the exact (AD) second
    derivative (GPa), the largest, and the LAMMPS time it took (s)."""

    strain: float
    errors_GPa: dict[str, float]
    max_abs_error_GPa: float
    seconds: float


@dataclass
class StabilitySummary:
    """The MD stability check at one temperature: whether every boundary passed, and every run's figures."""

    passed: bool
    temperature_K: float
    runs: list[BoundaryResult]


@dataclass(eq=False)
class TersoffResult(Result):
    """What a Tersoff workflow found: the properties against Table 1, the MD stability, the fit."""

    mode: str = key(*ALL)
    a0_A: float = key(*MEASURED)
    Ec_eV: float = key(*MEASURED)
    B_GPa: float = key(*MEASURED)
    Cprime_GPa: float = key(*MEASURED)
    C11_GPa: float = key(*MEASURED)
    C12_GPa: float = key(*MEASURED)
    C44_0_GPa: float = key(*MEASURED)
    C44_GPa: float = key(*MEASURED)
    loss: float = key(*MEASURED)                  # eq. 13 of this set (fit model at a*, Table 1 targets)
    reference_loss: float = key(*MEASURED)        # eq. 13 of Table 2's set
    fit_s: float | None = key(*MEASURED)          # None: no fit
    stability: StabilitySummary | None = key(*ALL)    # the check at the first temperature (None: none run)
    # properties: the finite-difference strain and its scan against the exact derivatives
    strain: float = key(PROPERTIES)
    spread_GPa: dict = key(PROPERTIES)
    model: dict = key(PROPERTIES)
    strain_scan: list[ScanRow] = key(PROPERTIES)
    lammps_s: float = key(PROPERTIES)
    # fit: the parameters, the candidates checked for stability, each start of the multistart L-BFGS
    parameters: dict = key(FIT)
    at_bounds: list = key(FIT)
    candidates_checked: list = key(FIT)
    model_at_a0: dict = key(FIT)
    model_at_target: dict = key(FIT)
    starts: list = key(FIT)
    lammps_minus_model: dict = key(*MEASURED)
    reference: dict[str, PropertyError] = key(*MEASURED)   # each property against Table 1's two columns
    headline: str = key(*ALL, default="")
    wall_s: float | None = key(*ALL)
    opalflow_version: str = key(*ALL, default=__version__)
    spec: dict | None = key(*ALL)

    @property
    def case(self) -> str:
        return self.mode
