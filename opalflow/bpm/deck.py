"""Decks: LAMMPS input scripts assembled from the blocks in ``templates/``.

A block is a text file with ``${name}`` placeholders.  Every value is passed through
:func:`opalflow.lammps.syntax.num` or :func:`~opalflow.lammps.syntax.name` (or is a
fixed keyword chosen here), so nothing unchecked reaches LAMMPS.  A deck holds only
the blocks its scene needs: no granular pair without contacts, no snapshot computes
without snapshots, ``break no`` for unbreakable bonds, bond and atom types only for
the materials present.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from opalflow.bpm.bonds import BOND_MODELS
from opalflow.bpm.loading import CONTACT_LAWS, LOADINGS
from opalflow.bpm.methods import METHODS
from opalflow.bpm.spec import BpmWorkflow
from opalflow.bpm.timestep import TimestepEstimate, estimate_timestep
from opalflow.lammps.syntax import name, num, render
from opalflow.materials import BondCoefficients, ContactProperties, bond_coefficients, contact_properties
from opalflow.spec import SpecError
from opalflow.structure import Structure
from opalflow.version import __version__

DIAMOND = "diamond"
#: the bonds of each particle at the start, for the broken-bond count of the snapshots (a run 0 makes
#: compute nbond/atom current; the bond reference states it sets are those of the first step anyway)
COUNT_BONDS = """variable        bonds_now atom c_bonds_per_atom
run             0 post no
set             group all i_bonds0 v_bonds_now"""
#: more steps than this is a time step far too small for the scene, not a run to start
MAX_STEPS = 10**10


@dataclass
class BondBins:
    """Bond types binned by material and initial length (kt, kb scale with 1/L0)."""

    bond_types: np.ndarray                 # (M,) new type per bond, 1-based
    materials: list[str]                   # per new type
    lengths: list[float]                   # representative L0 per new type (harmonic mean)
    counts: list[int]
    stiffness_error_max: float             # max |kb(L_rep)/kb(L0) - 1| over bonds
    stiffness_error_rms: float


def bin_bonds(s: Structure, n_bins: int, r0: np.ndarray | None = None) -> BondBins:
    """Split each material's bonds into ``n_bins`` equal-width bins of initial length.

    Each bin's representative length is the harmonic mean of its bonds' lengths, so
    the bin's summed bending and twisting stiffness (proportional to 1/L0) is exact;
    each bond's own kb, kt are off by L0 / L_rep - 1, reported as the stiffness error.
    kr and ks use every bond's own r0 (``normalize yes``) and carry no binning error.
    """
    r0 = s.bond_lengths() if r0 is None else r0
    new = np.zeros(s.n_bonds, np.int32)
    materials, lengths, counts, errors = [], [], [], np.zeros(s.n_bonds)
    for t, mat in enumerate(s.bond_type_names):
        sel = np.flatnonzero(s.bond_types == t + 1)
        if not len(sel):
            continue
        lo, hi = r0[sel].min(), r0[sel].max()
        edges = np.linspace(lo, hi, n_bins + 1)
        which = np.clip(np.searchsorted(edges, r0[sel], side="right") - 1, 0, n_bins - 1)
        for b in range(n_bins):
            members = sel[which == b]
            if not len(members):
                continue
            rep = 1.0 / np.mean(1.0 / r0[members])
            materials.append(mat)
            lengths.append(float(rep))
            counts.append(int(len(members)))
            new[members] = len(materials)
            errors[members] = r0[members] / rep - 1.0
    return BondBins(new, materials, lengths, counts, float(np.max(np.abs(errors), initial=0.0)),
                    float(np.sqrt(np.mean(errors**2))) if len(errors) else 0.0)


def particle_material(type_name: str, matrix: str) -> str:
    return matrix if type_name == "substrate" else type_name


def plate_contact_E(particle: ContactProperties, plate: ContactProperties) -> float:
    """Young's modulus to give ``fix wall/gran`` so that its contact E* is particle-on-diamond.

    LAMMPS gives the wall the particle's properties: E* = E / (2 (1 - nu^2)).  The
    wanted E* is 1 / ((1 - nu_p^2)/E_p + (1 - nu_d^2)/E_d) (Hertz, eq. 5).
    """
    e_star = 1.0 / ((1 - particle.poisson_ratio**2) / particle.youngs_modulus_MPa
                    + (1 - plate.poisson_ratio**2) / plate.youngs_modulus_MPa)
    return 2.0 * (1.0 - particle.poisson_ratio**2) * e_star


@dataclass
class LoadedSample:
    """The sample of a compression or tension as every method sees it (the dynamic deck, the static and
    quasi-static solves): its bonded structure, the loaded height, cross-section and top layer."""

    structure: Structure                    # with length-binned bond types
    source: Structure                       # as built, bonds typed by material
    bins: BondBins
    coefficients: list[BondCoefficients]
    bond_lengths: np.ndarray                # r0 of each bond (nm)
    height_nm: float                        # strain = the driven particles' displacement / height_nm
    area_nm2: float                         # stress = their force / area_nm2 (uniaxial: the cross-section)
    base_nm: float                          # the substrate's top
    plate_z0_nm: float                      # the sample's top
    top_z0_nm: float                        # the driven particles' mean centre height
    top_layer: np.ndarray                   # the driven particles (LAMMPS group "top")
    marks: dict                             # what else the loading placed (bending: span, supports, nose)
    loading: str                            # compression.loading (opalflow.bpm.loading.LOADINGS)
    loading_sense: int                      # +1: compression, -1: tension (strain and stress positive in it)


@dataclass
class CompressionDeck(LoadedSample):
    """Everything a dynamic compression run needs: the loaded sample, the decks and the numbers behind them."""

    in_lmp: str = ""
    resume_lmp: str = ""
    timestep: TimestepEstimate | None = None
    dt_ns: float = 0.0
    steps: int = 0
    every: int = 0
    restart_every: int = 0
    snapshot_steps: list[int] = field(default_factory=list)
    plate_speed_nm_ns: float = 0.0
    blocks: list[str] = field(default_factory=list)
    modulus_affine_MPa: float = 0.0
    omega1_per_ns: float = 0.0
    viscous_gamma: float = 0.0
    initial_ke_zJ: float = 0.0              # kinetic energy given at the start (glued: affine field, top layer)

    def info(self) -> dict:
        return {
            "timestep_s": self.dt_ns * 1e-9, "steps": self.steps, "output_every_steps": self.every,
            "restart_every_steps": self.restart_every, "snapshot_steps": self.snapshot_steps,
            "height_nm": self.height_nm, "area_nm2": self.area_nm2, "plate_z0_nm": self.plate_z0_nm,
            "plate_speed_m_s": self.plate_speed_nm_ns, "blocks": self.blocks,
            "modulus_affine_GPa": self.modulus_affine_MPa / 1e3, "omega1_per_ns": self.omega1_per_ns,
            "viscous_gamma": self.viscous_gamma, "top_z0_nm": self.top_z0_nm,
            "loading": self.loading, "loading_sense": self.loading_sense,
            "timestep_estimate_s": self.timestep.as_seconds(),
            "bond_types": [{"material": m, "length_nm": L, "count": c, "kr_pN": cf.kr, "ks_pN": cf.ks,
                            "kt_pN_nm": cf.kt, "kb_pN_nm": cf.kb, "fr_c_pN": cf.fr_c, "fs_c_pN": cf.fs_c}
                           for m, L, c, cf in zip(self.bins.materials, self.bins.lengths, self.bins.counts,
                                                  self.coefficients)],
            "bond_stiffness_error_max": self.bins.stiffness_error_max,
            "bond_stiffness_error_rms": self.bins.stiffness_error_rms,
        }


def bond_model(spec: BpmWorkflow, s: Structure, r0: np.ndarray | None = None
               ) -> tuple[Structure, BondBins, list[BondCoefficients]]:
    """``s`` with its bonds typed by material and length bin, the bins, and each type's bpm/rotational
    coefficients (the materials' bond E and strength at the mean particle radius and mass of the type)."""
    r0 = s.bond_lengths() if r0 is None else r0
    bins = bin_bonds(s, spec.bonds.length_bins, r0)
    data = Structure(positions=s.positions, diameters=s.diameters, types=s.types, densities=s.densities,
                     box_lo=s.box_lo, box_hi=s.box_hi, periodic=s.periodic, bonds=s.bonds,
                     bond_types=bins.bond_types, molecules=s.molecules, type_names=s.type_names,
                     bond_type_names=[f"{m}_{i + 1}" for i, m in enumerate(bins.materials)],
                     groups=s.groups, meta=s.meta)
    masses = s.densities * np.pi / 6 * s.diameters**3
    coeffs = []
    for mat, L in zip(bins.materials, bins.lengths):
        on = np.isin(s.types, [k + 1 for k, n in enumerate(s.type_names)
                               if particle_material(n, spec.material) == mat])
        m = float(np.mean(masses[on]))
        r = float(np.mean(s.diameters[on])) / 2
        coeffs.append(bond_coefficients(mat, spec.bonds.radius_factor * r, L, m, 0.4 * m * r * r,
                                        spec.bonds.damping_ratio, spec.materials,
                                        moments=BOND_MODELS[spec.bonds.model].moments))
    return data, bins, coeffs


def loaded_sample(spec: BpmWorkflow, s: Structure) -> LoadedSample:
    """``s`` as the loading of ``spec`` holds it (:class:`LoadedSample`, its geometry from
    :meth:`opalflow.bpm.loading.Loading.place`): the static and quasi-static solves need this and no deck."""
    loading = LOADINGS[spec.compression.loading]
    place = loading.place(s, float(np.mean(s.diameters)))      # refuses a sample the loading cannot hold
    r0 = s.bond_lengths()
    data, bins, coeffs = bond_model(spec, s, r0)
    return LoadedSample(structure=data, source=s, bins=bins, coefficients=coeffs, bond_lengths=r0, **vars(place),
                        loading=loading.name, loading_sense=loading.sense)


def particle_contacts(spec: BpmWorkflow, s: Structure):
    """(law, contact properties per atom type, the plate's contact E per type): the contact law of
    ``contacts.model`` prepared for each type's material and mean radius, friction and restitution as given."""
    d_mean = float(np.mean(s.diameters))
    given = {k: v for k, v in (("friction", spec.contacts.friction), ("restitution", spec.contacts.restitution))
             if v is not None}
    law = CONTACT_LAWS[spec.contacts.model]
    contacts = {}
    for k, n in enumerate(s.type_names):
        props = dataclasses.replace(contact_properties(particle_material(n, spec.material)), **given)
        on = s.types == k + 1
        contacts[k + 1] = law.prepare(props, 0.5 * float(np.mean(s.diameters[on])) if np.any(on) else 0.5 * d_mean)
    plate = contact_properties(DIAMOND)
    return law, contacts, {t: plate_contact_E(cp, plate) for t, cp in contacts.items()}


def time_step(spec: BpmWorkflow, sample: LoadedSample, contacts: dict, plate_E: dict) -> tuple[TimestepEstimate, float]:
    """The stability estimate (:func:`opalflow.bpm.timestep.estimate_timestep`) and the time step (ns): the
    one given, refused above the limit, or ``timestep_safety`` of the limit."""
    c = spec.compression
    estimate = estimate_timestep(sample.structure, sample.coefficients, contacts if spec.contacts.enabled else {},
                                 plate_E, contacts, sample.bond_lengths,
                                 spectral=not METHODS[spec.compression.method].linear)
    limit_ns = estimate.limit_ns
    if not c.timestep_s:
        return estimate, c.timestep_safety * limit_ns
    dt = c.timestep_s * 1e9
    if dt > limit_ns:
        raise SpecError("compression.timestep_s", c.timestep_s,
                        f"above the stability limit {limit_ns * 1e-9:.3g} s estimated from the "
                        f"stiffest mode ({estimate.stiffest}); use <= that or 0 for the estimate")
    return estimate, dt


def schedule(spec: BpmWorkflow, height: float, dt: float) -> tuple[int, int, int, list[int]]:
    """(steps, output interval, restart interval, snapshot steps) of a run at the plate speed to
    ``strain_max`` over the loading's length ``height``."""
    c = spec.compression
    steps_per_strain = height / c.plate_speed_m_s / dt           # m/s = nm/ns
    steps = int(math.ceil(c.strain_max * steps_per_strain))
    if steps > MAX_STEPS:
        raise SpecError("compression.timestep_s", c.timestep_s,
                        f"gives {steps:.3g} steps to strain {c.strain_max:g} (at most {MAX_STEPS:.0e}); "
                        "use 0 for the estimated time step")
    every = max(1, int(round(c.output_every_strain * steps_per_strain)))
    # restart files at whole output intervals: a run resumed from one writes its first averaged
    # curve row one interval later, so no row is lost or written twice
    restart_every = every * max(1, int(round(c.restart_every_strain * steps_per_strain / every)))
    return steps, every, restart_every, sorted({max(1, int(round(e * steps_per_strain))) for e in c.snapshot_strains})


def damping(spec: BpmWorkflow, sample: LoadedSample) -> tuple[float, float, float, float]:
    """(omega_1, the affine modulus, the drag gamma, the kinetic energy of the start): the drag is
    ``global_damping`` of critical for the fundamental mode (:func:`fundamental_mode`) at the moving particles'
    mean mass; a glued loading starts the mobile particles on the affine field and the top layer at the wall's
    speed."""
    s, v = sample.source, spec.compression.plate_speed_m_s
    substrate, top_group = s.groups["substrate"], sample.top_layer
    masses = s.densities * np.pi / 6 * s.diameters**3
    omega1, modulus_affine = fundamental_mode(sample.structure, sample.coefficients, sample.height_nm,
                                              sample.area_nm2, masses, sample.bond_lengths)
    initial_ke = 0.0
    if LOADINGS[spec.compression.loading].glued:     # the start gives the mobile particles the affine field
        moving = ~substrate & ~top_group
        v_z = v * np.clip((s.positions[:, 2] - sample.base_nm) / sample.height_nm, 0.0, 1.0)
        initial_ke = float(0.5 * np.sum(masses[moving] * v_z[moving] ** 2) + 0.5 * np.sum(masses[top_group]) * v**2)
    gamma = 2 * spec.compression.global_damping * omega1 * float(np.mean(masses[~substrate]))
    return omega1, modulus_affine, gamma, initial_ke


def compression_deck(spec: BpmWorkflow, s: Structure) -> CompressionDeck:
    """Decks (fresh and resume) for the loading of ``s``: the loaded sample (:func:`loaded_sample`) and what a
    dynamic run adds to it (contacts, time step, schedule, damping: the functions above), as blocks."""
    c = spec.compression
    sample = loaded_sample(spec, s)
    d_mean = float(np.mean(s.diameters))
    coeffs, r0 = sample.coefficients, sample.bond_lengths
    loading = LOADINGS[c.loading]
    law, contacts, plate_E = particle_contacts(spec, s)
    estimate, dt = time_step(spec, sample, contacts, plate_E)
    steps, every, restart_every, snaps = schedule(spec, sample.height_nm, dt)
    omega1, modulus_affine, gamma, initial_ke = damping(spec, sample)
    v, top, height = c.plate_speed_m_s, sample.plate_z0_nm, sample.height_nm

    style = BOND_MODELS[spec.bonds.model]
    bond_lines = "\n".join(f"bond_coeff      {t + 1} " + " ".join(num(x) for x in style.coefficients(cf))
                           for t, cf in enumerate(coeffs))
    common = dict(ghost_cutoff=num(1.25 * float(np.max(r0, initial=d_mean)) + 0.2 * d_mean),
                  data_file="data.lmp", boundary=("p p " if s.periodic[0] else "m m ") + loading.z_boundary)
    blocks = {
        "system": render("system", **common),
        "bonds": render(style.block, breakable="yes" if spec.bonds.breakable else "no",
                        smooth="yes" if spec.bonds.breakable and spec.bonds.smooth else "no", bond_coeffs=bond_lines),
        "contacts": render("contacts", pair_coeffs="\n".join(
            f"pair_coeff      {t} {t} {law.args(cp)}" for t, cp in contacts.items())),
        "integrate": render("integrate", skin=num(0.2 * d_mean), timestep=num(dt)),
        "damping": render("damping", zeta=num(c.global_damping), gamma=num(gamma),
                          plate_speed=num(loading.sense * v if loading.affine else 0.0),
                          base=num(sample.base_nm), height=num(height)),
        **loading.blocks(sample, v, s.type_names.index("substrate") + 1, top - 0.75 * d_mean,
                         law.args(contacts[1], plate_E[1], 2 * contacts[1].stiffness)),
        "snapshots": render("snapshots", next_snapshot=_next_snapshot(snaps), count_bonds=COUNT_BONDS),
        "run": render("run", restart_every=num(restart_every), steps=num(steps)),
        "output": dict(height=num(height), every=num(every), strain_sign=loading.strain_expression(),
                       substrate_fz=loading.support_force),
        "resume": {"system": render("system_restart", ghost_cutoff=common["ghost_cutoff"],
                                    restart_file="restart.*.bin"),
                   "snapshots": render("snapshots", next_snapshot=_next_snapshot(snaps),
                                       count_bonds="# i_bonds0: the bond counts at the start, from the restart file")},
    }
    wanted = ["system", "groups", "bonds"] + (["contacts"] if spec.contacts.enabled else []) + \
             ["integrate"] + (["damping"] if c.global_damping > 0 else []) + \
             ["plate"] + (["affine_start"] if "affine_start" in blocks else []) + ["output"] + \
             (["snapshots"] if snaps else []) + ["run"]
    title = f"# opalflow {__version__}: {name(spec.name)} - {loading.title}\n"
    return CompressionDeck(**{f.name: getattr(sample, f.name) for f in dataclasses.fields(LoadedSample)},
                           in_lmp=title + _deck(wanted, blocks, fresh=True),
                           resume_lmp=title + _deck(wanted, blocks, fresh=False), timestep=estimate, dt_ns=dt,
                           steps=steps, every=every, restart_every=restart_every, snapshot_steps=snaps,
                           plate_speed_nm_ns=v, blocks=wanted, modulus_affine_MPa=modulus_affine, omega1_per_ns=omega1,
                           viscous_gamma=gamma, initial_ke_zJ=initial_ke)


def _deck(wanted: list[str], blocks: dict, fresh: bool) -> str:
    """The fresh deck, or the one that resumes from the newest restart file: groups and velocities come back
    from it (no groups, no affine start), so do the bond counts at the start; the curve is appended to."""
    parts = []
    for b in wanted:
        if b == "output":
            parts.append(render("output", **blocks["output"], curve_file="file" if fresh else "append"))
        elif fresh:
            parts.append(blocks[b])
        elif b in blocks["resume"]:
            parts.append(blocks["resume"][b])
        elif b not in ("groups", "affine_start"):
            # bonds and contacts are given again: pair granular read back from a restart file
            # blows up the first contacts of pairs whose bond broke (see templates/system_restart.lmp)
            parts.append(blocks[b])
    return "\n".join(parts)


def fundamental_mode(s: Structure, coeffs: list[BondCoefficients], height: float, area: float,
                     masses: np.ndarray, L0: np.ndarray) -> tuple[float, float]:
    """Lowest axial frequency omega_1 = pi c / (2 H) of the sample on its fixed substrate.

    c = sqrt(C / rho) with the affine (Voigt) uniaxial-strain modulus of the bond
    network, C = sum_bonds (kr / L0) L0^2 n_z^4 / V, an upper bound of the real one,
    so omega_1 and the damping built on it are on the high side.
    """
    nz = s.bond_vectors()[:, 2] / L0
    kr = np.array([c.kr for c in coeffs])[s.bond_types - 1] / L0
    volume = area * height
    modulus = float(np.sum(kr * L0**2 * nz**4) / volume)
    substrate = s.groups.get("substrate", np.zeros(s.n_particles, bool))
    rho = float(np.sum(masses[~substrate]) / volume)
    return math.pi * math.sqrt(modulus / rho) / (2 * height), modulus


def _next_snapshot(steps: list[int]) -> str:
    """Equal-style expression giving the next snapshot step after the current one."""
    if not steps:
        return "0"
    terms = [f"(step<{steps[0]})*{steps[0]}"]
    for prev, nxt in zip(steps, steps[1:]):
        terms.append(f"(step>={prev}&&step<{nxt})*{nxt}")
    terms.append(f"(step>={steps[-1]})*{10**12}")
    return '"' + "+".join(terms) + '"'
