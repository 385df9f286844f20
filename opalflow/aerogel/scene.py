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
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from opalflow.aerogel.aggregation import Aggregate, aggregate, box_edge, gaussian_diameters
from opalflow.aerogel.loops import bond_cutoff, deflect_dangling, loop_statistics, network_bonds, winding_rank
from opalflow.aerogel.result import AerogelResult
from opalflow.aerogel.spec import RANDOM_PLACEMENT_MAX, AggregateSpec, AerogelWorkflow
from opalflow.bpm.scene import Scene
from opalflow.materials import material
from opalflow.spec import SpecError
from opalflow.structure import Structure, quantize
from opalflow.units import density_to_nano


def make_aggregate(a: AggregateSpec, cutoff_factor: float, progress=None) -> tuple[Aggregate, float, dict]:
    """The aggregate of an ``[aggregate]`` section (seeded: the same section gives the same spheres) with its
    loop model applied, the bond cutoff (multiple of r_i + r_j) of its network, and what the model did."""
    d = gaussian_diameters(a.particles, a.diameter_nm, a.diameter_std_nm, np.random.default_rng(a.seed))

    def said(left, n, moves, rate, eta):
        eta_txt = "time left not known yet" if math.isnan(eta) else f"up to about {eta:.0f} s left"
        progress(f"  aggregation: {left} clusters of {n} spheres left, {moves} moves ({rate:,.0f}/s), {eta_txt}")

    agg = aggregate(d, box_edge(d, a.solid_fraction), seed=a.seed, step_fraction=a.step_fraction,
                    mobility_exponent=a.mobility_exponent,
                    sticking_probability=a.sticking_probability if a.algorithm == "rlca" else 1.0,
                    stepping=a.stepping, restructure=a.loops == "restructuring", progress=said if progress else None,
                    random_placement_max=RANDOM_PLACEMENT_MAX)
    done = {"model": a.loops}
    if a.loops == "deflection":
        agg, counts = deflect_dangling(agg, cutoff_factor)
        done.update(counts)
        if progress:
            progress(f"  loops: {counts['deflected']} of {counts['dangling_before']} dangling spheres deflected to a "
                     f"second contact ({counts['left_dangling']} had none within reach)")
    return agg, bond_cutoff(a.loops, cutoff_factor, a.neck_gap), done


def coordination(n: int, bonds: np.ndarray) -> np.ndarray:
    """Bonds per sphere."""
    return np.bincount(bonds.ravel(), minlength=n)


def periodic_structure(agg: Aggregate, cutoff: float, material_name: str, overrides=None) -> Structure:
    """The whole aggregate bonded within ``cutoff`` x (r_i + r_j), periodic in x, y and z (no substrate)."""
    box = np.full(3, agg.box)
    x, bonds = network_bonds(agg, cutoff)
    rho = density_to_nano(material(material_name, overrides).density_kg_m3)
    return Structure(positions=x, diameters=agg.diameters.copy(), types=np.ones(len(x), np.int32),
                     densities=np.full(len(x), rho), box_lo=np.zeros(3), box_hi=box, periodic=np.ones(3, bool),
                     bonds=bonds, bond_types=np.ones(len(bonds), np.int32), type_names=[material_name],
                     bond_type_names=[material_name],
                     meta={"solid_fraction": agg.solid_fraction, "aggregate_solid_fraction": agg.solid_fraction,
                           "dropped_unattached": 0, "cut_bonds": 0, "box_nm": agg.box,
                           "aggregation_s": agg.wall_s, "aggregation_moves": agg.moves})


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


def slab(agg: Aggregate, cutoff: float, material_name: str, overrides=None) -> Structure:
    """The aggregate cut open at the best of CUTS heights, its bottom layer fixed, free pieces left out and
    the box in z opened by half the height on both sides (see the module docstring)."""
    box = np.full(3, agg.box)
    x, whole = network_bonds(agg, cutoff)
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
    rho = density_to_nano(material(material_name, overrides).density_kg_m3)
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
    """The slab (or with ``sample.periodic_z`` the periodic cube) of the spec's aggregate and loop model."""
    agg, cutoff, done = make_aggregate(spec.aggregate, spec.bonds.cutoff_factor, progress)
    if spec.sample.periodic_z:
        s = periodic_structure(agg, cutoff, spec.material, spec.materials)
        wraps = winding_rank(s.positions, s.bonds, agg.box)
        if wraps < 3:
            raise SpecError("sample.periodic_z", True, f"this network wraps around the periodic cube in {wraps} of 3 "
                            "directions (off-lattice cluster aggregation joins rigid clusters at contacts, so the "
                            "gel is a finite piece interleaved with its own images): it has no stiffness as a "
                            "periodic solid; use the slab (sample.periodic_z = false)")
    else:
        s = slab(agg, cutoff, spec.material, spec.materials)
    s.meta["loop_model"] = done
    return s


@dataclass
class AerogelStatistics:
    """Numbers about the slab (or cube) for the build and run summaries: its spheres and bonds, its solid fraction
    and the aggregate's, its density (the slab's mass over the aggregate's cube, kg/m^3), the network's loops, the
    loop model's record, what the cut left out, and the aggregation's time."""

    n_particles: int
    n_bonds: int
    solid_fraction: float
    aggregate_solid_fraction: float
    density_kg_m3: float
    mean_coordination: float
    dangling_fraction: float
    loops: int
    loops_per_10k: float
    loop_model: dict
    sample: str
    dropped_unattached: int
    cut_bonds: int
    aggregation_s: float


def statistics(s: Structure) -> AerogelStatistics:
    """Numbers about the slab for the build and run summaries."""
    n = s.n_particles
    volume = float(s.meta["box_nm"]) ** 3        # the cube the aggregate filled (the z box has room around it)
    mass = float(np.sum(s.densities * s.particle_volumes()))
    loops = loop_statistics(n, s.bonds)
    return AerogelStatistics(
        n_particles=n, n_bonds=s.n_bonds, solid_fraction=s.meta["solid_fraction"],
        aggregate_solid_fraction=s.meta["aggregate_solid_fraction"], density_kg_m3=mass / volume * 1e6,
        mean_coordination=loops.mean_coordination, dangling_fraction=loops.dangling_fraction, loops=loops.loops,
        loops_per_10k=loops.loops_per_10k, loop_model=s.meta.get("loop_model", {"model": "none"}),
        sample="cube" if s.periodic[2] else "slab", dropped_unattached=s.meta["dropped_unattached"],
        cut_bonds=s.meta["cut_bonds"], aggregation_s=s.meta["aggregation_s"])


def _describe(st: AerogelStatistics) -> str:
    model = st.loop_model.get("model")
    if st.sample == "cube":
        return (f"aerogel cube (periodic in x, y, z): {st.n_particles} spheres, {st.n_bonds} bonds (coordination "
                f"{st.mean_coordination:.2f}, {st.loops_per_10k:.0f} loops per 10 000 spheres, loop model "
                f"{model}), solid fraction {st.solid_fraction:.4f}")
    return (f"aerogel slab: {st.n_particles} spheres, {st.n_bonds} bonds (coordination "
            f"{st.mean_coordination:.2f}, {st.loops_per_10k:.0f} loops per 10 000 spheres, loop model "
            f"{model}), solid fraction {st.solid_fraction:.4f} "
            f"({st.dropped_unattached} spheres left out: no bond path to the bottom after the cut)")


SCENE = Scene(build=build_aerogel, statistics=statistics, run_keys=AerogelResult.structure_keys(), describe=_describe)
