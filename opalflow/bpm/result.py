"""The result of a bonded-particle run, every method's: one class renders summary.json, results.h5's attributes
and report.md's Results table.

A key is a field of :class:`CompressionResult` (:func:`opalflow.runs.result.key`); its cases are the methods
that give it (the dynamic LAMMPS run, the static solve, the quasi-static fracture, the periodic stiffness
tensor) and, where the report shows it, its label and format.  Adding a result key to every method is one field
here and the line that computes it.  Optional fields appear where the run has them (a rate check, the sessions
of a run opalflow drove).  The scene's statistics (porosity, density, ...) are added as they are.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from opalflow import registry
from opalflow.analysis.elasticity import IsotropicAverage
from opalflow.bpm.report import provenance_group, reference_errors, why
from opalflow.bpm.stiffness import EnergyParts
from opalflow.runs.record import Session
from opalflow.runs.result import Result, key
from opalflow.store import json_text
from opalflow.version import __version__

DYNAMIC, STATIC, QUASISTATIC, TENSOR = "dynamic", "static", "quasistatic", "tensor"
LOADED = (DYNAMIC, STATIC, QUASISTATIC)           # a loaded sample (not the periodic tensor)
BREAKING = (DYNAMIC, QUASISTATIC)                 # bonds that break: a strength
SOLVED = (STATIC, TENSOR)                         # one linear solve
EVERY_CASE = (*LOADED, TENSOR)
#: the strength's name by loading (bending: the flexural stress 3FL / (2bh^2) at the peak, ASTM D790)
STRENGTH = {"plate": "compressive", "glued": "compressive", "tension": "tensile", "bending": "flexural"}


@dataclass
class RateCheck:
    """The same dynamic run at half the plate speed (``compression.check_rate``): how much E and the strength
    change (relative; None: no strength), and the half-speed values."""

    youngs_modulus_change: float
    strength_change: float | None
    half_speed_youngs_modulus_GPa: float
    half_speed_strength_MPa: float | None


@dataclass
class EventFacts:
    """How a quasi-static run's events went (summary.json's ``quasistatic``): where they stopped, the re-solves,
    the local steps, the contacts, and what they cost."""

    events: int
    stopped: str
    resolver: str
    tolerance: float
    setup_s: float
    events_s: float
    factorizations: int
    cg_iterations: int
    local_rtol: float
    settled_locally: int
    loose_particles: int
    contacts: str
    contact_pairs: int
    contacts_pressing_at_peak: int
    contacts_pressing_at_end: int
    peak_memory_MiB: float
    #: the nonlinear method's states taken out of balance (:func:`opalflow.bpm.nonlinear.solve_nonlinear_fracture`)
    #: and the largest of their max |F| over the forces' scale
    out_of_balance_states: int = 0
    out_of_balance_max: float = 0.0


@dataclass(eq=False)
class CompressionResult(Result):
    """What a bonded-particle run found (compression, tension or bending; the periodic tensor), by method."""

    workflow: str = key(*LOADED, TENSOR)
    method: str = key(*LOADED, TENSOR)
    loading: str = key(*LOADED, TENSOR)
    youngs_modulus_GPa: float = key(*LOADED, TENSOR, label="Young's modulus (GPa)")
    youngs_modulus_specimen_GPa: float = key(*LOADED, label="Young's modulus, top-layer strain (GPa)")
    strength_MPa: float | None = key(*BREAKING, label="strength (MPa)")
    strain_at_peak: float | None = key(*BREAKING, label="strain at peak", fmt="{:.4f}")
    #: the work of the load per unit volume up to the peak, the area under the stress-strain curve (kJ/m^3)
    energy_to_peak_kJ_m3: float | None = key(*BREAKING, label="energy to the peak (kJ/m^3)", optional=True)
    strain_at_peak_specimen: float = key(DYNAMIC)                 # the top layer's (no plate settling)
    peak_stress_MPa: float | None = key(DYNAMIC, optional=True)   # the peak of a loading that breaks nothing
    broken_bonds: int = key(*BREAKING, label="broken bonds at the end", fmt="{}")
    broken_bonds_by_material: dict = key(QUASISTATIC)
    broken_bonds_at_peak: int = key(QUASISTATIC)
    broken_bonds_by_check: dict = key(QUASISTATIC)
    broken_bonds_by_check_at_peak: dict = key(QUASISTATIC)
    # the dynamic run: the elastic fit, the time steps and their cost
    elastic_window_strain: list = key(DYNAMIC)
    elastic_fit_r2: float = key(DYNAMIC)
    timestep_s: float = key(DYNAMIC)
    steps: int = key(DYNAMIC)
    steps_planned: int = key(DYNAMIC)
    lammps_s: float | None = key(DYNAMIC)
    wall_s: float | None = key(*LOADED, TENSOR, optional=True)   # finish() sets it (None: analyze only)
    bond_stiffness_error_max: float = key(DYNAMIC)
    timestep_estimate_s: dict = key(DYNAMIC)
    rate_check: RateCheck | None = key(DYNAMIC, optional=True)
    # the linear solves
    solver: str = key(*SOLVED)
    iterations: int | list = key(*SOLVED)
    relative_residual: float = key(*SOLVED)
    setup_s: float = key(STATIC)
    solve_s: float = key(STATIC)
    static_s: float = key(*SOLVED)
    peak_memory_MiB: float = key(*SOLVED)
    timings_s: dict = key(STATIC)                 # set-up, solve, analysis, files (the whole in wall_s)
    loose_particles_left_out: int = key(*SOLVED)
    energy_split: EnergyParts | None = key(STATIC)    # bonds' strain energy by mode (BondNetwork.energy_parts)
    bond_strain_per_strain: dict = key(STATIC)
    quasistatic: EventFacts = key(QUASISTATIC)   # the events: where they stopped, re-solves, contacts, cost
    # the periodic tensor (opalflow.analysis.elasticity)
    stiffness_tensor_GPa: list = key(TENSOR)
    voigt_order: str = key(TENSOR, default="xx yy zz yz xz xy")
    youngs_moduli_GPa: dict = key(TENSOR)
    poisson_ratio_zx: float = key(TENSOR)
    bulk_modulus_GPa: float = key(TENSOR)
    youngs_modulus_isotropic_GPa: float = key(TENSOR)
    poisson_ratio_isotropic: float = key(TENSOR)
    anisotropy_index: float = key(TENSOR)
    isotropic_average_GPa: IsotropicAverage = key(TENSOR)
    # the sample and the run
    n_particles: int = key(*LOADED, TENSOR)
    n_bonds: int = key(*LOADED, TENSOR)
    solid_fraction: float = key(*LOADED)
    stress_by_material: dict = key(DYNAMIC, STATIC)   # mean +- std of eq. 21 per material, by snapshot strain
    complete: bool = key(*LOADED, TENSOR, default=True)
    build_s: float = key(STATIC, QUASISTATIC, TENSOR)
    build_timings_s: dict | None = key(DYNAMIC, optional=True)
    sessions: list[Session] | None = key(DYNAMIC, optional=True)
    requeues: int | None = key(DYNAMIC, optional=True)
    opalflow_version: str = key(*LOADED, TENSOR, default=__version__)
    headline: str = key(*LOADED, TENSOR, default="")
    reference: dict = key(*LOADED, TENSOR)

    @property
    def case(self) -> str:
        """The method, or ``tensor`` for the static solve of a sample periodic in x, y and z."""
        return TENSOR if self.loading == "periodic" else self.method

    @classmethod
    def of(cls, kind: str, structure: dict, **keys) -> CompressionResult:
        """A run of ``kind``: its track's result class (:attr:`opalflow.registry.Kind.result`), the structure's
        numbers (``Scene.run_keys``) over the method's ``keys``; a structure's number that the class does not
        declare goes to ``extra`` (summary.json has it beside the declared keys)."""
        track = registry.get(kind).result_class()
        track = track if issubclass(track, cls) else cls
        names = {f.name for f in dataclasses.fields(track)}
        keys["extra"] = {**{k: v for k, v in structure.items() if k not in names}, **keys.get("extra", {})}
        return track(**{**keys, **{k: v for k, v in structure.items() if k in names}})

    @classmethod
    def structure_keys(cls) -> tuple[str, ...]:
        """The structure's numbers a track's class declares (its scene's ``run_keys``)."""
        return tuple(cls.__annotations__)

    def refer(self, references: dict) -> CompressionResult:
        """Each reference value ({key: (value, source)}) with its source and this result's error against it."""
        self.reference = reference_errors(self.summary(), references)
        return self

    def h5_attrs(self, h, run) -> None:
        """results.h5's file attributes (method, modulus, the summary as JSON) and its provenance group (the
        run's facts, :class:`opalflow.bpm.facts.RunFacts`)."""
        h.attrs["method"] = self.method
        h.attrs["youngs_modulus_GPa"] = self.youngs_modulus_GPa
        h.attrs["summary"] = json_text(self.summary())
        provenance_group(h, run)

    def results_table(self, diameter_nm: float) -> list[str]:
        """report.md's Results table: each labelled key of this method with its reference, error and, where
        the error is large and its reason known, why (:func:`opalflow.bpm.report.why`)."""
        lines = ["| quantity | value | reference | error | why the error |", "|---|---|---|---|---|"]
        for f in dataclasses.fields(self):
            name, label = f.name, f.metadata.get("label")
            if not label or name not in self.case_keys():
                continue
            if name == "youngs_modulus_specimen_GPa" and self.method != DYNAMIC:
                continue                  # a solve strains the top layer as the plate: one modulus
            value = getattr(self, name)
            if name == "strength_MPa":
                label = f"{STRENGTH.get(self.loading, '')} {label}".lstrip()
                if value is None:
                    lines.append(f"| {label} | none: bonds unbreakable (peak stress {self.peak_stress_MPa:.4g} MPa "
                                 "at the end of loading) | - | - | - |")
                    continue
            if name == "strain_at_peak" and self.strength_MPa is None:
                continue
            if name == "youngs_modulus_GPa" and self.method == DYNAMIC:
                label = "Young's modulus, plate strain (GPa)"
            if (name == "youngs_modulus_GPa" and self.method != DYNAMIC
                    and "youngs_modulus_specimen_GPa" in self.reference):    # no plate: the top layer's reference
                name = "youngs_modulus_specimen_GPa"
            ref = self.reference.get(name)
            solved = self.method != DYNAMIC and name.startswith("youngs_modulus")       # no Hertz settling
            reason = why("youngs_modulus_specimen_GPa" if solved else name, ref["error"], diameter_nm) if ref else ""
            lines.append(f"| {label} | {f.metadata['fmt'].format(value)} | "
                         + (f"{ref['value']:g} ({ref['source']}) | {100 * ref['error']:+.2f} % | {reason or '-'} |"
                            if ref else "- | - | - |"))
        return lines
