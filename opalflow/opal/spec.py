"""Spec sections of the inverse-opal scene (Dosta et al., section 2.1): packing, pores, coating,
substrate and side boundaries, on top of the compression pipeline's (:class:`BpmWorkflow`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from opalflow.bpm.spec import BoundarySpec, BpmWorkflow, check_material
from opalflow.packing import PACKING_METHODS
from opalflow.spec import SpecError, check

ARRANGEMENTS = ("fcc", "random", "none")
#: the largest sample opalflow builds (the paper's largest has 3.4 million particles)
MAX_PARTICLES = 5e7

#: the uncoated silica opal's experiment (do Rosario et al. [57], Dosta et al. 3.1.2)
EXPERIMENT_SILICA_OPAL = {"youngs_modulus_GPa": (1.7, "experiment, do Rosario et al. via Dosta et al. 3.1.2"),
                          "strength_MPa": (41.3, "experiment, do Rosario et al. via Dosta et al. 3.1.2")}


@dataclass
class PackingSpec:
    """Dense random packing of spheres (the solid skeleton before pores are cut)."""

    diameter_nm: float = 15.0        # mean particle diameter (Dosta et al. 2.1: 15 nm silica)
    solid_fraction: float = 0.62     # volume fraction of the packing before pores are cut (at most ~0.64, jamming)
    diameter_std_nm: float = 0.0     # standard deviation of the diameters (0: monodisperse)
    #: polydisperse diameters snapped to this many equal-probability sizes (one LAMMPS type each)
    size_bins: int = 8
    seed: int = 1                    # random seed of the packing
    #: edge of the periodic tile packed and repeated over the box (0: the whole box as one tile)
    tile_nm: float = 380.0
    max_overlap: float = 0.005       # the packing is relaxed until the largest overlap is below this x d
    #: the tile's relaxation: "fire" (LAMMPS's FIRE) or "musen" (the paper's generator's rule: opalflow.packing)
    method: str = "fire"


@dataclass
class PoresSpec:
    """Macropores cut out of the packing (eq. 1 of Dosta et al.)."""

    #: fcc: the inverse opal's ordered pores; random: random pores (porosity); none: no pores
    arrangement: str = "fcc"
    diameter_nm: float = 762.0       # pore diameter (the template's spheres)
    spacing_nm: float = 762.0        # nearest-neighbour distance of the FCC pore lattice (= diameter: touching pores)
    layers: int = 3                  # (111) pore layers stacked on the substrate (the sample's height)
    cells_x: int = 4                 # the box in x: this many cells of spacing_nm
    cells_y: int = 2                 # the box in y: this many cells of spacing_nm x sqrt(3) (two pores per layer each)
    porosity: float | None = None    # random: the macro-porosity to reach (pores taken until closest to it)
    porosity_tolerance: float = 0.01  # random: refused if the closest porosity the box allows is farther than this
    seed: int = 1                    # random: seed of the pores' positions


@dataclass
class CoatingSpec:
    """Coating of the pore walls (eq. 2); thickness 0 means uncoated."""

    thickness_nm: float = 0.0        # coating thickness on the pore walls, eq. 2 (0: uncoated)
    material: str = "titania"        # the coating's material (data/materials.toml)


@dataclass
class SubstrateSpec:
    """Fixed bottom particle layers."""

    layers: int = 2                  # fixed particle layers at the bottom (in particle diameters): the support


@dataclass
class OpalWorkflow(BpmWorkflow):
    """An inverse opal (kind = "opal") compressed by a plate."""

    packing: PackingSpec = field(default_factory=PackingSpec)
    pores: PoresSpec = field(default_factory=PoresSpec)
    coating: CoatingSpec = field(default_factory=CoatingSpec)
    substrate: SubstrateSpec = field(default_factory=SubstrateSpec)
    boundary: BoundarySpec = field(default_factory=BoundarySpec)

    def references(self) -> dict[str, tuple[float, str]]:
        """The experiment for the uncoated FCC silica opal; none for other opals."""
        uncoated_fcc_silica = (self.pores.arrangement == "fcc" and self.coating.thickness_nm == 0
                               and self.material == "silica")
        return dict(EXPERIMENT_SILICA_OPAL) if uncoated_fcc_silica else {}

    def validate(self) -> None:
        super().validate()
        k = self.packing
        check(1e-3 <= k.diameter_nm <= 1e5, "packing.diameter_nm", k.diameter_nm, "must be in [1e-3, 1e5] nm")
        check(0.05 <= k.solid_fraction <= 0.64, "packing.solid_fraction", k.solid_fraction,
              "must be in [0.05, 0.64] (random close packing of spheres is about 0.64)")
        check(0 <= k.diameter_std_nm <= 0.3 * k.diameter_nm, "packing.diameter_std_nm", k.diameter_std_nm,
              f"must be in [0, 0.3 diameter_nm = {0.3 * k.diameter_nm:g}] (sizes are cut at +-3 std)")
        check(1 <= k.size_bins <= 64, "packing.size_bins", k.size_bins, "must be in [1, 64]")
        check(k.seed >= 0, "packing.seed", k.seed, "must be >= 0")
        check(k.tile_nm == 0 or k.tile_nm >= 8 * k.diameter_nm, "packing.tile_nm", k.tile_nm,
              f"must be 0 (pack the whole box) or >= 8 particle diameters ({8 * k.diameter_nm:g} nm)")
        check(k.method in PACKING_METHODS, "packing.method", k.method, f"must be one of {', '.join(PACKING_METHODS)}")
        check(0 < k.max_overlap <= 0.01, "packing.max_overlap", k.max_overlap,
              "must be in (0, 0.01] (fraction of the diameter)")

        p = self.pores
        check(p.arrangement in ARRANGEMENTS, "pores.arrangement", p.arrangement,
              f"must be one of {', '.join(ARRANGEMENTS)}")
        check(p.diameter_nm > 2 * k.diameter_nm, "pores.diameter_nm", p.diameter_nm,
              f"must be > 2 particle diameters ({2 * k.diameter_nm:g} nm)")
        check(p.spacing_nm >= 0.75 * p.diameter_nm, "pores.spacing_nm", p.spacing_nm,
              f"must be >= 0.75 x pores.diameter_nm ({0.75 * p.diameter_nm:g} nm)")
        check(1 <= p.layers <= 100, "pores.layers", p.layers, "must be in [1, 100]")
        check(1 <= p.cells_x <= 100, "pores.cells_x", p.cells_x, "must be in [1, 100]")
        check(1 <= p.cells_y <= 100, "pores.cells_y", p.cells_y, "must be in [1, 100]")
        check(p.seed >= 0, "pores.seed", p.seed, "must be >= 0")
        if p.arrangement == "random":
            check(p.porosity is not None, "pores.porosity", p.porosity,
                  "required for arrangement = 'random' (target macro-porosity)")
            check(0 < p.porosity < 1, "pores.porosity", p.porosity, "must be in (0, 1)")
            check(p.porosity <= 0.66, "pores.porosity", p.porosity,
                  "must be <= 0.66: denser random non-overlapping pores cannot be placed")
            check(0 < p.porosity_tolerance <= 0.2, "pores.porosity_tolerance", p.porosity_tolerance,
                  "must be in (0, 0.2] (a small box holds few pores: each moves the porosity by its share)")
        elif p.porosity is not None:
            raise SpecError("pores.porosity", p.porosity,
                            "only allowed with arrangement = 'random' (fcc porosity follows from the lattice)")
        lx, ly, h = sample_box_nm(self)
        height = h + self.substrate.layers * k.diameter_nm
        n_est = k.solid_fraction * lx * ly * height / (math.pi / 6 * k.diameter_nm**3)
        check(n_est <= MAX_PARTICLES, "packing.diameter_nm", k.diameter_nm,
              f"a {lx:.4g} x {ly:.4g} x {height:.4g} nm sample of these particles holds ~{n_est:.2g}; at most "
              f"{MAX_PARTICLES:.0e} (larger particles or fewer cells and layers)")
        if p.arrangement != "none":
            check(p.diameter_nm <= min(lx, ly, h), "pores.diameter_nm", p.diameter_nm,
                  f"pores larger than the box ({lx:.0f} x {ly:.0f} x {h:.0f} nm); "
                  "add cells or layers, or make the pores smaller")

        c = self.coating
        check_material("coating.material", c.material)
        check(c.thickness_nm >= 0, "coating.thickness_nm", c.thickness_nm, "must be >= 0")
        if c.thickness_nm > 0:
            check(p.arrangement != "none", "coating.thickness_nm", c.thickness_nm,
                  "a coating needs pores (pores.arrangement = 'none')")
            limit = max_coating_nm(self)
            check(c.thickness_nm < limit, "coating.thickness_nm", c.thickness_nm,
                  f"coating thicker than the struts: must be < {limit:.1f} nm, the radius of the "
                  "largest solid region between pores")
        check(0 <= self.substrate.layers <= 10, "substrate.layers", self.substrate.layers, "must be in [0, 10]")
        self.boundary.validate()
        if k.tile_nm:
            check(k.tile_nm <= max(lx, ly, h), "packing.tile_nm", k.tile_nm,
                  f"must be <= the largest box edge ({max(lx, ly, h):.0f} nm) or 0")


def sample_box_nm(spec: OpalWorkflow) -> tuple[float, float, float]:
    """Lateral size and pore-region height of the sample (nm), from the FCC cell.

    The cell is rectangular: spacing x spacing*sqrt(3) in plane (two pores per
    (111) layer), layer spacing spacing*sqrt(2/3); the height holds ``layers``
    pore layers touching the bottom and top faces: 2 R + (layers - 1) h.
    """
    p = spec.pores
    a = p.spacing_nm
    h = a * math.sqrt(2.0 / 3.0)
    return p.cells_x * a, p.cells_y * a * math.sqrt(3.0), p.diameter_nm + (p.layers - 1) * h


def max_coating_nm(spec: OpalWorkflow) -> float:
    """Thickest coating that still leaves silica: radius of the largest solid region.

    For the FCC pore lattice with nearest-neighbour spacing a that is the octahedral
    hole, a / sqrt(2) - R_pore; random pores use the same bound for a = D_pore.
    """
    p = spec.pores
    a = p.spacing_nm if p.arrangement == "fcc" else p.diameter_nm
    return a / math.sqrt(2.0) - p.diameter_nm / 2.0
