"""The aerogel scene: an aggregate bonded at its contacts, whole (periodic cube) or cut to a slab.

Bonds join every pair whose centre distance is within ``bonds.cutoff_factor`` of its contact distance
r_i + r_j (1.001 by default: the contacts the aggregation made, which leave a tree, plus near-contacts
that close loops), across the periodic boundaries too.

The slab for the compression (kind ``aerogel``): the periodic aggregate is cut open by a horizontal
plane (bonds that cross it are dropped; x and y stay periodic, so the network is infinite sideways);
the spheres whose centres lie within one mean diameter above the plane are the fixed substrate (the
bottom wall the network is attached to), and every sphere with no bond path to the substrate (pieces the
cut set free: they would float) is left out and counted.  A DLCA network is nearly a tree, so a cut
frees whole branches: of CUTS planes at heights k L / CUTS the one that keeps the most spheres is taken
(deterministic).  The top is loaded by ``compression.loading``: "glued" (the aerogel workflows: the top
layer moves with the wall, as the bottom layer is held by the substrate) or "plate" (PFC's contact-only
wall, which loads the network where it reaches highest).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from opalflow.aerogel.aggregation import Aggregate, aggregate, box_edge, gaussian_diameters
from opalflow.aerogel.spec import RANDOM_PLACEMENT_MAX, AggregateSpec, AerogelWorkflow
from opalflow.bpm.bonds import find_bonds
from opalflow.bpm.scene import Scene
from opalflow.materials import material
from opalflow.structure import Structure, quantize
from opalflow.units import density_to_nano


def make_aggregate(a: AggregateSpec, progress=None) -> Aggregate:
    """The aggregate of an ``[aggregate]`` section (seeded: the same section gives the same spheres)."""
    d = gaussian_diameters(a.particles, a.diameter_nm, a.diameter_std_nm, np.random.default_rng(a.seed))

    def said(left, n, moves, rate, eta):
        eta_txt = "time left not known yet" if math.isnan(eta) else f"up to about {eta:.0f} s left"
        progress(f"  aggregation: {left} clusters of {n} spheres left, {moves} moves ({rate:,.0f}/s), {eta_txt}")

    return aggregate(d, box_edge(d, a.solid_fraction), seed=a.seed, step_fraction=a.step_fraction,
                     mobility_exponent=a.mobility_exponent,
                     sticking_probability=a.sticking_probability if a.algorithm == "rlca" else 1.0,
                     progress=said if progress else None, random_placement_max=RANDOM_PLACEMENT_MAX)


def coordination(n: int, bonds: np.ndarray) -> np.ndarray:
    """Bonds per sphere."""
    return np.bincount(bonds.ravel(), minlength=n)


def periodic_structure(agg: Aggregate, cutoff_factor: float, material_name: str, overrides=None) -> Structure:
    """The whole aggregate bonded at its contacts, periodic in x, y and z (no substrate)."""
    box = np.full(3, agg.box)
    periodic = np.ones(3, bool)
    x = quantize(agg.positions, box, periodic)
    bonds = find_bonds(x, agg.diameters, box, periodic, cutoff_factor)
    rho = density_to_nano(material(material_name, overrides)["density_kg_m3"])
    return Structure(positions=x, diameters=agg.diameters.copy(), types=np.ones(len(x), np.int32),
                     densities=np.full(len(x), rho), box_lo=np.zeros(3), box_hi=box, periodic=periodic,
                     bonds=bonds, bond_types=np.ones(len(bonds), np.int32), type_names=[material_name],
                     bond_type_names=[material_name],
                     meta={"solid_fraction": agg.solid_fraction})


#: candidate heights of the cut plane (fractions of the cube edge)
CUTS = 16


def _attached(z: np.ndarray, bonds: np.ndarray, box: float, d_mean: float) -> np.ndarray:
    """Spheres with a bond path to the bottom layer (centres below d_mean) once bonds across z = 0 = box
    are cut, for heights z in [0, box)."""
    n = len(z)
    keep = np.abs(z[bonds[:, 1]] - z[bonds[:, 0]]) < box / 2
    b = bonds[keep]
    _, label = connected_components(coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(n, n)), directed=False)
    return np.isin(label, np.unique(label[z < d_mean]))


def slab(agg: Aggregate, cutoff_factor: float, material_name: str, overrides=None) -> Structure:
    """The aggregate cut open at the best of CUTS heights, its bottom layer fixed, free pieces left out and
    the box in z opened by half the height on both sides (see the module docstring)."""
    box = np.full(3, agg.box)
    x = quantize(agg.positions, box, np.ones(3, bool))
    whole = find_bonds(x, agg.diameters, box, np.ones(3, bool), cutoff_factor)
    d_mean = float(np.mean(agg.diameters))
    counts = [int(_attached(np.mod(x[:, 2] - k * agg.box / CUTS, agg.box), whole, agg.box, d_mean).sum())
              for k in range(CUTS)]
    best = int(np.argmax(counts))
    x[:, 2] = np.mod(x[:, 2] - best * agg.box / CUTS, agg.box)
    x = quantize(x, box, np.ones(3, bool))
    keep = np.abs(x[whole[:, 1], 2] - x[whole[:, 0], 2]) < agg.box / 2
    bonds = whole[keep]
    n = len(x)
    substrate = x[:, 2] < d_mean
    attached = _attached(x[:, 2], whole, agg.box, d_mean)
    rho = density_to_nano(material(material_name, overrides)["density_kg_m3"])
    # z is not periodic: room for the network to bulge or lose pieces without atoms leaving the box
    lo, hi = np.array([0.0, 0.0, -agg.box / 2]), np.array([agg.box, agg.box, 1.5 * agg.box])
    s = Structure(positions=x, diameters=agg.diameters.copy(), types=np.where(substrate, 2, 1).astype(np.int32),
                  densities=np.full(n, rho), box_lo=lo, box_hi=hi, periodic=np.array([True, True, False]),
                  bonds=bonds, bond_types=np.ones(len(bonds), np.int32), molecules=np.ones(n, np.int32),
                  type_names=[material_name, "substrate"], bond_type_names=[material_name],
                  groups={"substrate": substrate})
    kept = s.select(attached)
    kept.meta = {"aggregate_solid_fraction": agg.solid_fraction,
                 "solid_fraction": float(np.sum(kept.particle_volumes()) / agg.box**3),
                 "dropped_unattached": int(n - attached.sum()), "cut_bonds": int(len(whole) - len(bonds)),
                 "cut_height_nm": best * agg.box / CUTS, "box_nm": agg.box,
                 "aggregation_s": agg.wall_s, "aggregation_moves": agg.moves}
    return kept


def build_aerogel(spec: AerogelWorkflow, progress=None) -> Structure:
    agg = make_aggregate(spec.aggregate, progress)
    return slab(agg, spec.bonds.cutoff_factor, spec.material, spec.materials)


def statistics(s: Structure) -> dict:
    """Numbers about the slab for the build and run summaries."""
    n = s.n_particles
    z = coordination(n, s.bonds)
    volume = float(s.meta["box_nm"]) ** 3        # the cube the aggregate filled (the z box has room around it)
    mass = float(np.sum(s.densities * s.particle_volumes()))
    return {"n_particles": n, "n_bonds": s.n_bonds, "solid_fraction": s.meta["solid_fraction"],
            "aggregate_solid_fraction": s.meta["aggregate_solid_fraction"],
            "density_kg_m3": mass / volume * 1e6, "mean_coordination": float(z.mean()),
            "dangling_fraction": float(np.mean(z <= 1)), "dropped_unattached": s.meta["dropped_unattached"],
            "cut_bonds": s.meta["cut_bonds"], "aggregation_s": s.meta["aggregation_s"]}


#: what each run summary carries of the statistics (the density study plots against them)
RUN_KEYS = ("solid_fraction", "density_kg_m3", "mean_coordination", "dropped_unattached")


def _describe(st: dict) -> str:
    return (f"aerogel slab: {st['n_particles']} spheres, {st['n_bonds']} bonds (coordination "
            f"{st['mean_coordination']:.2f}), solid fraction {st['solid_fraction']:.4f} "
            f"({st['dropped_unattached']} spheres left out: no bond path to the bottom after the cut)")


SCENE = Scene(build=build_aerogel, statistics=statistics, run_keys=RUN_KEYS, describe=_describe)
