"""Inverse-opal bonded-particle structures: spec -> Structure (Dosta et al., section 2.1).

Order of operations, as in the paper: dense random packing (periodic in x and y),
substrate = bottom particle layers, pores cut (eq. 1) with the optional coating
(eq. 2, windows kept open), bonds between all pairs within the cutoff.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from opalflow.bpm.bonds import (NetworkStatistics, bond_types_by_material, describe_network, find_bonds,
                                network_statistics)
from opalflow.bpm.scene import Scene
from opalflow.materials import material
from opalflow.opal import pores as pore_geometry
from opalflow.opal.result import OpalResult
from opalflow.packing import dense_random_packing
from opalflow.runs.result import optional
from opalflow.opal.spec import OpalWorkflow, sample_box_nm
from opalflow.opal.windows import coating_surface_distance, window_openings
from opalflow.structure import Structure, quantize
from opalflow.units import NM3_PER_UM3, density_from_nano, density_to_nano


def _random_pores(spec: OpalWorkflow, packing, substrate, box_xy, z0, height, progress):
    """Place random pores and take as many as bring the macro-porosity closest to the target.

    More pores than needed are packed (non-overlapping, collective rearrangement) in
    random order; for every particle the first pore in that order that cuts it is
    found, which gives the porosity after the first n pores for every n at once.
    The chosen n misses the target by at most half of one pore's share (about
    V_pore / V_sample = 1.5 % in the standard sample); more than ``pores.porosity_tolerance``
    is refused.  Pore centres lie anywhere
    in the sample height, so the top face cuts pores and the substrate truncates
    them, as in a sample cut out of a larger random porous body.
    """
    p = spec.pores
    R = p.diameter_nm / 2
    radii = packing.diameters / 2
    sample_volume = box_xy[0] * box_xy[1] * height
    sample = ~substrate
    n_sample = int(np.count_nonzero(sample))
    # about 10 % of each cut ball lies outside the sample (faces) on average
    n_est = p.porosity * sample_volume / (0.9 * 4 / 3 * math.pi * (R + radii.mean()) ** 3)
    rng = np.random.default_rng(p.seed)
    for margin in (1.25, 1.15, 1.05):
        try:
            centres = pore_geometry.random_centres(int(math.ceil(margin * n_est)) + 1, p.diameter_nm,
                                                   box_xy, (z0, z0 + height), rng)
            break
        except pore_geometry.PoreError:
            continue
    else:
        raise pore_geometry.PoreError(f"pores.porosity = {p.porosity}: could not place enough "
                                      "non-overlapping pores in this box")
    first = pore_geometry.first_cutting_pore(packing.positions, radii, centres, R, box_xy)
    first[substrate] = len(centres)
    counts = np.bincount(first[sample], minlength=len(centres) + 1)[:len(centres)]
    porosity_n = np.concatenate([[0.0], np.cumsum(counts) / n_sample])  # after 0..N pores
    n = int(np.argmin(np.abs(porosity_n - p.porosity)))
    if abs(porosity_n[n] - p.porosity) > p.porosity_tolerance:
        raise pore_geometry.PoreError(
            f"pores.porosity = {p.porosity}: the closest is {porosity_n[n]:.3f} with {n} pores in this box "
            f"(tolerance {p.porosity_tolerance:g}); enlarge the box or raise pores.porosity_tolerance")
    if progress:
        progress(f"random pores: {n} of {len(centres)} packed pores give porosity {porosity_n[n]:.4f} "
                 f"(target {p.porosity:.4f})")
    centres = centres[:n]
    keep, coated = pore_geometry.carve(packing.positions, radii, centres, R,
                                       spec.coating.thickness_nm, box_xy, substrate)
    return centres, keep, coated


def build_opal(spec: OpalWorkflow, progress=None) -> tuple[Structure, dict]:
    """Build the inverse-opal Structure of ``spec``; returns it and its statistics."""
    timings = {}
    d = spec.packing.diameter_nm
    lx, ly, height = sample_box_nm(spec)
    z0 = spec.substrate.layers * d
    box = np.array([lx, ly, z0 + height])
    periodic = np.array([spec.boundary.sides == "periodic"] * 2 + [False])
    fcc = spec.pores.arrangement == "fcc"

    t = time.perf_counter()
    k = spec.packing
    packing = dense_random_packing(
        box, d, k.solid_fraction, std=k.diameter_std_nm, size_bins=k.size_bins, seed=k.seed,
        tile_nm=k.tile_nm, max_overlap=k.max_overlap, method=k.method,
        coprime_with=(2 * spec.pores.cells_x, 6 * spec.pores.cells_y) if fcc else (1, 1),
        progress=(lambda s, w: progress(f"packing ({k.method}): step {s}, largest overlap {100 * w:.2f} % d"))
        if progress else None)
    timings["packing"] = time.perf_counter() - t

    t = time.perf_counter()
    substrate = packing.positions[:, 2] < z0
    box_xy = box[:2]
    centres = np.zeros((0, 3))
    keep = np.ones(len(packing.positions), bool)
    coated = np.zeros(len(packing.positions), bool)
    if fcc:
        centres = pore_geometry.fcc_centres(spec.pores.spacing_nm, spec.pores.diameter_nm,
                                            spec.pores.layers, spec.pores.cells_x, spec.pores.cells_y, z0)
        keep, coated = pore_geometry.carve(packing.positions, packing.diameters / 2, centres,
                                           spec.pores.diameter_nm / 2, spec.coating.thickness_nm,
                                           box_xy, substrate)
    elif spec.pores.arrangement == "random":
        centres, keep, coated = _random_pores(spec, packing, substrate, box_xy, z0, height, progress)
    timings["pores"] = time.perf_counter() - t

    positions = quantize(packing.positions[keep], box, periodic)
    diameters = packing.diameters[keep]
    substrate_k, coated_k = substrate[keep], coated[keep]
    type_names = [spec.material]
    types = np.ones(len(positions), np.int32)
    if substrate_k.any():
        type_names.append("substrate")
        types[substrate_k] = len(type_names)
    if coated_k.any():
        type_names.append(spec.coating.material)
        types[coated_k] = len(type_names)
    densities = np.full(len(positions), density_to_nano(material(spec.material, spec.materials).density_kg_m3))
    if coated_k.any():
        densities[coated_k] = density_to_nano(material(spec.coating.material, spec.materials).density_kg_m3)

    t = time.perf_counter()
    bonds = find_bonds(positions, diameters, box, periodic, spec.bonds.cutoff_factor, spec.bonds.min_length_factor)
    bond_types = bond_types_by_material(bonds, coated_k)
    timings["bonds"] = time.perf_counter() - t

    structure = Structure(
        positions=positions, diameters=diameters, types=types, densities=densities,
        box_lo=np.zeros(3), box_hi=box, periodic=periodic, bonds=bonds, bond_types=bond_types,
        type_names=type_names,
        bond_type_names=[spec.material] + ([spec.coating.material] if coated_k.any() else []),
        groups={"substrate": substrate_k, "coating": coated_k},
        meta={"pore_centres_nm": centres, "pore_arrangement": spec.pores.arrangement, "pore_diameter_nm": spec.pores.diameter_nm,
              "substrate_top_nm": z0, "sample_height_nm": height,
              "packing_solid_fraction": packing.solid_fraction,
              "packing_particles_in_sample": int(np.count_nonzero(~substrate)),
              "packing_solid_volume_in_sample_nm3":
                  float(np.sum(np.pi / 6 * packing.diameters[~substrate] ** 3)),
              "packing_max_overlap_fraction": packing.max_overlap_fraction,
              "packing_tile_nm": packing.tile.tolist(), "packing_tile_particles": packing.tile_particles,
              "packing_relax_steps": packing.relax_steps},
    )
    structure.meta["timings_s"] = timings
    return structure, timings


def bulk_slab(s: Structure) -> tuple[float, float]:
    """The z-range that represents the bulk opal, away from the substrate and the top.

    Between the centre planes of the lowest and the highest pore layer, each slab
    between neighbouring centre planes holds half of each of its two pore layers and
    nothing of the others (R_pore + R_part < layer spacing): the structure there is
    the infinite FCC opal.  With fewer than two pore layers (or no pores) the whole
    sample above the substrate is used.
    """
    z0 = s.meta["substrate_top_nm"]
    top = z0 + s.meta["sample_height_nm"]
    centres = np.asarray(s.meta["pore_centres_nm"]).reshape(-1, 3)
    levels = np.unique(np.round(centres[:, 2], 6)) if len(centres) else np.zeros(0)
    if s.meta.get("pore_arrangement") == "fcc" and len(levels) >= 2:
        return float(levels[0]), float(levels[-1])
    return float(z0), float(top)


@dataclass
class Windows:
    """The windows between neighbouring pores (:func:`opalflow.opal.windows.window_openings`): how many, how many
    open, and their free radius (nm)."""

    count: int
    open: int
    free_radius_nm_min: float
    free_radius_nm_mean: float


@dataclass
class OpalStatistics:
    """The numbers the paper reports about a structure (:func:`structure_statistics`); summary.json's keys."""

    n_particles: int
    n_bonds: int
    box_nm: list[float]
    sample_height_nm: float
    substrate_thickness_nm: float
    packing_fraction: float
    porosity: float
    total_porosity: float
    bonds_per_particle: float
    particles_per_um3: float
    bonds_per_um3: float
    bulk_slab_nm: list[float]
    particles_per_um3_sample: float
    bonds_per_um3_sample: float
    max_overlap_fraction: float
    n_by_material: dict[str, int]
    n_bonds_by_type: dict[str, int]
    n_pores: int
    density_kg_m3: float
    bond_length_nm: dict[str, float]
    network: NetworkStatistics
    windows: Windows | None = optional()
    coating_max_distance_to_pore_surface_nm: float | None = optional()


def structure_statistics(s: Structure) -> OpalStatistics:
    """The numbers the paper reports about a structure (section 2.1 and 4).

    ``particles_per_um3`` and ``bonds_per_um3`` (particles, and bonds by their
    midpoint) are counted in the bulk slab (:func:`bulk_slab`), the paper's "needed
    to represent 1 um^3 of FCC-ordered inverse opal"; the substrate is not in them.
    ``*_per_um3_sample`` count the whole sample above the substrate (particles in it,
    bonds with at least one end in it) per its volume, faces included.
    ``porosity`` is the macro-porosity, 1 - (particles left in the sample) / (particles
    the packing had there), the paper's measure (density = (1 - porosity) x 1297
    kg/m^3 for silica); ``total_porosity`` also counts the packing's own voids.
    ``density_kg_m3`` weighs each particle's material by the solid it stands for,
    V_p / phi (section 4: "volumetric amount and density of each component").
    """
    m = s.meta
    sample = ~s.groups.get("substrate", np.zeros(s.n_particles, bool))
    sample_volume = s.box_lengths[0] * s.box_lengths[1] * m["sample_height_nm"]
    vp = s.particle_volumes()
    phi = m["packing_solid_fraction"]
    n_sample = int(np.count_nonzero(sample))
    bonds_in_sample = int(np.count_nonzero(sample[s.bonds[:, 0]] | sample[s.bonds[:, 1]])) if s.n_bonds else 0
    d = s.bond_vectors() if s.n_bonds else np.zeros((0, 3))
    r0 = np.sqrt(np.einsum("ij,ij->i", d, d))
    contact = 0.5 * (s.diameters[s.bonds[:, 0]] + s.diameters[s.bonds[:, 1]]) if s.n_bonds else np.zeros(0)
    overlap = float(max(0.0, np.max((contact - r0) / contact))) if s.n_bonds else 0.0
    n_by_material = {name: int(np.count_nonzero(s.types == t + 1)) for t, name in enumerate(s.type_names)}
    bonds_by_type = {name: int(np.count_nonzero(s.bond_types == t + 1))
                     for t, name in enumerate(s.bond_type_names)}
    # each particle stands for V_p / phi of skeleton, and V_sample = V_solid(packing) / phi
    density = np.sum((s.densities * vp)[sample]) / m["packing_solid_volume_in_sample_nm3"]
    bulk_lo, bulk_hi = bulk_slab(s)
    in_bulk = (s.positions[:, 2] >= bulk_lo) & (s.positions[:, 2] < bulk_hi)
    bulk_volume = s.box_lengths[0] * s.box_lengths[1] * (bulk_hi - bulk_lo)
    if s.n_bonds:
        zmid = s.positions[s.bonds[:, 0], 2] + d[:, 2] / 2
        bonds_in_bulk = int(np.count_nonzero((zmid >= bulk_lo) & (zmid < bulk_hi)))
    else:
        bonds_in_bulk = 0
    pore_radius = m.get("pore_diameter_nm", 0.0) / 2
    windows = window_openings(s, pore_radius) if len(m["pore_centres_nm"]) else np.zeros(0)
    coat = coating_surface_distance(s, pore_radius)
    return OpalStatistics(
        n_particles=s.n_particles, n_bonds=s.n_bonds, box_nm=s.box_lengths.tolist(),
        sample_height_nm=m["sample_height_nm"], substrate_thickness_nm=m["substrate_top_nm"], packing_fraction=phi,
        porosity=1 - n_sample / m["packing_particles_in_sample"],
        total_porosity=1 - float(np.sum(vp[sample])) / sample_volume,
        bonds_per_particle=s.n_bonds / max(1, s.n_particles),
        particles_per_um3=int(np.count_nonzero(in_bulk)) / bulk_volume * NM3_PER_UM3,
        bonds_per_um3=bonds_in_bulk / bulk_volume * NM3_PER_UM3, bulk_slab_nm=[float(bulk_lo), float(bulk_hi)],
        particles_per_um3_sample=n_sample / sample_volume * NM3_PER_UM3,
        bonds_per_um3_sample=bonds_in_sample / sample_volume * NM3_PER_UM3, max_overlap_fraction=overlap,
        n_by_material=n_by_material, n_bonds_by_type=bonds_by_type, n_pores=int(len(m["pore_centres_nm"])),
        density_kg_m3=float(density_from_nano(density)),
        bond_length_nm={"min": float(r0.min()) if len(r0) else 0.0, "max": float(r0.max()) if len(r0) else 0.0},
        network=network_statistics(s.positions, s.diameters, s.box_lengths, s.periodic, s.bonds, phi),
        windows=Windows(int(len(windows)), int(np.count_nonzero(windows > 0)), float(windows.min()),
                        float(windows.mean())) if len(windows) else None,
        coating_max_distance_to_pore_surface_nm=float(coat.max()) if len(coat) else None)


def _describe(stats: OpalStatistics) -> str:
    return (f"{stats.n_particles} particles, {stats.n_bonds} bonds, porosity {stats.porosity:.3f}, "
            f"{stats.particles_per_um3:.0f} particles/um^3, {stats.bonds_per_um3:.0f} bonds/um^3; "
            + describe_network(stats.network))


def opal_structure(spec: OpalWorkflow, progress=None) -> Structure:
    return build_opal(spec, progress)[0]


SCENE = Scene(build=opal_structure, statistics=structure_statistics, run_keys=OpalResult.structure_keys(), describe=_describe)
