"""Dense random packing of spheres, periodic in x and y.

Method
------
A periodic *tile* is packed by overlap relaxation and replicated over the box:

1. ``N = phi V / <V_p>`` sphere centres are drawn uniformly at random in a fully
   periodic tile (reduced units, mean diameter 1).  Diameters are monodisperse or
   drawn from a normal distribution and snapped to ``size_bins`` equal-probability
   bins (one LAMMPS type each).
2. The harmonic overlap energy ``U = sum_ij k (d_ij - r_ij)^2`` (r_ij < d_ij, the
   ``pair_style harmonic/cut`` of LAMMPS) is minimised with FIRE (Bitzek et al.,
   PRL 97, 170201 (2006)) in the LAMMPS library, in chunks of 200 steps, until the
   largest overlap is below ``max_overlap`` x d.  Below the jamming density
   (phi_J ~ 0.64 for monodisperse spheres) U reaches zero, so any phi <= 0.64 is
   reached at exactly the requested solid fraction - the same end state as the
   force-biased algorithm the paper used (Mościński, Bargieł et al., Mol. Simul. 3,
   201 (1989)), without its shrinking outer diameter.
3. The tile is repeated over the box and cropped in z.  Its x and y edges divide
   the box edges, so the packing stays periodic in x and y; the numbers of tiles
   along x and y are chosen coprime with the numbers of pore columns and rows of
   the FCC pore lattice so that no two pores see the same stretch of packing.

``method = "musen"`` relaxes the same tile by the paper's own generator instead of FIRE (MUSEN's
PackageGenerator, Dosta et al. ref. [17], read from its source; :func:`push_apart`): every particle has the
same mass, overlaps push pairs apart with a linear force k delta, velocities keep 0.4 of the last step's,
a step that would move a particle by more than 0.1 of its radius is undone and k divided by 1.2, k is
multiplied by 1.2 while every particle moves less than 0.01 of its radius (k within [0.001, 0.05]), and it
stops as soon as the largest overlap is below the target (checked every 10 steps).  It leaves pairs
overlapping by up to the target where FIRE, checked every 200 steps, overshoots it (the pore-free block at
d = 40 nm: 2.78 pairs a particle overlapping against none), and MUSEN's default bonding
(``bonds.min_length_factor = 1``) leaves those pairs unbonded.

Why: a 1000-step FIRE relaxation of a ~20 000-particle tile takes a few seconds,
while relaxing the 5.7 million particles of the paper's standard sample directly
would take about 20 minutes on one core; the tile length (default 380 nm, 25 d) is
far above the packing's correlation length (a few d).  ``tile_nm = 0`` packs the
whole box as one tile (no repetition) for users who want that.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opalflow.jit import njit
from opalflow.lammps.engine import new_lammps
from opalflow.lammps.syntax import num
from opalflow.neighbors import pairs_within, separations

CHUNK_STEPS = 200
FIRE_MAX_STEPS = 40_000
#: packing relaxations (``packing.method``): LAMMPS's FIRE, the paper's generator (module docstring)
PACKING_METHODS = ("fire", "musen")
#: ``push_apart`` gives up after this many steps
PUSH_MAX_STEPS = 400_000


class PackingError(RuntimeError):
    """The relaxation did not remove the overlaps."""


@dataclass
class Packing:
    positions: np.ndarray          # (N, 3) nm
    diameters: np.ndarray          # (N,) nm
    box: np.ndarray                # (3,) nm, lower corner at 0
    tile: np.ndarray               # (3,) nm
    tile_particles: int
    max_overlap_fraction: float    # largest overlap / mean pair diameter
    relax_steps: int

    @property
    def solid_fraction(self) -> float:
        return float(np.sum(np.pi / 6 * self.diameters**3) / np.prod(self.box))


def sample_diameters(n: int, mean: float, std: float, bins: int, rng) -> np.ndarray:
    """Diameters: all ``mean`` (std = 0) or a normal distribution snapped to bin means.

    The normal distribution is truncated at +-3 std and cut into ``bins`` bins of
    equal probability; each particle gets its bin's mean diameter, so the packing
    needs one LAMMPS type per bin.
    """
    if std == 0 or bins == 1:
        return np.full(n, mean)
    from scipy.stats import truncnorm

    dist = truncnorm(-3, 3, loc=mean, scale=std)
    edges = dist.ppf(np.linspace(0, 1, bins + 1))
    # bin means by integrating x f(x) over each bin (numerically, fine grid)
    xs = np.linspace(edges[0], edges[-1], 20001)
    w = dist.pdf(xs)
    idx = np.clip(np.searchsorted(edges, xs, side="right") - 1, 0, bins - 1)
    means = np.bincount(idx, xs * w, bins) / np.bincount(idx, w, bins)
    which = np.minimum((rng.random(n) * bins).astype(np.int64), bins - 1)
    return means[which]


def relax_tile(tile: np.ndarray, diameters: np.ndarray, rng, max_overlap: float,
               progress=None) -> tuple[np.ndarray, float, int]:
    """Random centres in a periodic ``tile`` relaxed to overlaps < max_overlap (reduced units)."""
    n = len(diameters)
    x = rng.random((n, 3)) * tile
    sizes, kind = np.unique(diameters, return_inverse=True)
    lmp = new_lammps(suffix="")      # never accelerated: the relaxation is chaotic, the packing must not depend on it
    try:
        lmp.commands_string(f"""
units lj
atom_style atomic
atom_modify map array sort 0 0
region tile block 0 {num(tile[0])} 0 {num(tile[1])} 0 {num(tile[2])}
create_box {len(sizes)} tile
mass * 1.0
pair_style harmonic/cut
neighbor 0.1 bin
neigh_modify every 1 delay 0 check yes
timestep 0.2
min_style fire
min_modify integrator verlet tmax 5
""")
        for a in range(len(sizes)):
            for b in range(a, len(sizes)):
                lmp.command(f"pair_coeff {a + 1} {b + 1} 1.0 {num(0.5 * (sizes[a] + sizes[b]))}")
        lmp.create_atoms(n, np.arange(1, n + 1).tolist(), (kind + 1).tolist(), x.ravel().tolist())
        steps, worst = 0, math.inf
        while steps < FIRE_MAX_STEPS:
            lmp.command(f"minimize 0 0 {CHUNK_STEPS} {10 * CHUNK_STEPS}")
            steps += CHUNK_STEPS
            x = np.array(lmp.gather_atoms("x", 1, 3), dtype=np.float64).reshape(n, 3)
            x %= tile
            worst = max_pair_overlap(x, diameters, tile)
            if progress:
                progress(steps, worst)
            if worst < max_overlap:
                return x, worst, steps
    finally:
        lmp.close()
    raise PackingError(f"packing did not reach overlaps < {max_overlap:g} d after {FIRE_MAX_STEPS} FIRE "
                       f"steps (largest {worst:.3g} d); lower packing.solid_fraction")


def push_apart(tile: np.ndarray, diameters: np.ndarray, rng, max_overlap: float,
               progress=None) -> tuple[np.ndarray, float, int]:
    """Random centres in a periodic ``tile`` (reduced units: mean diameter 1) pushed apart by MUSEN's package
    generator's rule (module docstring) until the largest overlap is below ``max_overlap``."""
    from scipy.spatial import cKDTree

    n = len(diameters)
    x = rng.random((n, 3)) * tile
    r = diameters / 2
    skin = 0.3
    k, v_kept = 0.001, np.zeros((n, 3))
    pairs, x_listed = None, None
    worst = math.inf
    for step in range(PUSH_MAX_STEPS):
        if pairs is None or np.max(np.abs(x - x_listed)) > skin / 2:
            tree = cKDTree(np.mod(x, tile), boxsize=tile)
            pairs = tree.query_pairs(float(diameters.max()) + skin, output_type="ndarray").astype(np.int64)
            x_listed = x.copy()
        if step % 10 == 0:
            worst = _largest_overlap(x, r, pairs, tile)
            if progress and step % 10_000 == 0:
                progress(step, worst)
            if worst < max_overlap:
                return np.mod(x, tile), worst, step
        v = 0.4 * v_kept + _overlap_forces(x, r, pairs, tile, k)
        if np.max(np.sqrt(np.einsum("ij,ij->i", v, v)) / r) > 0.1:      # too far: undo, softer
            v_kept[:] = 0.0
            k /= 1.2
            continue
        x += v
        v_kept = v
        if np.max(np.sqrt(np.einsum("ij,ij->i", v, v)) / r) < 0.01 and k < 0.05:
            k *= 1.2
    raise PackingError(f"packing did not reach overlaps < {max_overlap:g} d after {PUSH_MAX_STEPS} steps of MUSEN's "
                       f"rule (largest {worst:.3g} d); lower packing.solid_fraction")


@njit(cache=True, nogil=True)
def _overlap_forces(x, r, pairs, tile, k):
    f = np.zeros_like(x)
    for p in range(len(pairs)):
        i, j = pairs[p, 0], pairs[p, 1]
        d = x[j] - x[i]
        d -= tile * np.round(d / tile)
        dist = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        overlap = r[i] + r[j] - dist
        if overlap > 0 and dist > 0:
            push = k * overlap / dist * d
            f[i] -= push
            f[j] += push
    return f


@njit(cache=True, nogil=True)
def _largest_overlap(x, r, pairs, tile):
    worst = 0.0
    for p in range(len(pairs)):
        i, j = pairs[p, 0], pairs[p, 1]
        d = x[j] - x[i]
        d -= tile * np.round(d / tile)
        worst = max(worst, (r[i] + r[j] - math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)) / (r[i] + r[j]))
    return worst


#: ``packing.method`` -> the tile's relaxation
TILE_RELAXATIONS = {"fire": relax_tile, "musen": push_apart}


def max_pair_overlap(x: np.ndarray, diameters: np.ndarray, box: np.ndarray,
                     periodic=(True, True, True)) -> float:
    """Largest (d_ij - r_ij) / d_ij over all pairs, 0 if none overlap."""
    pairs = pairs_within(x, float(diameters.max()), box, periodic)
    if len(pairs) == 0:
        return 0.0
    d = separations(x, pairs, box, periodic)
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    dij = 0.5 * (diameters[pairs[:, 0]] + diameters[pairs[:, 1]])
    return float(max(0.0, np.max((dij - r) / dij)))


def tile_count(length: float, target: float, coprime_with: int) -> int:
    """Number of tiles along an edge: near length/target, coprime with ``coprime_with``."""
    n0 = max(1, round(length / target))
    for step in range(0, 64):
        for n in (n0 + step, n0 - step):
            if n >= 1 and math.gcd(n, coprime_with) == 1 and length / n <= 2 * target:
                return n
    return n0


def dense_random_packing(box: np.ndarray, diameter: float, solid_fraction: float, *,
                         std: float = 0.0, size_bins: int = 8, seed: int = 1, tile_nm: float = 380.0,
                         max_overlap: float = 0.005, coprime_with: tuple[int, int] = (1, 1),
                         method: str = "fire", progress=None) -> Packing:
    """Pack spheres at ``solid_fraction`` in ``box`` (nm; x, y periodic), see the module doc.

    Parameters
    ----------
    box : (3,) box edges in nm; the packing fills [0, box).
    diameter, std : mean and standard deviation of the particle diameter (nm).
    solid_fraction : phi, volume of spheres / volume of the box.
    seed : random seed; the same arguments give the same bytes.
    tile_nm : edge of the periodic tile (0: the whole box is one tile).
    coprime_with : tile counts along x and y are made coprime with these numbers.
    method : the tile's relaxation, one of :data:`PACKING_METHODS` (module docstring).
    """
    box = np.asarray(box, dtype=float)
    rng = np.random.default_rng(seed)
    if tile_nm:
        nx = tile_count(box[0], tile_nm, coprime_with[0])
        ny = tile_count(box[1], tile_nm, coprime_with[1])
        tile = np.array([box[0] / nx, box[1] / ny, tile_nm])
    else:
        nx = ny = 1
        tile = box.copy()
    mean_volume = np.pi / 6 * diameter**3
    if std:
        probe = sample_diameters(200_000, diameter, std, size_bins, np.random.default_rng(seed))
        mean_volume = float(np.mean(np.pi / 6 * probe**3))
    n_tile = int(round(solid_fraction * np.prod(tile) / mean_volume))
    d_tile = sample_diameters(n_tile, diameter, std, size_bins, rng)
    if tile_nm:  # the free z edge makes the tile hold exactly phi for the sampled diameters
        tile[2] = np.sum(np.pi / 6 * d_tile**3) / (solid_fraction * tile[0] * tile[1])
    x, worst, steps = TILE_RELAXATIONS[method](tile / diameter, d_tile / diameter, rng, max_overlap, progress)
    x *= diameter
    counts = (nx, ny, math.ceil(box[2] / tile[2] - 1e-9))
    grid = np.stack(np.meshgrid(*[np.arange(c) for c in counts], indexing="ij"), -1).reshape(-1, 3)
    pos = (x[None, :, :] + (grid * tile)[:, None, :]).reshape(-1, 3)
    dia = np.tile(d_tile, len(grid))
    keep = pos[:, 2] < box[2]
    return Packing(positions=pos[keep], diameters=dia[keep], box=box, tile=tile,
                   tile_particles=n_tile, max_overlap_fraction=worst, relax_steps=steps)
