"""Workflow specs: TOML -> validated dataclasses.

Every error is a :class:`SpecError` whose message is one line naming the field, the
value and what is allowed, raised before anything is written.  Names that reach a
LAMMPS script must match ``[A-Za-z0-9_]+`` and numbers must be numbers, so a
workflow file cannot smuggle LAMMPS commands (LAMMPS has ``shell``) into a deck.
"""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_type_hints

NAME_RE = re.compile(r"[A-Za-z0-9_]+")


class SpecError(ValueError):
    """A spec field holds a value that is not allowed (one-line message)."""

    def __init__(self, field_name: str, value: Any, allowed: str):
        self.field = field_name
        self.value = value
        self.allowed = allowed
        super().__init__(f"{field_name} = {value!r}: {allowed}")


@dataclass
class PackingSpec:
    """Dense random packing of spheres (the solid skeleton before pores are cut)."""

    diameter_nm: float = 15.0
    solid_fraction: float = 0.62
    diameter_std_nm: float = 0.0
    size_bins: int = 8
    seed: int = 1
    tile_nm: float = 380.0
    max_overlap: float = 0.005


@dataclass
class PoresSpec:
    """Macropores cut out of the packing (eq. 1 of Dosta et al.)."""

    arrangement: str = "fcc"
    diameter_nm: float = 762.0
    spacing_nm: float = 762.0
    layers: int = 3
    cells_x: int = 4
    cells_y: int = 2
    porosity: float | None = None
    porosity_tolerance: float = 0.01
    seed: int = 1


@dataclass
class CoatingSpec:
    """Coating of the pore walls (eq. 2); thickness 0 means uncoated."""

    thickness_nm: float = 0.0
    material: str = "titania"


@dataclass
class SubstrateSpec:
    """Fixed bottom particle layers."""

    layers: int = 2


@dataclass
class BondsSpec:
    """Bonds: who is bonded (cutoff) and how they respond (bpm/rotational)."""

    cutoff_factor: float = 1.75
    radius_factor: float = 1.0
    length_bins: int = 8
    breakable: bool = True
    damping_ratio: float = 0.05


@dataclass
class ContactsSpec:
    """Hertz-Mindlin contacts between unbonded particles (pair_style granular)."""

    enabled: bool = True


@dataclass
class CompressionSpec:
    """Uniaxial compression by a rigid plate moving down at constant speed."""

    strain_max: float = 0.04
    plate_speed_m_s: float = 2.0
    timestep_s: float = 0.0
    timestep_safety: float = 0.8
    global_damping: float = 0.5
    output_every_strain: float = 2.0e-4
    snapshot_strains: list[float] = field(default_factory=lambda: [0.01, 0.02])
    restart_every_strain: float = 0.005
    check_rate: bool = False


@dataclass
class LatticeSpec:
    """Regular arrays of bonded spheres (kind = "lattice") for analytic checks."""

    arrangement: str = "sc"
    spacing_nm: float = 20.0
    cells_x: int = 4
    cells_y: int = 4
    cells_z: int = 8


@dataclass
class DatafileSpec:
    """A user's bpm/sphere data file (kind = "datafile"); materials name its atom types in order."""

    path: str = ""
    materials: list[str] = field(default_factory=list)
    periodic_sides: bool = True


@dataclass
class TersoffSpec:
    """Tersoff potential: which file, how its properties are evaluated, and the fit (seed 003)."""

    potential: str = "Si_zhuravlev2021.tersoff"
    element: str = "Si"
    cells: int = 2
    strain: float = 1e-4
    strain_scan: list[float] = field(default_factory=lambda: [1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1])
    lattice_target_A: float = 5.431
    targets: dict = field(default_factory=dict)
    weights: dict = field(default_factory=dict)
    fixed: list[str] = field(default_factory=lambda: ["m", "R", "D"])
    bounds: dict = field(default_factory=dict)
    starts: int = 16
    seed: int = 1
    max_iter: int = 5000
    rank_top: int = 3


@dataclass
class StabilitySpec:
    """MD stability check of a Tersoff set: 4x4x4 cells, 0.01 ns, four boundary conditions."""

    boundaries: list[str] = field(default_factory=lambda: ["ppp", "ppf", "pff", "fff"])
    temperatures_K: list[float] = field(default_factory=lambda: [300.0, 600.0])
    time_ps: float = 10.0
    timestep_fs: float = 1.0
    cells: int = 4
    seed: int = 12345
    max_drift_eV: float = 1e-3
    min_fourfold: float = 0.95
    max_rms_A: float = 0.5
    workers: int = 0


@dataclass
class StudySpec:
    """A study (kind = "study"): many compression jobs made from one base workflow (Dosta et al.)."""

    type: str = "calibration"
    base: str = "quickstart"
    paper_base: str = "opal_fcc"
    paper_scale: bool = False
    set: list[str] = field(default_factory=list)
    workers: int = 0
    np: int = 1
    # calibration (eqs. 18-19)
    target_E_GPa: float = 1.7
    target_strength_MPa: float = 41.3
    tolerance: float = 0.005
    max_runs: int = 8
    jacobian: str = "decoupled"
    fd_step: float = 0.1
    start_E_GPa: float = 0.0
    start_strength_MPa: float = 0.0
    # bulk (K_E), coating, porosity, convergence
    diameters_nm: list[float] = field(default_factory=lambda: [60.0, 45.0])
    thicknesses_nm: list[float] = field(default_factory=lambda: [0.0, 10.0, 20.0, 34.0])
    porosities: list[float] = field(default_factory=lambda: [0.30, 0.36, 0.42, 0.49, 0.55, 0.62])
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    cells: list[list[int]] = field(default_factory=lambda: [[1, 1], [2, 1], [2, 2]])


@dataclass
class BoundarySpec:
    """Side boundaries (x and y): periodic, or open (no bonds across)."""

    sides: str = "periodic"


@dataclass
class WorkflowSpec:
    """A whole workflow file."""

    name: str = "opal"
    description: str = ""
    kind: str = "opal"
    material: str = "silica"
    packing: PackingSpec = field(default_factory=PackingSpec)
    pores: PoresSpec = field(default_factory=PoresSpec)
    coating: CoatingSpec = field(default_factory=CoatingSpec)
    substrate: SubstrateSpec = field(default_factory=SubstrateSpec)
    bonds: BondsSpec = field(default_factory=BondsSpec)
    boundary: BoundarySpec = field(default_factory=BoundarySpec)
    contacts: ContactsSpec = field(default_factory=ContactsSpec)
    compression: CompressionSpec = field(default_factory=CompressionSpec)
    lattice: LatticeSpec = field(default_factory=LatticeSpec)
    datafile: DatafileSpec = field(default_factory=DatafileSpec)
    tersoff: TersoffSpec = field(default_factory=TersoffSpec)
    stability: StabilitySpec = field(default_factory=StabilitySpec)
    study: StudySpec = field(default_factory=StudySpec)
    materials: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


KINDS = ("opal", "lattice", "datafile", "tersoff_properties", "tersoff_fit", "tersoff_stability", "study")
STUDIES = ("calibration", "bulk", "coating", "porosity", "convergence")
LATTICES = ("sc", "fcc")
ARRANGEMENTS = ("fcc", "random", "none")
SIDES = ("periodic", "open")


# ----------------------------------------------------------------------------- loading
def parse_value(text: str) -> Any:
    """A ``--set`` value: TOML syntax (numbers, booleans, quoted strings, arrays), else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(raw: dict, overrides: list[str]) -> dict:
    """Apply ``section.key=value`` overrides to the raw TOML dict (before validation)."""
    for item in overrides:
        if "=" not in item:
            raise SpecError("--set", item, "expected section.key=value")
        path, text = item.split("=", 1)
        keys = path.strip().split(".")
        if not all(NAME_RE.fullmatch(k) for k in keys):
            raise SpecError("--set", item, "keys must match [A-Za-z0-9_]+ separated by dots")
        node = raw
        for k in keys[:-1]:
            node = node.setdefault(k, {})
            if not isinstance(node, dict):
                raise SpecError(path, item, f"'{k}' is not a section")
        node[keys[-1]] = parse_value(text.strip())
    return raw


def _convert(cls, raw: dict, prefix: str):
    hints = get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for key in raw:
        if key not in names:
            where = f"{prefix}{key}"
            raise SpecError(where, raw[key], f"unknown key; allowed in "
                            f"{prefix.rstrip('.') or 'the top level'}: {', '.join(names)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in raw:
            continue
        value, hint, where = raw[f.name], hints[f.name], f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise SpecError(where, value, "must be a table (section)")
            kwargs[f.name] = _convert(hint, value, f"{where}.")
        else:
            kwargs[f.name] = _coerce(value, hint, where)
    return cls(**kwargs)


def _coerce(value, hint, where):
    """Check a TOML value against a field's type (``X | None`` allows a missing value)."""
    if typing.get_origin(hint) is list:
        if not isinstance(value, list):
            raise SpecError(where, value, "must be a list")
        item = typing.get_args(hint)[0]
        return [_coerce(v, item, f"{where}[{k}]") for k, v in enumerate(value)]
    args = typing.get_args(hint)
    if args:
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SpecError(where, value, "must be a finite number")
        return float(value)
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise SpecError(where, value, "must be an integer")
    if hint is str and not isinstance(value, str):
        raise SpecError(where, value, "must be a string")
    if hint is dict and not isinstance(value, dict):
        raise SpecError(where, value, "must be a table")
    if hint is bool and not isinstance(value, bool):
        raise SpecError(where, value, "must be true or false")
    return value


def load_spec(path: str | Path, overrides: list[str] | None = None) -> WorkflowSpec:
    """Read, override and validate a workflow file."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SpecError("workflow", str(path), "file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError("workflow", str(path), f"not valid TOML ({exc})") from None
    return spec_from_dict(apply_overrides(raw, overrides or []))


def spec_from_dict(raw: dict) -> WorkflowSpec:
    spec = _convert(WorkflowSpec, raw, "")
    validate(spec)
    return spec


# ----------------------------------------------------------------------------- validation
def _check(cond: bool, where: str, value, allowed: str):
    if not cond:
        raise SpecError(where, value, allowed)


def check_name(where: str, value: str):
    _check(bool(NAME_RE.fullmatch(value)), where, value,
           "names may only contain letters, digits and '_' ([A-Za-z0-9_]+)")


def sample_box_nm(spec: WorkflowSpec) -> tuple[float, float, float]:
    """Lateral size and pore-region height of the sample (nm), from the FCC cell.

    The cell is rectangular: spacing x spacing*sqrt(3) in plane (two pores per
    (111) layer), layer spacing spacing*sqrt(2/3); the height holds ``layers``
    pore layers touching the bottom and top faces: 2 R + (layers - 1) h.
    """
    p = spec.pores
    a = p.spacing_nm
    h = a * math.sqrt(2.0 / 3.0)
    return p.cells_x * a, p.cells_y * a * math.sqrt(3.0), p.diameter_nm + (p.layers - 1) * h


def max_coating_nm(spec: WorkflowSpec) -> float:
    """Thickest coating that still leaves silica: radius of the largest solid region.

    For the FCC pore lattice with nearest-neighbour spacing a that is the octahedral
    hole, a / sqrt(2) - R_pore; random pores use the same bound for a = D_pore.
    """
    p = spec.pores
    a = p.spacing_nm if p.arrangement == "fcc" else p.diameter_nm
    return a / math.sqrt(2.0) - p.diameter_nm / 2.0


def validate(spec: WorkflowSpec, known_materials: tuple[str, ...] | None = None) -> None:
    """Check every field; raise SpecError naming the first bad one."""
    from opalflow.materials import material_names

    materials = known_materials or material_names()
    check_name("name", spec.name)
    _check(spec.kind in KINDS, "kind", spec.kind, f"must be one of {', '.join(KINDS)}")
    from opalflow.materials import OVERRIDABLE

    for mname, props in spec.materials.items():
        check_name("materials", mname)
        _check(mname in materials, f"materials.{mname}", props, f"unknown material; known: {', '.join(materials)}")
        _check(isinstance(props, dict), f"materials.{mname}", props, "must be a table of properties")
        for key, value in props.items():
            _check(key in OVERRIDABLE, f"materials.{mname}.{key}", value,
                   f"unknown key; allowed: {', '.join(OVERRIDABLE)}")
            _check(not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
                   and value > 0, f"materials.{mname}.{key}", value, "must be a number > 0")
    check_name("material", spec.material)
    _check(spec.material in materials, "material", spec.material,
           f"unknown material; known: {', '.join(materials)}")

    k = spec.packing
    _check(k.diameter_nm > 0, "packing.diameter_nm", k.diameter_nm, "must be > 0")
    _check(0.05 <= k.solid_fraction <= 0.64, "packing.solid_fraction", k.solid_fraction,
           "must be in [0.05, 0.64] (random close packing of spheres is about 0.64)")
    _check(0 <= k.diameter_std_nm <= k.diameter_nm / 4, "packing.diameter_std_nm", k.diameter_std_nm,
           f"must be in [0, diameter_nm/4 = {k.diameter_nm / 4:g}]")
    _check(1 <= k.size_bins <= 64, "packing.size_bins", k.size_bins, "must be in [1, 64]")
    _check(k.seed >= 0, "packing.seed", k.seed, "must be >= 0")
    _check(k.tile_nm == 0 or k.tile_nm >= 8 * k.diameter_nm, "packing.tile_nm", k.tile_nm,
           f"must be 0 (pack the whole box) or >= 8 particle diameters ({8 * k.diameter_nm:g} nm)")
    _check(0 < k.max_overlap <= 0.01, "packing.max_overlap", k.max_overlap,
           "must be in (0, 0.01] (fraction of the diameter)")

    p = spec.pores
    _check(p.arrangement in ARRANGEMENTS, "pores.arrangement", p.arrangement,
           f"must be one of {', '.join(ARRANGEMENTS)}")
    _check(p.diameter_nm > 2 * k.diameter_nm, "pores.diameter_nm", p.diameter_nm,
           f"must be > 2 particle diameters ({2 * k.diameter_nm:g} nm)")
    _check(p.spacing_nm >= 0.75 * p.diameter_nm, "pores.spacing_nm", p.spacing_nm,
           f"must be >= 0.75 x pores.diameter_nm ({0.75 * p.diameter_nm:g} nm)")
    _check(p.layers >= 1, "pores.layers", p.layers, "must be >= 1")
    _check(p.cells_x >= 1, "pores.cells_x", p.cells_x, "must be >= 1")
    _check(p.cells_y >= 1, "pores.cells_y", p.cells_y, "must be >= 1")
    _check(p.seed >= 0, "pores.seed", p.seed, "must be >= 0")
    if p.arrangement == "random":
        _check(p.porosity is not None, "pores.porosity", p.porosity,
               "required for arrangement = 'random' (target macro-porosity)")
        _check(0 < p.porosity < 1, "pores.porosity", p.porosity, "must be in (0, 1)")
        _check(p.porosity <= 0.66, "pores.porosity", p.porosity,
               "must be <= 0.66: denser random non-overlapping pores cannot be placed")
        _check(0 < p.porosity_tolerance <= 0.2, "pores.porosity_tolerance", p.porosity_tolerance,
               "must be in (0, 0.2] (a small box holds few pores: each moves the porosity by its share)")
    elif p.porosity is not None:
        raise SpecError("pores.porosity", p.porosity,
                        "only allowed with arrangement = 'random' (fcc porosity follows from the lattice)")
    lx, ly, h = sample_box_nm(spec)
    if p.arrangement != "none":
        _check(p.diameter_nm <= min(lx, ly, h), "pores.diameter_nm", p.diameter_nm,
               f"pores larger than the box ({lx:.0f} x {ly:.0f} x {h:.0f} nm); "
               "add cells or layers, or make the pores smaller")

    c = spec.coating
    check_name("coating.material", c.material)
    _check(c.material in materials, "coating.material", c.material,
           f"unknown material; known: {', '.join(materials)}")
    _check(c.thickness_nm >= 0, "coating.thickness_nm", c.thickness_nm, "must be >= 0")
    if c.thickness_nm > 0:
        _check(p.arrangement != "none", "coating.thickness_nm", c.thickness_nm,
               "a coating needs pores (pores.arrangement = 'none')")
        limit = max_coating_nm(spec)
        _check(c.thickness_nm < limit, "coating.thickness_nm", c.thickness_nm,
               f"coating thicker than the struts: must be < {limit:.1f} nm, the radius of the "
               "largest solid region between pores")

    _check(0 <= spec.substrate.layers <= 10, "substrate.layers", spec.substrate.layers,
           "must be in [0, 10]")
    b = spec.bonds
    _check(1.0 <= b.cutoff_factor <= 3.0, "bonds.cutoff_factor", b.cutoff_factor,
           "must be in [1.0, 3.0] (bond cutoff in particle diameters)")
    _check(0 < b.radius_factor <= 2.0, "bonds.radius_factor", b.radius_factor,
           "must be in (0, 2] (bond radius / particle radius)")
    _check(1 <= b.length_bins <= 100, "bonds.length_bins", b.length_bins, "must be in [1, 100]")
    _check(0 <= b.damping_ratio <= 2.0, "bonds.damping_ratio", b.damping_ratio, "must be in [0, 2]")
    c = spec.compression
    _check(0 < c.strain_max <= 0.5, "compression.strain_max", c.strain_max, "must be in (0, 0.5]")
    _check(0 < c.plate_speed_m_s <= 100, "compression.plate_speed_m_s", c.plate_speed_m_s,
           "must be in (0, 100] m/s (quasi-static loading)")
    _check(c.timestep_s >= 0, "compression.timestep_s", c.timestep_s, "must be >= 0 (0: estimated)")
    _check(0 < c.timestep_safety <= 1, "compression.timestep_safety", c.timestep_safety, "must be in (0, 1]")
    _check(0 <= c.global_damping <= 2, "compression.global_damping", c.global_damping,
           "must be in [0, 2] (fraction of critical damping of the sample's fundamental mode)")
    _check(0 < c.output_every_strain <= c.strain_max / 10, "compression.output_every_strain",
           c.output_every_strain, f"must be in (0, strain_max/10 = {c.strain_max / 10:g}]")
    for i, e in enumerate(c.snapshot_strains):
        _check(0 < e <= c.strain_max, f"compression.snapshot_strains[{i}]", e,
               f"must be in (0, strain_max = {c.strain_max:g}]")
    _check(c.restart_every_strain > 0, "compression.restart_every_strain", c.restart_every_strain,
           "must be > 0 (restart files every this much strain)")
    if spec.kind == "lattice":
        lat = spec.lattice
        _check(lat.arrangement in LATTICES, "lattice.arrangement", lat.arrangement,
               f"must be one of {', '.join(LATTICES)}")
        _check(lat.spacing_nm > 0, "lattice.spacing_nm", lat.spacing_nm, "must be > 0")
        for axis in "xyz":
            n = getattr(lat, f"cells_{axis}")
            _check(2 <= n <= 200, f"lattice.cells_{axis}", n, "must be in [2, 200]")
    if spec.kind == "datafile":
        d = spec.datafile
        _check(bool(d.path) and Path(d.path).is_file(), "datafile.path", d.path, "must name an existing file")
        _check(len(d.materials) >= 1, "datafile.materials", d.materials,
               "must name the material of each atom type, in type order ('substrate' = fixed)")
        for i, mname in enumerate(d.materials):
            check_name(f"datafile.materials[{i}]", mname)
            _check(mname in materials or mname == "substrate", f"datafile.materials[{i}]", mname,
                   f"unknown material; known: {', '.join(materials)}, substrate")
    if spec.kind.startswith("tersoff"):
        validate_tersoff(spec)
    if spec.kind == "study":
        validate_study(spec)
    _check(spec.boundary.sides in SIDES, "boundary.sides", spec.boundary.sides,
           f"must be one of {', '.join(SIDES)}")
    if k.tile_nm:
        _check(k.tile_nm <= max(lx, ly, h), "packing.tile_nm", k.tile_nm,
               f"must be <= the largest box edge ({max(lx, ly, h):.0f} nm) or 0")


def validate_tersoff(spec: WorkflowSpec) -> None:
    """The [tersoff] and [stability] sections (atomistic workflows)."""
    from opalflow.tersoff.fit import DEFAULT_BOUNDS, PROPERTY_KEYS
    from opalflow.tersoff.parameters import COLUMNS
    from opalflow.tersoff.workflow import load_parameters

    t = spec.tersoff
    check_name("tersoff.element", t.element)
    load_parameters(t)                     # file found, entry present, values allowed
    _check(1 <= t.cells <= 10, "tersoff.cells", t.cells, "must be in [1, 10] (conventional cells per edge)")
    for i, e in enumerate([t.strain, *t.strain_scan]):
        where = "tersoff.strain" if i == 0 else f"tersoff.strain_scan[{i - 1}]"
        _check(1e-7 <= e <= 0.2, where, e, "must be in [1e-7, 0.2]")
    _check(4.0 <= t.lattice_target_A <= 7.0, "tersoff.lattice_target_A", t.lattice_target_A,
           "must be in [4, 7] A (diamond-structure lattice constant)")
    for key, value in t.targets.items():
        _check(key in PROPERTY_KEYS, f"tersoff.targets.{key}", value, f"unknown target; allowed: {', '.join(PROPERTY_KEYS)}")
        _check(not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
               and value != 0, f"tersoff.targets.{key}", value, "must be a non-zero number (errors are relative)")
    for key, value in t.weights.items():
        _check(key in PROPERTY_KEYS or key == "grad", f"tersoff.weights.{key}", value,
               f"unknown weight; allowed: grad, {', '.join(PROPERTY_KEYS)}")
        _check(not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
               and value >= 0, f"tersoff.weights.{key}", value, "must be a number >= 0")
    for i, name in enumerate(t.fixed):
        _check(name in COLUMNS, f"tersoff.fixed[{i}]", name, f"must be a parameter: {', '.join(COLUMNS)}")
    _check("m" in t.fixed, "tersoff.fixed", t.fixed, "must hold 'm' (1 or 3, not a continuous parameter)")
    for key, value in t.bounds.items():
        _check(key in COLUMNS and key not in t.fixed, f"tersoff.bounds.{key}", value,
               f"must name a free parameter: {', '.join(k for k in COLUMNS if k not in t.fixed)}")
        _check(isinstance(value, list) and len(value) == 2 and all(
            not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in value)
            and value[0] < value[1], f"tersoff.bounds.{key}", value, "must be [low, high] with low < high")
    for name in COLUMNS:
        _check(name in t.fixed or name in t.bounds or name in DEFAULT_BOUNDS, "tersoff.bounds", t.bounds,
               f"free parameter '{name}' needs bounds [low, high]")
    _check(1 <= t.starts <= 10000, "tersoff.starts", t.starts, "must be in [1, 10000]")
    _check(t.seed >= 0, "tersoff.seed", t.seed, "must be >= 0")
    _check(1 <= t.max_iter <= 100000, "tersoff.max_iter", t.max_iter, "must be in [1, 100000]")
    _check(0 <= t.rank_top <= t.starts, "tersoff.rank_top", t.rank_top,
           f"must be in [0, starts = {t.starts}] (best candidates checked for stability; 0: none)")
    s = spec.stability
    _check(len(s.boundaries) >= 1, "stability.boundaries", s.boundaries, "must name at least one")
    for i, b in enumerate(s.boundaries):
        _check(len(b) == 3 and set(b) <= {"p", "f"}, f"stability.boundaries[{i}]", b,
               "must be three letters p (periodic) or f (free), x y z: e.g. ppp, ppf, pff, fff")
    _check(len(s.temperatures_K) >= 1, "stability.temperatures_K", s.temperatures_K, "must hold at least one")
    for i, temp in enumerate(s.temperatures_K):
        _check(0 < temp <= 5000, f"stability.temperatures_K[{i}]", temp, "must be in (0, 5000] K")
    _check(0 < s.time_ps <= 1000, "stability.time_ps", s.time_ps, "must be in (0, 1000] ps")
    _check(0.01 <= s.timestep_fs <= 5, "stability.timestep_fs", s.timestep_fs, "must be in [0.01, 5] fs")
    _check(s.time_ps * 1000 / s.timestep_fs >= 10, "stability.time_ps", s.time_ps,
           "must be at least 10 time steps")
    _check(2 <= s.cells <= 20, "stability.cells", s.cells, "must be in [2, 20]")
    _check(s.seed > 0, "stability.seed", s.seed, "must be > 0 (LAMMPS velocity seed)")
    _check(s.max_drift_eV > 0, "stability.max_drift_eV", s.max_drift_eV, "must be > 0")
    _check(0 < s.min_fourfold <= 1, "stability.min_fourfold", s.min_fourfold, "must be in (0, 1]")
    _check(s.max_rms_A > 0, "stability.max_rms_A", s.max_rms_A, "must be > 0")
    _check(s.workers >= 0, "stability.workers", s.workers, "must be >= 0 (MD runs at once; 0: all cores)")


def validate_study(spec: WorkflowSpec) -> None:
    """The [study] section; the jobs' own specs are validated when the study builds them."""
    st = spec.study
    _check(st.type in STUDIES, "study.type", st.type, f"must be one of {', '.join(STUDIES)}")
    for where, name in (("study.base", st.base), ("study.paper_base", st.paper_base)):
        check_name(where, name)
    _check(st.workers >= 0, "study.workers", st.workers, "must be >= 0 (jobs at once; 0: cores / np)")
    _check(st.np >= 1, "study.np", st.np, "must be >= 1 (MPI processes per job)")
    _check(st.target_E_GPa > 0, "study.target_E_GPa", st.target_E_GPa, "must be > 0")
    _check(st.target_strength_MPa > 0, "study.target_strength_MPa", st.target_strength_MPa, "must be > 0")
    _check(0 < st.tolerance < 0.5, "study.tolerance", st.tolerance, "must be in (0, 0.5) (relative)")
    _check(2 <= st.max_runs <= 100, "study.max_runs", st.max_runs, "must be in [2, 100]")
    _check(st.jacobian in ("decoupled", "full"), "study.jacobian", st.jacobian, "must be 'decoupled' or 'full'")
    _check(0.001 <= st.fd_step <= 0.5, "study.fd_step", st.fd_step, "must be in [0.001, 0.5] (relative step, eq. 19)")
    _check(st.start_E_GPa >= 0, "study.start_E_GPa", st.start_E_GPa, "must be >= 0 (0: the material's)")
    _check(st.start_strength_MPa >= 0, "study.start_strength_MPa", st.start_strength_MPa,
           "must be >= 0 (0: the material's)")
    _check(len(st.diameters_nm) >= 1 and all(d > 0 for d in st.diameters_nm), "study.diameters_nm",
           st.diameters_nm, "must be a non-empty list of diameters > 0")
    _check(all(0 <= t < 200 for t in st.thicknesses_nm), "study.thicknesses_nm", st.thicknesses_nm,
           "must be thicknesses in [0, 200) nm")
    _check(len(st.porosities) >= 1 and all(0 < p <= 0.66 for p in st.porosities), "study.porosities",
           st.porosities, "must be porosities in (0, 0.66]")
    _check(len(st.seeds) >= 1 and all(s >= 0 for s in st.seeds) and len(set(st.seeds)) == len(st.seeds),
           "study.seeds", st.seeds, "must be distinct seeds >= 0")
    _check(len(st.cells) >= 1 and all(len(c) == 2 and min(c) >= 1 for c in st.cells), "study.cells",
           st.cells, "must be [cells_x, cells_y] pairs >= 1")
