"""Cluster-cluster aggregation of spheres in a periodic cube: DLCA and RLCA (Roy and Hossain, section 10.3).

The seed's algorithm (its Fig. 10.6): a cube is filled at random with non-intersecting spheres whose
diameters follow a Gaussian; the spheres diffuse; a moving cluster that meets another is placed
touching it and the two merge; the process ends when a single cluster is left.

Kinetics.  Every move picks one of the clusters left at random (uniformly) and translates it by a
random-walk step in a uniformly random direction.  Each cluster thus moves once per sweep (one unit of
time per cluster); its step length is ``step0 * N**(alpha / 2)`` so that its mean-square displacement
per sweep grows as the diffusion coefficient D ~ N**alpha, with alpha = -1/2 by default: the mobility
law of Meakin's off-lattice cluster-cluster aggregation (Meakin, Phys. Rev. Lett. 51, 1119, 1983;
Kolb, Botet and Jullien, Phys. Rev. Lett. 51, 1123, 1983); D_f of DLCA is insensitive to alpha for
alpha <= 0 (both papers).  ``step0`` is a fraction of the mean diameter (0.5 by default).

Collisions are exact: a move of length l along the unit vector u stops at the first contact of any of
the cluster's spheres with a sphere of another cluster, the smallest root t in [0, l] of
|x_i + t u - x_j| = r_i + r_j over the candidate pairs; candidates come from a cell list with cells no
smaller than l_max + 2 r_max (27 cells per sphere), kept up to date sphere by sphere.  The moving
cluster is placed touching (t is reduced by 1e-9 of the contact distance so that rounding never makes
an overlap) and the two clusters merge (DLCA); in RLCA they merge with probability
``sticking_probability`` per contact, and otherwise the mover stays where it touched and moves on at
the next pick (it bounces off).

Clusters are linked lists of their spheres; merging appends the smaller to the larger.  Unwrapped
coordinates are kept per cluster (the merged-in cluster is shifted by the whole box vector that makes
the contact a direct one) together with the sums of x and |x|^2, so the radius of gyration of every
merged cluster costs nothing: (N, R_g) of each merger is recorded for the R_g(N) fractal dimension.

The random numbers are numba's (Mersenne Twister, seeded from the spec's seed); the same spec gives the
same bytes on the same machine.  The kernel runs in chunks of moves so that Python can print progress.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

#: seconds between progress lines
PROGRESS_S = 3.0
#: contact distance fraction by which a colliding cluster stops short (rounding never overlaps)
BACKOFF = 1e-9


def time_left(history: list[tuple[float, int]]) -> float:
    """Seconds until one cluster is left, from (elapsed s, clusters left) so far: the cluster count's decay
    n ~ t^-z over the last halving of the elapsed time, extrapolated to n = 1 (nan until it can be).

    The fraction of mergers done says nothing about time (measured: 97 % of the mergers in 4 % of the
    time); the wall time goes to the last clusters, whose moves each cost their size.  Their decay speeds
    up as the gel forms, so the extrapolation overestimates: by 1.4-3x at solid fraction 0.005 and 0.02
    (5 000 and 10 000 spheres), which ``said`` states as "up to"."""
    if len(history) < 2:
        return math.nan
    t1, n1 = history[-1]
    t0, n0 = min(history[:-1], key=lambda h: abs(h[0] - t1 / 2))
    if n1 <= 1 or n0 <= n1 or t1 <= t0:
        return math.nan
    z = math.log(n0 / n1) / math.log(t1 / t0)
    return t1 * (n1 ** (1 / z) - 1)


@dataclass
class Aggregate:
    """The result of an aggregation: spheres in a periodic cube and what the process recorded."""

    positions: np.ndarray        # (N, 3) nm, wrapped into [0, L)
    diameters: np.ndarray        # (N,) nm
    box: float                   # cube edge L, nm
    cluster: np.ndarray          # (N,) final cluster label (one label when finished)
    arrival: np.ndarray          # (N,) merger index at which the sphere's cluster joined the final one
    contacts: np.ndarray         # (M, 2) sphere pairs that stuck (one per merger)
    merger_size: np.ndarray      # (M,) N of the cluster each merger made
    merger_rg: np.ndarray        # (M,) its radius of gyration (nm), unwrapped
    moves: int
    collisions: int              # contacts met (DLCA: = mergers; RLCA: more)
    clusters_left: int
    wall_s: float
    placement: str

    @property
    def solid_fraction(self) -> float:
        return float(np.sum(np.pi / 6 * self.diameters**3) / self.box**3)


def gaussian_diameters(n: int, mean: float, std: float, rng: np.random.Generator) -> np.ndarray:
    """n diameters from N(mean, std), redrawn below 5 % of the mean (the truncation to positive sizes)."""
    d = rng.normal(mean, std, n) if std > 0 else np.full(n, float(mean))
    low = d < 0.05 * mean
    while low.any():
        d[low] = rng.normal(mean, std, int(low.sum()))
        low = d < 0.05 * mean
    return d


def box_edge(diameters: np.ndarray, solid_fraction: float) -> float:
    """Edge L of the cube that holds the spheres at that solid fraction."""
    return float((np.sum(np.pi / 6 * diameters**3) / solid_fraction) ** (1 / 3))


def cells_per_edge(box: float, diameters: np.ndarray, step: float) -> int:
    """Cells per cube edge: cells no smaller than step + the largest diameter (0 if fewer than 3 fit)."""
    n = int(box // (step + float(diameters.max())))
    return n if n >= 3 else 0


# ----------------------------------------------------------------------------- numba kernels
@njit(cache=True)
def _seed(seed):
    np.random.seed(seed)


@njit(cache=True)
def _cell(x, box, nc):
    cx = min(int(x[0] / box * nc), nc - 1)
    cy = min(int(x[1] / box * nc), nc - 1)
    cz = min(int(x[2] / box * nc), nc - 1)
    return (cx * nc + cy) * nc + cz


@njit(cache=True)
def _neighbour_cells(c, nc):
    """The 27 cells around cell c (itself included), periodic."""
    cz = c % nc
    cy = (c // nc) % nc
    cx = c // (nc * nc)
    out = np.empty(27, np.int64)
    k = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                out[k] = (((cx + dx) % nc) * nc + (cy + dy) % nc) * nc + (cz + dz) % nc
                k += 1
    return out


@njit(cache=True)
def _insert(i, c, head, nxt, prv, cell_of):
    nxt[i] = head[c]
    prv[i] = -1
    if head[c] >= 0:
        prv[head[c]] = i
    head[c] = i
    cell_of[i] = c


@njit(cache=True)
def _remove(i, head, nxt, prv, cell_of):
    c = cell_of[i]
    if prv[i] >= 0:
        nxt[prv[i]] = nxt[i]
    else:
        head[c] = nxt[i]
    if nxt[i] >= 0:
        prv[nxt[i]] = prv[i]


@njit(cache=True)
def _min_image(d, box):
    return d - box * np.floor(d / box + 0.5)


@njit(cache=True)
def _place_random(r, box, nc, head, nxt, prv, cell_of, pos, max_tries):
    """Random sequential addition without overlap; returns how many spheres were placed."""
    n = r.shape[0]
    x = np.empty(3)
    for i in range(n):
        placed = False
        for _ in range(max_tries):
            for k in range(3):
                x[k] = np.random.random() * box
            c = _cell(x, box, nc)
            ok = True
            for cc in _neighbour_cells(c, nc):
                j = head[cc]
                while j >= 0 and ok:
                    s = r[i] + r[j]
                    d2 = 0.0
                    for k in range(3):
                        dk = _min_image(x[k] - pos[j, k], box)
                        d2 += dk * dk
                    ok = d2 >= s * s
                    j = nxt[j]
                if not ok:
                    break
            if ok:
                for k in range(3):
                    pos[i, k] = x[k]
                _insert(i, c, head, nxt, prv, cell_of)
                placed = True
                break
        if not placed:
            return i
    return n


@njit(cache=True)
def _aggregate(pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, ctail, csize, csum, csq,
               active, where, state, step0, alpha, p_stick, max_moves, min_left, rec_i, rec_j, rec_n, rec_rg2,
               arrival):
    """Up to ``max_moves`` moves, until ``min_left`` (>= 1) clusters are left; state = [clusters left, moves,
    collisions, mergers]."""
    u = np.empty(3)
    w = np.empty(3)
    for _ in range(max_moves):
        na = state[0]
        if na <= min_left:
            break
        c = active[np.random.randint(0, na)]
        n = csize[c]
        ell = step0 * n ** (0.5 * alpha)
        norm = 0.0
        while norm < 1e-12:
            for k in range(3):
                u[k] = np.random.normal(0.0, 1.0)
            norm = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
        for k in range(3):
            u[k] /= norm
        tmin = ell
        hit_i = -1
        hit_j = -1
        i = chead[c]
        while i >= 0:
            for cc in _neighbour_cells(cell_of[i], nc):
                j = head[cc]
                while j >= 0:
                    if cl[j] != c:
                        b = 0.0
                        ww = 0.0
                        for k in range(3):
                            w[k] = _min_image(pos[i, k] - pos[j, k], box)
                            b += w[k] * u[k]
                            ww += w[k] * w[k]
                        if b < 0.0:           # approaching: the first root of |w + t u| = r_i + r_j
                            s = r[i] + r[j]
                            disc = b * b - (ww - s * s)
                            if disc > 0.0:
                                t = -b - math.sqrt(disc)
                                if t < tmin:
                                    tmin = max(t, 0.0)
                                    hit_i = i
                                    hit_j = j
                    j = nxt[j]
            i = cnext[i]
        t = tmin
        if hit_i >= 0:
            t = max(tmin - BACKOFF * (r[hit_i] + r[hit_j]), 0.0)
        if t > 0.0:
            i = chead[c]
            while i >= 0:
                for k in range(3):
                    upos[i, k] += t * u[k]
                    x = pos[i, k] + t * u[k]
                    x -= box * math.floor(x / box)
                    if x >= box:
                        x = 0.0
                    pos[i, k] = x
                cnew = _cell(pos[i], box, nc)
                if cnew != cell_of[i]:
                    _remove(i, head, nxt, prv, cell_of)
                    _insert(i, cnew, head, nxt, prv, cell_of)
                i = cnext[i]
            dot = 0.0
            for k in range(3):
                dot += u[k] * csum[c, k]
            csq[c] += 2.0 * t * dot + n * t * t
            for k in range(3):
                csum[c, k] += n * t * u[k]
        state[1] += 1
        if hit_i < 0:
            continue
        state[2] += 1
        if p_stick < 1.0 and np.random.random() >= p_stick:
            continue
        # merge: the smaller cluster (b) into the larger (a), shifted by the box vector that makes
        # the contact i-j a direct one in unwrapped coordinates
        c2 = cl[hit_j]
        if csize[c] >= csize[c2]:
            a, bb, ia, ib = c, c2, hit_i, hit_j
        else:
            a, bb, ia, ib = c2, c, hit_j, hit_i
        for k in range(3):
            w[k] = upos[ia, k] + _min_image(pos[ib, k] - pos[ia, k], box) - upos[ib, k]
        nb = csize[bb]
        dot = 0.0
        for k in range(3):
            dot += w[k] * csum[bb, k]
        csq[bb] += 2.0 * dot + nb * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        for k in range(3):
            csum[bb, k] += nb * w[k]
        i = chead[bb]
        while i >= 0:
            cl[i] = a
            for k in range(3):
                upos[i, k] += w[k]
            i = cnext[i]
        cnext[ctail[a]] = chead[bb]
        ctail[a] = ctail[bb]
        csize[a] += nb
        csq[a] += csq[bb]
        for k in range(3):
            csum[a, k] += csum[bb, k]
        kb = where[bb]
        last = active[na - 1]
        active[kb] = last
        where[last] = kb
        state[0] = na - 1
        m = state[3]
        rec_i[m] = hit_i
        rec_j[m] = hit_j
        nn = csize[a]
        rec_n[m] = nn
        rg2 = csq[a] / nn
        for k in range(3):
            rg2 -= (csum[a, k] / nn) ** 2
        rec_rg2[m] = max(rg2, 0.0)
        state[3] = m + 1
        i = chead[bb]          # the merged-in spheres (now at the end of a's list) arrive now
        while i >= 0:
            arrival[i] = m
            i = cnext[i]
    return state


# ----------------------------------------------------------------------------- driver
def place_grid(r: np.ndarray, box: float, rng: np.random.Generator) -> np.ndarray:
    """Spheres in random slots of a cubic grid of spacing >= the largest diameter, jittered in their slots
    (solid fractions that random addition cannot reach)."""
    n = len(r)
    m = int(math.ceil(n ** (1 / 3)))
    a = box / m
    slots = rng.choice(m**3, n, replace=False)
    ijk = np.stack(np.unravel_index(slots, (m, m, m)), -1)
    room = np.maximum(a - 2 * r, 0.0)[:, None]
    return (ijk + 0.5) * a + (rng.random((n, 3)) - 0.5) * room


def aggregate(diameters: np.ndarray, box: float, *, seed: int, step_fraction: float = 0.5,
              mobility_exponent: float = -0.5, sticking_probability: float = 1.0, progress=None,
              chunk_moves: int = 20_000, random_placement_max: float = 0.3) -> Aggregate:
    """Aggregate spheres of these diameters in a periodic cube of edge ``box`` (see the module docstring).

    progress : ``progress(clusters_left, n, moves, moves_per_s, eta_s)`` between chunks of moves.
    """
    t0 = time.perf_counter()
    n = len(diameters)
    r = 0.5 * np.asarray(diameters, float)
    step0 = step_fraction * float(np.mean(diameters))
    nc = cells_per_edge(box, diameters, step0)
    if nc == 0:
        raise ValueError(f"box {box:.4g} nm is too small: fewer than 3 cells of {step0 + diameters.max():.4g} nm")
    rng = np.random.default_rng(seed)
    _seed(int(rng.integers(2**31)))
    head = np.full(nc**3, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    prv = np.full(n, -1, np.int64)
    cell_of = np.zeros(n, np.int64)
    pos = np.zeros((n, 3))
    phi = float(np.sum(np.pi / 6 * diameters**3) / box**3)
    placement = "random sequential addition"
    if phi <= random_placement_max:
        placed = _place_random(r, box, nc, head, nxt, prv, cell_of, pos, 100_000)
        if placed < n:
            raise ValueError(f"only {placed} of {n} spheres found room at solid fraction {phi:.3g}")
    else:
        placement = "random slots of a cubic grid"
        pos = place_grid(r, box, rng)
        for i in range(n):
            _insert(i, _cell(pos[i], box, nc), head, nxt, prv, cell_of)
    upos = pos.copy()
    cl = np.arange(n, dtype=np.int64)
    chead = np.arange(n, dtype=np.int64)
    cnext = np.full(n, -1, np.int64)
    ctail = np.arange(n, dtype=np.int64)
    csize = np.ones(n, np.int64)
    csum = pos.copy()
    csq = np.einsum("ij,ij->i", pos, pos)
    active = np.arange(n, dtype=np.int64)
    where = np.arange(n, dtype=np.int64)
    state = np.array([n, 0, 0, 0], np.int64)
    rec_i = np.zeros(max(n - 1, 1), np.int64)
    rec_j = np.zeros_like(rec_i)
    rec_n = np.zeros_like(rec_i)
    rec_rg2 = np.zeros(len(rec_i))
    arrival = np.full(n, -1, np.int64)
    t_start = time.perf_counter()
    history: list[tuple[float, int]] = []
    said_at = -PROGRESS_S
    while state[0] > 1:
        t_chunk = time.perf_counter()
        _aggregate(pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, ctail, csize, csum, csq,
                   active, where, state, step0, mobility_exponent, sticking_probability, chunk_moves,
                   max(1, state[0] // 2),      # a chunk at most halves the clusters: the last ones are slow
                   rec_i, rec_j, rec_n, rec_rg2, arrival)
        # about one progress line every PROGRESS_S seconds (the moves do not depend on the chunking)
        grow = PROGRESS_S / max(time.perf_counter() - t_chunk, 1e-3)
        chunk_moves = int(np.clip(chunk_moves * min(grow, 2.0), 1000, 10**8))
        el = time.perf_counter() - t_start
        history.append((el, int(state[0])))
        if progress is not None and state[0] > 1 and el - said_at >= PROGRESS_S:
            said_at = el
            progress(int(state[0]), n, int(state[1]), state[1] / max(el, 1e-9), time_left(history))
    m = int(state[3])
    return Aggregate(positions=pos, diameters=np.asarray(diameters, float), box=float(box), cluster=cl,
                     arrival=arrival, contacts=np.stack([rec_i[:m], rec_j[:m]], -1), merger_size=rec_n[:m].copy(),
                     merger_rg=np.sqrt(rec_rg2[:m]), moves=int(state[1]), collisions=int(state[2]),
                     clusters_left=int(state[0]), wall_s=time.perf_counter() - t0, placement=placement)
