"""Spec sections of the compression pipeline, shared by every bonded-particle scene.

:class:`BpmWorkflow` is the workflow spec a scene extends with its own sections (the opal's
packing and pores, the lattice's array, the user's data file): the matrix ``material``,
``[materials.<name>]`` overrides, ``[bonds]``, ``[contacts]`` and ``[compression]``.
:class:`StabilityMatrixWorkflow` (kind ``stability_matrix``) runs the pipeline's stability check
over rows of such workflows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from opalflow.bpm.bonds import BOND_MODELS
from opalflow.bpm.contacts import CONTACT_FRICTION
from opalflow.bpm.loading import CONTACT_LAWS, LOADINGS
from opalflow.bpm.methods import METHODS
from opalflow.materials import OVERRIDABLE, material_names
from opalflow.spec import WorkflowSpec, check, check_name, is_number

SIDES = ("periodic", "open")
PLOTS = ("auto", "all", "none")
#: allowed range of each material property a workflow may override (far around any ceramic's)
PROPERTY_RANGES = {"density_kg_m3": (1.0, 1e5), "bond_youngs_modulus_GPa": (1e-6, 1e4),
                   "bond_poisson_ratio": (-0.99, 0.499), "bond_strength_MPa": (1e-6, 1e6)}


@dataclass
class BondsSpec:
    """Bonds: who is bonded (cutoff) and how they respond (bpm/rotational).

    ``model``: "parallel" (PFC's parallel bond: normal and shear force and bending and twisting moment
    over the bond's cross-section: bpm/rotational) or "contact" (PFC's contact bond: a force at the
    contact point and no moment: bpm/spring; why, in :class:`opalflow.materials.BondCoefficients`).
    """

    model: str = "parallel"          # parallel: force and moments (bpm/rotational); contact: force only (bpm/spring)
    #: pairs whose centres are within this x (d_i + d_j) / 2 are bonded (Dosta et al. 2.2)
    cutoff_factor: float = 1.75
    #: pairs closer than this x (d_i + d_j) / 2 get no bond (0: every pair within the cutoff; 1: MUSEN's default,
    #: overlapping pairs unbonded, touching by contacts only: opalflow.bpm.bonds)
    min_length_factor: float = 0.0
    radius_factor: float = 1.0       # bond radius r_b = this x the mean particle radius of its material
    #: bond types per material by length (stiffness ~ 1/length; the report gives the error)
    length_bins: int = 8
    breakable: bool = True           # false: no bond breaks (E only; the report gives the peak stress, not a strength)
    #: each bond's damping, a fraction of critical for its spring (bpm/rotational gamma_*)
    damping_ratio: float = 0.05
    #: LAMMPS's ``smooth``: a bond's force and torque scaled by 1 - B^4 (B its breaking index), so it fades out
    #: before it breaks; false breaks it at full load (the paper's bonds, the quasi-static method's rule)
    smooth: bool = True
    #: when a bond breaks (:data:`BREAKING_RULES`; the quasi-static method alone can apply the paper's rules)
    breaking: str = "lammps"


#: bond breaking rules (opalflow.bpm.quasistatic.bond_checks), each as a report states it: LAMMPS's
#: bpm/rotational (one sum of four ratios, the signed normal force), the paper's eqs. 16-17 as printed (normal
#: and shear stress apart, |F_n|), as the paper's code MUSEN computes them today (the normal force signed), as
#: MUSEN's first public code computed them (2020: force and moment terms subtracted) and MUSEN's second criterion
#: (each of the four terms alone)
BREAKING_RULES = {"lammps": "LAMMPS's rule B = Fr/Fcr + |Fs|/Fcs + |Tb|/Tcb + |Tt|/Tct >= 1",
                  "dosta": "the paper's rule (eqs. 16-17) max(|Fr|/Fcr + |Tb|/Tcb, |Fs|/Fcs + |Tt|/Tct) >= 1",
                  "musen": "the paper's rule (eqs. 16-17) as its code MUSEN computes it, max(Fr/Fcr + |Tb|/Tcb, "
                           "|Fs|/Fcs + |Tt|/Tct) >= 1 with Fr signed",
                  "musen_2020": "MUSEN's rule of 2020 (first public commit 655e066), max(||Tb|/Tcb - |Fr|/Fcr| in "
                                "tension, ||Tt|/Tct - |Fs|/Fcs|) >= 1: the terms the paper's eqs. 16-17 add, "
                                "subtracted",
                  "musen_crit2": "MUSEN's second criterion (CONSIDER_BREAKAGE 2), max(Fr/Fcr, |Tb|/Tcb in tension, "
                                 "|Fs|/Fcs, |Tt|/Tct) >= 1: each term alone"}


@dataclass
class ContactsSpec:
    """Hertz-Mindlin contacts between unbonded particles (pair_style granular); friction and restitution
    replace every material's (data/materials.toml) when given."""

    #: contacts between unbonded particles in the dynamic method (pair_style granular) and in the nonlinear
    #: quasi-static one (the same law, static: opalflow.bpm.contacts.GranularContacts)
    enabled: bool = True
    model: str = "hertz"             # hertz: hertz/material + mindlin; linear: hooke + linear_history
    friction: float | None = None    # Coulomb friction coefficient of every contact (None: each material's)
    restitution: float | None = None  # coefficient of restitution of every contact (None: each material's)
    #: contacts in the quasi-static method (opalflow.bpm.contacts): "off", or linear Hertz-Mindlin springs between
    #: touching unbonded pairs, in compression only, "frictionless" (mu = 0) or "sticking" (no slip limit)
    quasistatic: str = "off"
    #: ... their springs are Hertz's secant and Mindlin's tangent at this overlap / contact distance
    reference_strain: float = 0.01


#: solvers of the static method (opalflow.bpm.static.SOLVERS)
STATIC_SOLVERS = ("auto", "direct", "amg", "block-amg", "cg", "cg-jax")
#: re-solves of the quasistatic method (opalflow.bpm.quasistatic.RESOLVERS)
RESOLVERS = ("auto", "direct", "amg", "block-amg")


@dataclass
class CompressionSpec:
    """Uniaxial compression by a rigid plate moving down at constant speed."""

    strain_max: float = 0.04         # the plate stops at this strain (of the sample's height)
    #: dynamic: the plate's speed (the paper's; slower changes E little: docs/validation/opals.md)
    plate_speed_m_s: float = 2.0
    timestep_s: float = 0.0          # dynamic: LAMMPS's time step (0: timestep_safety x the estimated stability limit)
    timestep_safety: float = 0.8     # dynamic: the fraction of the estimated limit taken when timestep_s is 0
    #: dynamic: viscous damping of the moving particles, a fraction of critical for the fundamental mode
    global_damping: float = 0.5
    output_every_strain: float = 2.0e-4  # dynamic: a point of the stress-strain curve every this much strain
    #: dynamic: particle dumps (stresses, broken bonds) at these strains
    snapshot_strains: list[float] = field(default_factory=lambda: [0.01, 0.02])
    #: dynamic: a LAMMPS restart file every this much strain (--resume starts from the newest)
    restart_every_strain: float = 0.005
    #: dynamic: run again at half the plate speed and report how much E and strength move
    check_rate: bool = False
    loading: str = "plate"           # plate: contact wall (fix wall/gran); glued: top layer moves with the wall
    method: str = "dynamic"          # dynamic: LAMMPS; static: one linear solve (E and stresses only)
    solver: str = "auto"             # static: auto, amg, block-amg, cg or cg-jax (opalflow/bpm/static.py)
    drop_loose: bool = False         # static: leave out particles with no bond path to the substrate
    resolver: str = "auto"           # quasistatic: re-solves by direct (Cholesky + Woodbury), amg, block-amg, or auto
    event_tolerance: float = 0.0     # quasistatic: break every bond within this fraction of the next one's limit
    stop_fraction: float = 0.5       # quasistatic: stop when the stress has fallen below this fraction of the peak
    events_max: int = 100_000        # quasistatic: at most this many events
    resolve_rtol: float = 1e-6       # quasistatic, amg and block-amg: each re-solve to this residual (of |b|)
    local_rtol: float = 0.0          # quasistatic: events settle by a local solve while the residual stays below this
    #: quasistatic: "linear" (small rotations: one solve an event) or "nonlinear" (LAMMPS's bond law at finite
    #: rotation, Newton at each load step, with contacts.enabled its Hertz-Mindlin contacts with friction:
    #: opalflow/bpm/nonlinear.py; bending networks at large strain)
    geometry: str = "linear"
    plots: str = "auto"              # the report's plots: all, none, or auto (all but for the static method)


@dataclass
class CalibrationSpec:
    """First-estimate bond properties from a target Young's modulus and tensile strength of the particle
    assembly (Roy and Hossain, eqs. 10.3-10.4, PFC's cubic-array relations): k_n = 4 R E, s_n = 4 R^2
    sigma_t.  0 leaves the material's bond properties as they are (see :func:`first_estimate`)."""

    target_E_GPa: float = 0.0        # the assembly's Young's modulus to calibrate the bond E for (0: the material's)
    #: the assembly's tensile strength to calibrate the bond strength for (0: the material's)
    target_tensile_strength_MPa: float = 0.0
    shear_ratio: float = 1.0         # k_s / k_n


def first_estimate(c: CalibrationSpec, radius_factor: float) -> dict[str, float]:
    """Bond properties (``[materials.<name>]`` keys) of the first estimate (eqs. 10.3-10.4).

    In PFC k_n is a ball's normal stiffness: a contact is two balls in series, K = k_n / 2 = 2 R E, and
    a simple-cubic array of spacing 2R carries E = K / (2R) = k_n / (4 R) (eq. 10.3); each contact
    carries the tensile force of a (2R)^2 square, s_n = 4 R^2 sigma_t (eq. 10.4).  A bpm/rotational bond
    (``normalize yes``, r0 = 2R) is the contact spring when k_r / r0 = K, i.e. k_r = E_b pi r_b^2 =
    4 R^2 E with r_b = radius_factor R, so E_b = 4 E / (pi f^2), and its critical force sigma_b pi r_b^2
    = s_n, so sigma_b = 4 sigma_t / (pi f^2); neither depends on R.  k_s / k_n = G_b / E_b =
    1 / (2 (1 + nu_b)) sets the bond Poisson ratio nu_b = 1 / (2 shear_ratio) - 1.  The shear strength
    equals the normal one (s_s = s_n, PFC's "equal" choice; opalflow's bonds have one strength).
    """
    f2 = radius_factor**2
    out = {"bond_youngs_modulus_GPa": 4 * c.target_E_GPa / (math.pi * f2),
           "bond_poisson_ratio": 1 / (2 * c.shear_ratio) - 1}
    if c.target_tensile_strength_MPa > 0:
        out["bond_strength_MPa"] = 4 * c.target_tensile_strength_MPa / (math.pi * f2)
    return out


@dataclass
class BoundarySpec:
    """Side boundaries (x and y): periodic, or open (no bonds across)."""

    sides: str = "periodic"          # x and y sides: periodic, or open (a free surface, no bonds across)

    def validate(self) -> None:
        check(self.sides in SIDES, "boundary.sides", self.sides, f"must be one of {', '.join(SIDES)}")


@dataclass
class BpmWorkflow(WorkflowSpec):
    """A bonded-particle scene compressed by a plate: what every scene's workflow has."""

    material: str = "silica"         # the matrix's material, a table of data/materials.toml
    #: [materials.NAME] overrides: density_kg_m3, bond_youngs_modulus_GPa, bond_poisson_ratio, bond_strength_MPa
    materials: dict = field(default_factory=dict)
    bonds: BondsSpec = field(default_factory=BondsSpec)
    contacts: ContactsSpec = field(default_factory=ContactsSpec)
    compression: CompressionSpec = field(default_factory=CompressionSpec)
    calibration: CalibrationSpec = field(default_factory=CalibrationSpec)

    def references(self) -> dict[str, tuple[float, str]]:
        """Reference values a run of this scene is compared with: {summary key: (value, source)}."""
        return {}

    def validate(self) -> None:
        super().validate()
        self._check_materials()
        self._check_bonds_and_contacts()
        self._check_compression()

    def _check_materials(self) -> None:
        """[materials.NAME]: known materials, known keys, values in range."""
        materials = material_names()
        for mname, props in self.materials.items():
            check_name("materials", mname)
            check(mname in materials, f"materials.{mname}", props, f"unknown material; known: {', '.join(materials)}")
            check(isinstance(props, dict), f"materials.{mname}", props, "must be a table of properties")
            for key, value in props.items():
                check(key in OVERRIDABLE, f"materials.{mname}.{key}", value,
                      f"unknown key; allowed: {', '.join(OVERRIDABLE)}")
                lo, hi = PROPERTY_RANGES[key]
                check(is_number(value) and lo <= value <= hi, f"materials.{mname}.{key}", value,
                      f"must be a number in [{lo:g}, {hi:g}]")

    def _check_bonds_and_contacts(self) -> None:
        """The matrix's material, [bonds] and [contacts]."""
        check_material("material", self.material)
        b = self.bonds
        check(b.model in BOND_MODELS, "bonds.model", b.model, f"must be one of {', '.join(BOND_MODELS)}")
        check(self.contacts.model in CONTACT_LAWS, "contacts.model", self.contacts.model,
              f"must be one of {', '.join(CONTACT_LAWS)}")
        check(1.0 <= b.cutoff_factor <= 3.0, "bonds.cutoff_factor", b.cutoff_factor,
              "must be in [1.0, 3.0] (bond cutoff in particle diameters)")
        check(0 <= b.min_length_factor < b.cutoff_factor, "bonds.min_length_factor", b.min_length_factor,
              f"must be in [0, bonds.cutoff_factor = {b.cutoff_factor:g}) (the shortest bond in particle diameters)")
        check(0 < b.radius_factor <= 2.0, "bonds.radius_factor", b.radius_factor,
              "must be in (0, 2] (bond radius / particle radius)")
        check(1 <= b.length_bins <= 100, "bonds.length_bins", b.length_bins, "must be in [1, 100]")
        check(0 <= b.damping_ratio <= 2.0, "bonds.damping_ratio", b.damping_ratio, "must be in [0, 2]")
        k = self.contacts
        if k.friction is not None:
            check(0 <= k.friction <= 10, "contacts.friction", k.friction, "must be in [0, 10] (sliding friction)")
        if k.restitution is not None:
            check(0 < k.restitution <= 1, "contacts.restitution", k.restitution,
                  "must be in (0, 1] (coefficient of restitution)")
        check(k.quasistatic in ("off", *CONTACT_FRICTION), "contacts.quasistatic", k.quasistatic,
              f"must be one of off, {', '.join(CONTACT_FRICTION)}")
        check(0 < k.reference_strain <= 0.2, "contacts.reference_strain", k.reference_strain,
              "must be in (0, 0.2] (overlap / contact distance where the Hertz-Mindlin springs are taken)")
        if k.quasistatic != "off":
            check(self.compression.local_rtol == 0, "compression.local_rtol", self.compression.local_rtol,
                  "must be 0 with contacts.quasistatic (the local step takes no contacts)")

    def _check_compression(self) -> None:
        """[compression]: the loading, the method and their settings (each as one line: field, value, allowed)."""
        b, c = self.bonds, self.compression
        check(0 < c.strain_max <= 0.5, "compression.strain_max", c.strain_max, "must be in (0, 0.5]")
        check(0 < c.plate_speed_m_s <= 100, "compression.plate_speed_m_s", c.plate_speed_m_s,
              "must be in (0, 100] m/s (quasi-static loading)")
        check(c.timestep_s >= 0, "compression.timestep_s", c.timestep_s, "must be >= 0 (0: estimated)")
        check(0 < c.timestep_safety <= 1, "compression.timestep_safety", c.timestep_safety, "must be in (0, 1]")
        check(0 <= c.global_damping <= 2, "compression.global_damping", c.global_damping,
              "must be in [0, 2] (fraction of critical damping of the sample's fundamental mode)")
        check(0 < c.output_every_strain <= c.strain_max / 10, "compression.output_every_strain",
              c.output_every_strain, f"must be in (0, strain_max/10 = {c.strain_max / 10:g}]")
        for i, e in enumerate(c.snapshot_strains):
            check(0 < e <= c.strain_max, f"compression.snapshot_strains[{i}]", e,
                  f"must be in (0, strain_max = {c.strain_max:g}]")
        check(c.loading in LOADINGS, "compression.loading", c.loading, f"must be one of {', '.join(LOADINGS)}")
        check(c.method in METHODS, "compression.method", c.method, f"must be one of {', '.join(METHODS)}")
        check(c.plots in PLOTS, "compression.plots", c.plots, f"must be one of {', '.join(PLOTS)} (auto: all but "
              "for the static method, whose solve the plots would outlast)")
        check(c.solver in STATIC_SOLVERS, "compression.solver", c.solver,
              f"must be one of {', '.join(STATIC_SOLVERS)} (static method)")
        check(b.breaking in BREAKING_RULES, "bonds.breaking", b.breaking,
              f"must be one of {', '.join(BREAKING_RULES)}")
        METHODS[c.method].check(self)
        LOADINGS[c.loading].check(self)
        check(c.resolver in RESOLVERS, "compression.resolver", c.resolver,
              f"must be one of {', '.join(RESOLVERS)} (quasistatic method)")
        check(c.geometry in ("linear", "nonlinear"), "compression.geometry", c.geometry,
              'must be "linear" or "nonlinear" (quasistatic method)')
        check(c.geometry == "linear" or c.method == "quasistatic", "compression.geometry", c.geometry,
              'is the quasi-static method\'s (the dynamic one is LAMMPS, at finite rotation already)')
        check(c.geometry == "linear" or not self.contacts.enabled or self.contacts.model == "hertz",
              "contacts.model", self.contacts.model, 'must be "hertz" with compression.geometry = "nonlinear" and '
              "contacts.enabled (its contacts are Hertz-Mindlin's; contacts.enabled = false: none)")
        check(c.geometry == "linear" or b.breaking == "lammps", "bonds.breaking", b.breaking,
              'must be "lammps" with compression.geometry = "nonlinear" (LAMMPS\'s bpm/rotational law and rule)')
        check(c.geometry == "linear" or self.contacts.quasistatic == "off", "contacts.quasistatic",
              self.contacts.quasistatic, 'must be "off" with compression.geometry = "nonlinear" (the linear '
              "method's contact springs)")
        check(0 <= c.event_tolerance <= 0.5, "compression.event_tolerance", c.event_tolerance,
              "must be in [0, 0.5] (bonds within this fraction of the next limit break in one event)")
        check(0 <= c.stop_fraction < 1, "compression.stop_fraction", c.stop_fraction, "must be in [0, 1)")
        check(1 <= c.events_max <= 10**8, "compression.events_max", c.events_max, "must be in [1, 1e8]")
        check(1e-12 <= c.resolve_rtol <= 1e-2, "compression.resolve_rtol", c.resolve_rtol,
              "must be in [1e-12, 1e-2] (the iterative re-solves' relative residual)")
        check(c.local_rtol == 0 or c.resolve_rtol <= c.local_rtol <= 1e-2, "compression.local_rtol", c.local_rtol,
              f"must be 0 (every event re-solved) or in [compression.resolve_rtol = {c.resolve_rtol:g}, 1e-2] (the "
              "residual, of |b|, up to which an event settles by a local solve)")
        self._apply_calibration()
        check(0 < c.restart_every_strain <= 1, "compression.restart_every_strain", c.restart_every_strain,
              "must be in (0, 1] (restart files every this much strain; >= strain_max: none)")

    def _apply_calibration(self) -> None:
        """Fold the first estimate (``[calibration]``) into ``materials.<material>``."""
        cal = self.calibration
        check(0 <= cal.target_E_GPa <= 1e4, "calibration.target_E_GPa", cal.target_E_GPa,
              "must be in [0, 1e4] GPa (0: no first estimate)")
        check(0 <= cal.target_tensile_strength_MPa <= 1e6, "calibration.target_tensile_strength_MPa",
              cal.target_tensile_strength_MPa, "must be in [0, 1e6] MPa")
        check(0.34 <= cal.shear_ratio <= 10, "calibration.shear_ratio", cal.shear_ratio,
              "must be in [0.34, 10] (k_s / k_n = 1 / (2 (1 + nu_b)) with nu_b in (-0.95, 0.47))")
        if cal.target_E_GPa == 0:
            check(cal.target_tensile_strength_MPa == 0, "calibration.target_tensile_strength_MPa",
                  cal.target_tensile_strength_MPa, "needs calibration.target_E_GPa > 0 as well")
            return
        derived = first_estimate(cal, self.bonds.radius_factor)
        given = dict(self.materials.get(self.material, {}))
        for key, value in derived.items():
            check(key not in given or math.isclose(given[key], value, rel_tol=1e-12), f"materials.{self.material}.{key}",
                  given.get(key), "is set by [calibration] (eqs. 10.3-10.4): leave it out")
        self.materials = {**self.materials, self.material: {**given, **derived}}


def check_material(where: str, value: str, also: tuple[str, ...] = ()) -> None:
    """A material name of data/materials.toml (or one of ``also``)."""
    check_name(where, value)
    known = (*material_names(), *also)
    check(value in known, where, value, f"unknown material; known: {', '.join(known)}")


@dataclass
class MatrixSpec:
    """Rows of the stability matrix: label -> {workflow = "NAME", set = ["section.key=value", ...], strain = S}
    (``strain``: run each check until the plate has compressed the sample by S instead of ``steps``)."""

    steps: int = 1500                # LAMMPS time steps of each row's check (unless the row gives a strain)
    rows: dict = field(default_factory=dict)  # label -> {workflow, set, strain}: the scenes checked


@dataclass
class StabilityMatrixWorkflow(WorkflowSpec):
    """The stability check (opalflow.bpm.stability) over corner cases of bonded-particle scenes."""

    matrix: MatrixSpec = field(default_factory=MatrixSpec)

    def validate(self) -> None:
        super().validate()
        m = self.matrix
        check(100 <= m.steps <= 10**6, "matrix.steps", m.steps, "must be in [100, 1e6] (time steps of each run)")
        check(len(m.rows) >= 1, "matrix.rows", m.rows, "must hold at least one row")
        for label, row in m.rows.items():
            where = f"matrix.rows.{label}"
            check_name(where, label)
            check(isinstance(row, dict) and set(row) <= {"workflow", "set", "strain"} and "workflow" in row, where,
                  row, "must be a table {workflow = \"NAME\", set = [\"section.key=value\", ...], strain = S}")
            check(isinstance(row["workflow"], str), f"{where}.workflow", row["workflow"], "must be a workflow name")
            check_name(f"{where}.workflow", row["workflow"])
            sets = row.get("set", [])
            check(isinstance(sets, list) and all(isinstance(x, str) and "=" in x for x in sets), f"{where}.set",
                  sets, "must be a list of \"section.key=value\" strings")
            if "strain" in row:
                check(is_number(row["strain"]) and 0 < row["strain"] <= 0.9, f"{where}.strain", row["strain"],
                      "must be a number in (0, 0.9] (compress each check this far)")
