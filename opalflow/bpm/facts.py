"""What a bonded-particle run knows of its sample and its deck, typed where it is written and where it is read.

:class:`SampleFacts` is written by every method as it starts (:func:`opalflow.bpm.pipeline.prepare` for the
dynamic deck, :func:`opalflow.bpm.static_run.network_run` for the solves, the periodic tensor's run) and kept in
run.json as the record's ``deck`` (its fields by name, flat: the file a user reads, and what ``--resume`` and
``analyze`` go on from); :meth:`SampleFacts.read` gives it back as the same type.  :class:`RunFacts` adds the
spec, rebuilt typed from the record (:func:`opalflow.registry.spec_from_dict`), and the references: what an
analysis and a report read, as attributes (``run.spec.bonds.breakable``, ``run.sample.height_nm``).

``facts_version`` counts changes of the fields' meaning; a record written before it existed reads as version 1.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from opalflow import registry
from opalflow.bpm.spec import BpmWorkflow
from opalflow.materials import Material
from opalflow.runs.result import optional, typed
from opalflow.spec import InputError
from opalflow.store import RECORD

FACTS_VERSION = 1


@dataclass
class BondType:
    """One bond type of the deck: a material's bonds in one length bin and their bpm/rotational coefficients
    (:func:`opalflow.materials.bond_coefficients`)."""

    material: str
    length_nm: float
    count: int
    kr_pN: float | None = None          # None: a record from before the coefficients were kept
    ks_pN: float | None = None
    kt_pN_nm: float | None = None
    kb_pN_nm: float | None = None
    fr_c_pN: float | None = None
    fs_c_pN: float | None = None


@dataclass
class SampleFacts:
    """A run's sample and deck: what its analysis and report need (None: the method has no such number)."""

    n_particles: int
    n_bonds: int
    type_names: list
    solid_fraction: float
    build_s: float
    periodic: list
    loading: str = "plate"
    loading_sense: int = 1                  # +1 compression, -1 tension
    height_nm: float | None = optional()          # strain = the driven particles' displacement / height_nm
    area_nm2: float | None = optional()           # stress = their force / area_nm2
    source: str = ""                        # the data file a datafile scene read
    method: str | None = optional()               # a solve's compression.method (the dynamic deck's record has none)
    # the structure as prepared for the dynamic deck
    mean_diameter_nm: float | None = optional()
    box_nm: list | None = optional()
    materials: dict[str, Material] = field(default_factory=dict)    # each particle material's properties
    statistics: dict | None = optional()                          # the scene's statistics (build's summary.json)
    structure: dict | None = optional()                           # those of them each run summary carries
    build_timings_s: dict | None = optional()
    # the dynamic deck (opalflow.bpm.deck.CompressionDeck)
    timestep_s: float | None = optional()
    steps: int | None = optional()
    output_every_steps: int | None = optional()
    restart_every_steps: int | None = optional()
    snapshot_steps: list | None = optional()
    plate_z0_nm: float | None = optional()
    plate_speed_m_s: float | None = optional()
    blocks: list | None = optional()
    modulus_affine_GPa: float | None = optional()
    omega1_per_ns: float | None = optional()
    viscous_gamma: float | None = optional()
    top_z0_nm: float | None = optional()
    timestep_estimate_s: dict | None = optional()
    bond_types: list[BondType] | None = optional()
    bond_stiffness_error_max: float | None = optional()
    bond_stiffness_error_rms: float | None = optional()
    # the solves (static, quasi-static, the periodic tensor)
    top_layer_particles: int | None = optional()
    structure_cache: str | None = optional()
    structure_first_build_s: float | None = optional()
    timings_s: dict | None = optional()
    volume_nm3: float | None = optional()
    facts_version: int = FACTS_VERSION

    @classmethod
    def from_dict(cls, raw: dict) -> SampleFacts:
        """The facts of a record's ``deck``; a key no field declares is refused (one line)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(raw) - names)
        if unknown:
            raise InputError(f"{RECORD}'s deck: unknown facts {', '.join(unknown)} (facts version "
                             f"{raw.get('facts_version', 1)}; this opalflow reads version {FACTS_VERSION})")
        return typed(cls, raw)

    @classmethod
    def read(cls, record) -> SampleFacts:
        """The facts a run record (:class:`opalflow.runs.record.RunRecord`) keeps."""
        return cls.from_dict(record.deck)

    @property
    def sides(self) -> str:
        """The side boundaries: periodic or open."""
        return "periodic" if self.periodic[0] else "open"


@dataclass
class RunFacts:
    """What an analysis or a report of a bonded-particle run reads: its spec (typed), its sample and deck, and
    the references its results are compared with."""

    spec: BpmWorkflow
    sample: SampleFacts
    references: dict = field(default_factory=dict)

    @classmethod
    def of(cls, record) -> RunFacts:
        """The facts of a run record: the spec rebuilt from it and validated, the deck's facts."""
        return cls(registry.spec_from_dict(record.spec), SampleFacts.read(record), record.references)

    @property
    def workflow(self) -> str:
        return self.spec.name
