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
    stepping: str = "fixed"
    jumps: int = 0               # free-distance jumps (stepping "jump")

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


def cells_per_edge(box: float, diameters: np.ndarray, step: float, edge: float = 0.0) -> int:
    """Cells per cube edge: cells no smaller than step + the largest diameter, nor than ``edge`` (0 if fewer
    than 3 fit)."""
    n = int(box // max(step + float(diameters.max()), edge))
    return n if n >= 3 else 0


def jump_cell_edge(diameters: np.ndarray, solid_fraction: float) -> float:
    """The cell edge of the jump stepping: the volume per sphere (one sphere per cell on average), so that
    a scan of 27 cells meets ~27 spheres while a lone cluster may jump up to an edge less a diameter."""
    return float((np.mean(np.pi / 6 * diameters**3) / solid_fraction) ** (1 / 3))


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
def _direction(u):
    """A uniformly random unit vector into u (three normal draws, redrawn if degenerate)."""
    norm = 0.0
    while norm < 1e-12:
        for k in range(3):
            u[k] = np.random.normal(0.0, 1.0)
        norm = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    for k in range(3):
        u[k] /= norm


@njit(cache=True)
def _scan(c, u, ell, pos, r, box, nc, head, nxt, cell_of, cl, chead, cnext, w, hit):
    """The first contact of cluster c moving by up to ``ell`` along u with a sphere of another cluster, among
    the 27 cells around each of its spheres: returns (t, smallest surface gap met), hit = [i, j] (-1 if none)."""
    tmin = ell
    gap = math.inf
    hit[0] = -1
    hit[1] = -1
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
                    s = r[i] + r[j]
                    gap = min(gap, math.sqrt(ww) - s)
                    if b < 0.0:           # approaching: the first root of |w + t u| = r_i + r_j
                        disc = b * b - (ww - s * s)
                        if disc > 0.0:
                            t = -b - math.sqrt(disc)
                            if t < tmin:
                                tmin = max(t, 0.0)
                                hit[0] = i
                                hit[1] = j
                j = nxt[j]
        i = cnext[i]
    return tmin, gap


@njit(cache=True)
def _set_position(i, x, pos, box, nc, head, nxt, prv, cell_of):
    """Sphere i to x, wrapped into [0, L), its cell-list entry kept up to date."""
    for k in range(3):
        v = x[k] - box * math.floor(x[k] / box)
        if v >= box:
            v = 0.0
        pos[i, k] = v
    cnew = _cell(pos[i], box, nc)
    if cnew != cell_of[i]:
        _remove(i, head, nxt, prv, cell_of)
        _insert(i, cnew, head, nxt, prv, cell_of)


@njit(cache=True)
def _translate(c, t, u, n, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq):
    """Move cluster c by t u (cell lists, unwrapped coordinates and the R_g sums kept up to date)."""
    x = np.empty(3)
    i = chead[c]
    while i >= 0:
        for k in range(3):
            upos[i, k] += t * u[k]
            x[k] = pos[i, k] + t * u[k]
        _set_position(i, x, pos, box, nc, head, nxt, prv, cell_of)
        i = cnext[i]
    dot = 0.0
    for k in range(3):
        dot += u[k] * csum[c, k]
    csq[c] += 2.0 * t * dot + n * t * t
    for k in range(3):
        csum[c, k] += n * t * u[k]


@njit(cache=True)
def _step(c, tmin, hit, u, n, r, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq):
    """Move cluster c by tmin along u, stopped BACKOFF of the contact distance short of a contact hit."""
    t = tmin
    if hit[0] >= 0:
        t = max(tmin - BACKOFF * (r[hit[0]] + r[hit[1]]), 0.0)
    if t > 0.0:
        _translate(c, t, u, n, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq)


@njit(cache=True)
def _merge(c, hit_i, hit_j, pos, upos, box, cl, chead, cnext, ctail, csize, csum, csq, active, where, state,
           rec_i, rec_j, rec_n, rec_rg2, arrival, w):
    """Merge the clusters of the contact hit_i (of the mover c) - hit_j: the smaller into the larger, shifted
    by the box vector that makes the contact a direct one in unwrapped coordinates; returns the survivor."""
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
    na = state[0]
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
    return a


@njit(cache=True)
def _rotated(b, ib, ia, cvec, axis, theta, k, upos, out):
    """Where sphere k of cluster b sits relative to the centre of sphere ia once b is turned by theta about
    the axis through that centre (Rodrigues' formula), b touching ia with its sphere ib along cvec."""
    ct, st = math.cos(theta), math.sin(theta)
    v0 = cvec[0] + upos[k, 0] - upos[ib, 0]
    v1 = cvec[1] + upos[k, 1] - upos[ib, 1]
    v2 = cvec[2] + upos[k, 2] - upos[ib, 2]
    dot = axis[0] * v0 + axis[1] * v1 + axis[2] * v2
    out[0] = v0 * ct + (axis[1] * v2 - axis[2] * v1) * st + axis[0] * dot * (1 - ct)
    out[1] = v1 * ct + (axis[2] * v0 - axis[0] * v2) * st + axis[1] * dot * (1 - ct)
    out[2] = v2 * ct + (axis[0] * v1 - axis[1] * v0) * st + axis[2] * dot * (1 - ct)


@njit(cache=True)
def _overlap(b, ib, ia, cvec, axis, theta, pos, upos, r, box, nc, head, nxt, cl, chead, cnext, hit):
    """Does cluster b, turned by theta about the centre of ia, overlap a sphere of another cluster?  The first
    overlapping pair goes to hit = [k of b, j]."""
    rel = np.empty(3)
    x = np.empty(3)
    k = chead[b]
    while k >= 0:
        _rotated(b, ib, ia, cvec, axis, theta, k, upos, rel)
        for q in range(3):
            x[q] = pos[ia, q] + rel[q]
            x[q] -= box * math.floor(x[q] / box)
            if x[q] >= box:
                x[q] = 0.0
        for cc in _neighbour_cells(_cell(x, box, nc), nc):
            j = head[cc]
            while j >= 0:
                if cl[j] != b and not (k == ib and j == ia):
                    d2 = 0.0
                    for q in range(3):
                        dq = _min_image(x[q] - pos[j, q], box)
                        d2 += dq * dq
                    s = r[k] + r[j]
                    if d2 < s * s:
                        hit[0] = k
                        hit[1] = j
                        return True
                j = nxt[j]
        k = cnext[k]
    return False


@njit(cache=True)
def _restructure(c, hit_i, hit_j, pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, csize, csum,
                 csq, d_mean, hit):
    """Turn the smaller of the two clusters meeting at (hit_i of the mover c, hit_j) about the centre of the
    other's contact sphere, about a random axis perpendicular to the contact, until a second sphere touches
    (Meakin and Jullien's restructuring, J. Chem. Phys. 89, 246, 1988; for a single sphere it is the
    dangling-bond deflection of Ma, Jullien and Scherer, Phys. Rev. E 65, 041403, 2002).  Angular steps move
    no sphere by more than d_mean / 4, the contact angle is bisected; no contact within a turn: unchanged.
    hit = [k, j] of the second contact (-1 if none)."""
    hit[0] = -1
    hit[1] = -1
    c2 = cl[hit_j]
    if csize[c] <= csize[c2]:
        b, ib, ia = c, hit_i, hit_j
    else:
        b, ib, ia = c2, hit_j, hit_i
    cvec = np.empty(3)
    for q in range(3):
        cvec[q] = _min_image(pos[ib, q] - pos[ia, q], box)
    cn = math.sqrt(cvec[0] ** 2 + cvec[1] ** 2 + cvec[2] ** 2)
    reach = _reach(b, ib, cvec, upos, chead, cnext)
    axis = np.empty(3)
    norm = 0.0
    while norm < 1e-9:
        _direction(axis)
        dot = (axis[0] * cvec[0] + axis[1] * cvec[1] + axis[2] * cvec[2]) / cn
        for q in range(3):
            axis[q] -= dot * cvec[q] / cn
        norm = math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
    for q in range(3):
        axis[q] /= norm
    dth = min(0.25 * d_mean / reach, 0.5)
    turn = 2.0 * math.pi
    lo, hi = 0.0, -1.0
    trial = np.empty(2, np.int64)
    th = dth
    while lo < turn:
        th = min(lo + dth, turn)
        if _overlap(b, ib, ia, cvec, axis, th, pos, upos, r, box, nc, head, nxt, cl, chead, cnext, trial):
            hi = th
            hit[0] = trial[0]
            hit[1] = trial[1]
            break
        lo = th
    if hi < 0.0:
        return
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        if _overlap(b, ib, ia, cvec, axis, mid, pos, upos, r, box, nc, head, nxt, cl, chead, cnext, trial):
            hi = mid
            hit[0] = trial[0]
            hit[1] = trial[1]
        else:
            lo = mid
    _turn(b, ib, ia, cvec, axis, lo, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csize, csum, csq)


@njit(cache=True)
def _reach(b, ib, cvec, upos, chead, cnext):
    """The largest distance of a sphere of cluster b from the centre of the contact sphere (at -cvec from ib)."""
    reach = 0.0
    k = chead[b]
    while k >= 0:
        d2 = 0.0
        for q in range(3):
            d2 += (cvec[q] + upos[k, q] - upos[ib, q]) ** 2
        reach = max(reach, math.sqrt(d2))
        k = cnext[k]
    return reach


@njit(cache=True)
def _turn(b, ib, ia, cvec, axis, angle, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csize, csum, csq):
    """Turn cluster b by ``angle`` about ``axis`` through the centre of ia: positions, unwrapped positions, cells
    and the R_g sums."""
    rel = np.empty(3)
    new = np.empty((csize[b], 3))
    m = 0
    k = chead[b]
    while k >= 0:
        _rotated(b, ib, ia, cvec, axis, angle, k, upos, rel)
        for q in range(3):
            new[m, q] = rel[q]
        m += 1
        k = cnext[k]
    base = np.empty(3)
    for q in range(3):
        base[q] = upos[ib, q] - cvec[q]        # the centre of ia in b's unwrapped frame
    for q in range(3):
        csum[b, q] = 0.0
    csq[b] = 0.0
    x = np.empty(3)
    m = 0
    k = chead[b]
    while k >= 0:
        for q in range(3):
            upos[k, q] = base[q] + new[m, q]
            x[q] = pos[ia, q] + new[m, q]
            csum[b, q] += upos[k, q]
            csq[b] += upos[k, q] * upos[k, q]
        _set_position(k, x, pos, box, nc, head, nxt, prv, cell_of)
        m += 1
        k = cnext[k]


@njit(cache=True)
def _stick(c, hit_i, hit_j, restructure, d_mean, pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext,
           ctail, csize, csum, csq, active, where, state, rec_i, rec_j, rec_n, rec_rg2, arrival, w):
    """The mover c sticks at (hit_i, hit_j): restructured first when asked (a second contact: a loop, or a
    third cluster that then joins too); returns the surviving cluster."""
    second = np.full(2, -1, np.int64)
    if restructure:
        _restructure(c, hit_i, hit_j, pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, csize, csum,
                     csq, d_mean, second)
    a = _merge(c, hit_i, hit_j, pos, upos, box, cl, chead, cnext, ctail, csize, csum, csq, active, where, state,
               rec_i, rec_j, rec_n, rec_rg2, arrival, w)
    if second[0] >= 0 and cl[second[0]] != cl[second[1]]:
        a = _merge(cl[second[0]], second[0], second[1], pos, upos, box, cl, chead, cnext, ctail, csize, csum, csq,
                   active, where, state, rec_i, rec_j, rec_n, rec_rg2, arrival, w)
    return a


@njit(cache=True)
def _aggregate(pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, ctail, csize, csum, csq,
               active, where, state, step0, alpha, p_stick, max_moves, min_left, rec_i, rec_j, rec_n, rec_rg2,
               arrival, restructure, d_mean):
    """Fixed steps: up to ``max_moves`` moves, until ``min_left`` (>= 1) clusters are left; state = [clusters
    left, moves, collisions, mergers, jumps]."""
    u = np.empty(3)
    w = np.empty(3)
    hit = np.empty(2, np.int64)
    for _ in range(max_moves):
        na = state[0]
        if na <= min_left:
            break
        c = active[np.random.randint(0, na)]
        n = csize[c]
        ell = step0 * n ** (0.5 * alpha)
        _direction(u)
        tmin, gap = _scan(c, u, ell, pos, r, box, nc, head, nxt, cell_of, cl, chead, cnext, w, hit)
        _step(c, tmin, hit, u, n, r, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq)
        state[1] += 1
        if hit[0] < 0:
            continue
        state[2] += 1
        if p_stick < 1.0 and np.random.random() >= p_stick:
            continue
        _stick(c, hit[0], hit[1], restructure, d_mean, pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead,
               cnext, ctail, csize, csum, csq, active, where, state, rec_i, rec_j, rec_n, rec_rg2, arrival, w)
    return state


@njit(cache=True)
def _heap_push(key, val, hk, hv, size):
    """Push (key, val) on the binary min-heap hk/hv of ``size`` entries; returns the new size."""
    k = size
    hk[k] = key
    hv[k] = val
    while k > 0:
        p = (k - 1) // 2
        if hk[p] <= hk[k]:
            break
        hk[p], hk[k] = hk[k], hk[p]
        hv[p], hv[k] = hv[k], hv[p]
        k = p
    return size + 1


@njit(cache=True)
def _heap_pop(hk, hv, size):
    """Remove the smallest entry (read it from hk[0], hv[0] first); returns the new size."""
    size -= 1
    hk[0] = hk[size]
    hv[0] = hv[size]
    k = 0
    while True:
        a, b, m = 2 * k + 1, 2 * k + 2, k
        if a < size and hk[a] < hk[m]:
            m = a
        if b < size and hk[b] < hk[m]:
            m = b
        if m == k:
            break
        hk[m], hk[k] = hk[k], hk[m]
        hv[m], hv[k] = hv[k], hv[m]
        k = m
    return size


@njit(cache=True)
def _aggregate_jumps(pos, upos, r, box, nc, cell_edge, d_max, head, nxt, prv, cell_of, cl, chead, cnext, ctail,
                     csize, csum, csq, active, where, state, step0, alpha, p_stick, jump_min, max_moves, min_left,
                     rec_i, rec_j, rec_n, rec_rg2, arrival, clock, hk, hv, hsize, restructure, d_mean):
    """Free-distance jumps (see ``aggregate``): each cluster has its own clock (in its own moves); the cluster
    whose clock is behind moves next (a heap, stale entries skipped), a move adds an exponential time of mean 1
    (a Poisson clock per cluster: uniform picking in continuous time), a jump of R adds (R / ell)^2.
    hsize = [entries]; state as ``_aggregate``."""
    u = np.empty(3)
    w = np.empty(3)
    hit = np.empty(2, np.int64)
    for _ in range(max_moves):
        if state[0] <= min_left:
            break
        key = hk[0]
        c = hv[0]
        hsize[0] = _heap_pop(hk, hv, hsize[0])
        if cl[chead[c]] != c or key != clock[c]:
            continue                          # merged away, or an old entry of a cluster since moved
        n = csize[c]
        ell = step0 * n ** (0.5 * alpha)
        _direction(u)
        tmin, gap = _scan(c, u, ell, pos, r, box, nc, head, nxt, cell_of, cl, chead, cnext, w, hit)
        free = min(gap, cell_edge - d_max)    # spheres beyond the 27 cells are at least this far
        if free - ell >= jump_min * ell:      # far from everything: to the sphere of radius free - ell at once
            jump = free - ell
            _translate(c, jump, u, n, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq)
            clock[c] += (jump / ell) ** 2     # mean exit time of the walk from that sphere, in moves
            state[4] += 1
            hsize[0] = _heap_push(clock[c], c, hk, hv, hsize[0])
            continue
        _step(c, tmin, hit, u, n, r, pos, upos, box, nc, head, nxt, prv, cell_of, chead, cnext, csum, csq)
        state[1] += 1
        clock[c] -= math.log(1.0 - np.random.random())
        if hit[0] >= 0:
            state[2] += 1
            if p_stick >= 1.0 or np.random.random() < p_stick:
                a = _stick(c, hit[0], hit[1], restructure, d_mean, pos, upos, r, box, nc, head, nxt, prv, cell_of, cl,
                           chead, cnext, ctail, csize, csum, csq, active, where, state, rec_i, rec_j, rec_n, rec_rg2,
                           arrival, w)
                clock[a] = clock[c]
                c = a
        hsize[0] = _heap_push(clock[c], c, hk, hv, hsize[0])
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


def _initial_placement(r: np.ndarray, box: float, nc: int, phi: float, rng, random_placement_max: float):
    """The spheres' first positions and their cell lists (head, next, previous, cell of each): random sequential
    addition up to ``random_placement_max``, random slots of a cubic grid above it (the kernel's random state
    seeded before)."""
    n = len(r)
    head = np.full(nc**3, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    prv = np.full(n, -1, np.int64)
    cell_of = np.zeros(n, np.int64)
    pos = np.zeros((n, 3))
    if phi <= random_placement_max:
        placed = _place_random(r, box, nc, head, nxt, prv, cell_of, pos, 100_000)
        if placed < n:
            raise ValueError(f"only {placed} of {n} spheres found room at solid fraction {phi:.3g}")
        return pos, (head, nxt, prv, cell_of), "random sequential addition"
    pos = place_grid(r, box, rng)
    for i in range(n):
        _insert(i, _cell(pos[i], box, nc), head, nxt, prv, cell_of)
    return pos, (head, nxt, prv, cell_of), "random slots of a cubic grid"


def aggregate(diameters: np.ndarray, box: float, *, seed: int, step_fraction: float = 0.5,
              mobility_exponent: float = -0.5, sticking_probability: float = 1.0, stepping: str = "fixed",
              jump_min: float = 4.0, restructure: bool = False, progress=None, chunk_moves: int = 20_000,
              random_placement_max: float = 0.3) -> Aggregate:
    """Aggregate spheres of these diameters in a periodic cube of edge ``box`` (see the module docstring).

    stepping : "fixed" (every move one step) or "jump" (free-distance jumps when the free distance exceeds
        ``jump_min`` + 1 steps; see the module docstring).
    restructure : at every sticking contact the smaller cluster turns about it until a second contact
        (``_restructure``): a loop per merger.

    progress : ``progress(clusters_left, n, moves, moves_per_s, eta_s)`` between chunks of moves.
    """
    t0 = time.perf_counter()
    n = len(diameters)
    r = 0.5 * np.asarray(diameters, float)
    step0 = step_fraction * float(np.mean(diameters))
    phi = float(np.sum(np.pi / 6 * diameters**3) / box**3)
    jumps = stepping == "jump"
    nc = cells_per_edge(box, diameters, step0, jump_cell_edge(diameters, phi) if jumps else 0.0)
    if nc == 0:
        raise ValueError(f"box {box:.4g} nm is too small: fewer than 3 cells of {step0 + diameters.max():.4g} nm")
    rng = np.random.default_rng(seed)
    _seed(int(rng.integers(2**31)))
    pos, (head, nxt, prv, cell_of), placement = _initial_placement(r, box, nc, phi, rng, random_placement_max)
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
    state = np.array([n, 0, 0, 0, 0], np.int64)
    rec_i = np.zeros(max(n - 1, 1), np.int64)
    rec_j = np.zeros_like(rec_i)
    rec_n = np.zeros_like(rec_i)
    rec_rg2 = np.zeros(len(rec_i))
    arrival = np.full(n, -1, np.int64)
    n_clocks = n if jumps else 1                   # the clocks and their heap: the jump kernel's only
    clock = -np.log1p(-rng.random(n)) if jumps else np.zeros(n_clocks)   # each cluster's first move (Poisson clocks)
    hk, hv = np.empty(n_clocks + 1), np.empty(n_clocks + 1, np.int64)
    hsize = np.zeros(1, np.int64)
    if jumps:
        for c in range(n):
            hsize[0] = _heap_push(clock[c], c, hk, hv, hsize[0])
    t_start = time.perf_counter()
    history: list[tuple[float, int]] = []
    said_at = -PROGRESS_S
    while state[0] > 1:
        t_chunk = time.perf_counter()
        min_left = max(1, state[0] // 2)       # a chunk at most halves the clusters: the last ones are slow
        if jumps:
            _aggregate_jumps(pos, upos, r, box, nc, box / nc, float(diameters.max()), head, nxt, prv, cell_of, cl,
                             chead, cnext, ctail, csize, csum, csq, active, where, state, step0, mobility_exponent,
                             sticking_probability, jump_min, chunk_moves, min_left, rec_i, rec_j, rec_n, rec_rg2,
                             arrival, clock, hk, hv, hsize, restructure, float(np.mean(diameters)))
        else:
            _aggregate(pos, upos, r, box, nc, head, nxt, prv, cell_of, cl, chead, cnext, ctail, csize, csum, csq,
                       active, where, state, step0, mobility_exponent, sticking_probability, chunk_moves, min_left,
                       rec_i, rec_j, rec_n, rec_rg2, arrival, restructure, float(np.mean(diameters)))
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
                     clusters_left=int(state[0]), wall_s=time.perf_counter() - t0, placement=placement,
                     stepping=stepping, jumps=int(state[4]))
