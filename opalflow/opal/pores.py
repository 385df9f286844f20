"""Macropores, coating and substrate of an inverse opal (Dosta et al., section 2.1).

Geometry
--------
* Cut region of a pore: the ball of radius ``R_c = R_pore + R_part`` about its centre;
  every particle with ``|X_pore - X_part| <= R_c`` goes (eq. 1).
* Coating: particles whose centre lies inside the union of cut balls no deeper than
  ``L_coat`` below its surface become the coating material (eq. 2 for one pore,
  ``R_c - L_coat <= L <= R_c``).  Depth is the exact distance to the surface of the
  union: in the window between two overlapping cut balls the nearest surface is the
  window's rim, so particles in the middle of a window are deeper than ``L_coat``
  and are cut.  This is the paper's second step (titania farther than
  ``L_coat + R_part`` from the pore-wall surface is dropped, so the interpore
  openings stay open): the window radius shrinks by ``L_coat``, as ALD would do.
* Substrate: the bottom ``layers`` particle diameters of the packing; pores are
  placed above it and never cut into it.

FCC lattice: (111) planes parallel to the substrate, in-plane hexagonal with
nearest-neighbour distance ``a``, layer spacing ``a sqrt(2/3)``, ABC stacking; a
rectangular periodic cell ``a x a sqrt(3)`` holds two pores per layer.  Pores sit
at ``(a/4, a sqrt(3)/4)`` + lattice (centric: the box faces x = 0 and x = Lx are
mirror planes of the lattice and no pore is cut by a side face in x).
"""
from __future__ import annotations

import math

import numpy as np

from opalflow.neighbors import kdtree
from opalflow.spec import InputError


class PoreError(InputError):
    """Pores could not be placed as asked (bad input: the CLI says it in one line, exit 2)."""


def fcc_centres(spacing: float, diameter: float, layers: int, cells_x: int, cells_y: int,
                z0: float) -> np.ndarray:
    """Pore centres of the FCC opal: (111) layers stacked ABC from ``z0`` up (nm)."""
    a = spacing
    h = a * math.sqrt(2.0 / 3.0)
    base = np.array([[0.0, 0.0], [a / 2, a * math.sqrt(3) / 2]])
    offset = np.array([a / 4, a * math.sqrt(3) / 4])
    stack = np.array([a / 2, a * math.sqrt(3) / 6])
    L = np.array([cells_x * a, cells_y * a * math.sqrt(3)])
    out = []
    for k in range(layers):
        for i in range(cells_x):
            for j in range(cells_y):
                xy = base + offset + k * stack + np.array([i * a, j * a * math.sqrt(3)])
                xy = np.mod(xy, L)
                for p in xy:
                    out.append((p[0], p[1], z0 + diameter / 2 + k * h))
    return np.array(out)


def random_centres(n: int, diameter: float, box_xy: np.ndarray, z_range: tuple[float, float],
                   rng, max_iter: int = 20000) -> np.ndarray:
    """``n`` non-overlapping pores, periodic in x and y, centres within ``z_range``.

    Random centres relaxed by collective rearrangement: every overlapping pair is
    pushed apart along its axis by half its overlap (x 1.05), z clamped to the range,
    until no two pores overlap (Jodrey & Tory, Phys. Rev. A 32, 2347 (1985)).
    """
    lo, hi = z_range
    x = np.column_stack([rng.random(n) * box_xy[0], rng.random(n) * box_xy[1],
                         lo + rng.random(n) * (hi - lo)])
    iu = np.triu_indices(n, 1)
    L = np.array([box_xy[0], box_xy[1], np.inf])
    for _ in range(max_iter):
        d = x[:, None, :] - x[None, :, :]
        d[..., :2] -= L[:2] * np.round(d[..., :2] / L[:2])
        r = np.sqrt(np.einsum("ijk,ijk->ij", d, d))
        ov = diameter - r[iu]
        if ov.max() <= 0:
            return x
        push = np.zeros((n, n))
        push[iu] = np.where(ov > 0, 0.525 * (ov + 1e-6 * diameter) / np.maximum(r[iu], 1e-9), 0.0)
        push = push + push.T
        x += np.einsum("ij,ijk->ik", push, d)
        x[:, :2] %= box_xy
        x[:, 2] = np.clip(x[:, 2], lo, hi)
    raise PoreError(f"could not place {n} non-overlapping pores of {diameter:g} nm in the box")


def periodic_images(centres: np.ndarray, box_xy: np.ndarray) -> np.ndarray:
    """Centres with their 8 neighbouring images in x and y."""
    shifts = np.array([(i * box_xy[0], j * box_xy[1], 0.0) for i in (-1, 0, 1) for j in (-1, 0, 1)])
    return (centres[None, :, :] + shifts[:, None, :]).reshape(-1, 3)


def first_cutting_pore(positions: np.ndarray, radii: np.ndarray, centres: np.ndarray,
                       pore_radius: float, box_xy: np.ndarray) -> np.ndarray:
    """Index of the first pore (in the order given) that cuts each particle (eq. 1), or len(centres)."""
    n = len(centres)
    first = np.full(len(positions), n, dtype=np.int64)
    tree = kdtree(positions)
    reach = pore_radius + float(radii.max())
    for i in range(n - 1, -1, -1):
        for c in periodic_images(centres[i:i + 1], box_xy):
            idx = np.asarray(tree.query_ball_point(c, reach), dtype=np.int64)
            if len(idx):
                idx = idx[np.linalg.norm(positions[idx] - c, axis=1) <= pore_radius + radii[idx]]
                first[idx] = i
    return first


def union_depth(points: np.ndarray, centres: np.ndarray, radius: float, reach: float) -> np.ndarray:
    """Distance from each point to the surface of the union of equal balls (positive inside).

    ``centres`` must hold at least 6 balls (periodic images included).
    Candidates are the balls within ``radius + reach`` of a point (up to 6).  For
    ball j the nearest point of its sphere is the radial projection q_j; if q_j is
    covered by another ball k, the nearest exposed point of sphere j lies on the
    rim circle S_j ∩ S_k (a third ball covering that rim is not checked: cut balls
    overlap pairwise by at most 2 R_part).  Points outside every ball get
    ``-(distance to the nearest ball surface)``, or -inf beyond ``reach``.
    """
    tree = kdtree(centres)
    dist, idx = tree.query(points, k=6, distance_upper_bound=radius + reach)
    best = np.full(len(points), np.inf)
    inside = (dist < radius).any(axis=1)
    for col in range(dist.shape[1]):
        ok = np.isfinite(dist[:, col])
        if not ok.any():
            continue
        p, j = points[ok], idx[ok, col]
        c = centres[j]
        v = p - c
        r = np.linalg.norm(v, axis=1)
        u = v / np.maximum(r, 1e-12)[:, None]
        q = c + radius * u
        dq, kq = tree.query(q, k=2)
        # the nearest centre to q other than j itself
        other = np.where(kq[:, 0] == j, kq[:, 1], kq[:, 0])
        d_other = np.where(kq[:, 0] == j, dq[:, 1], dq[:, 0])
        covered = d_other < radius * (1 - 1e-12)
        cand = np.abs(radius - r)
        if covered.any():
            ck = centres[other[covered]]
            cj = c[covered]
            axis = ck - cj
            sep = np.linalg.norm(axis, axis=1)
            n_hat = axis / sep[:, None]
            mid = cj + 0.5 * axis
            rho = np.sqrt(np.maximum(radius**2 - (sep / 2) ** 2, 0.0))
            w = p[covered] - mid
            hgt = np.einsum("ij,ij->i", w, n_hat)
            rad = np.linalg.norm(w - hgt[:, None] * n_hat, axis=1)
            cand[covered] = np.sqrt(hgt**2 + (rad - rho) ** 2)
        best[ok] = np.minimum(best[ok], cand)
    return np.where(inside, best, radius - dist[:, 0])


def carve(positions: np.ndarray, radii: np.ndarray, centres: np.ndarray, pore_radius: float,
          coat: float, box_xy: np.ndarray, protected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cut pores (eq. 1) and mark the coating (eq. 2, windows kept open).

    Parameters
    ----------
    radii : particle radii (R_part); the cut radius is R_pore + R_part per particle,
        evaluated with the mean particle radius for the union geometry.
    protected : mask of particles never cut (the substrate).

    Returns
    -------
    keep, coated : boolean masks over the particles.
    """
    r_part = float(np.mean(radii))
    rc = pore_radius + r_part
    images = periodic_images(centres, box_xy)
    tree = kdtree(images)
    dmin, _ = tree.query(positions, distance_upper_bound=rc + coat + 1.0)
    inside = (dmin <= pore_radius + radii) & ~protected
    coated = np.zeros(len(positions), bool)
    if coat > 0:
        cand = np.flatnonzero(inside & (dmin >= rc - coat))
        depth = union_depth(positions[cand], images, rc, coat)
        coated[cand[(depth >= 0) & (depth <= coat)]] = True
        # particles whose depth relative to their own R_c is within the band are coating
        # even if the mean-radius union puts them a hair outside (polydisperse packings)
        coated[cand[depth < 0]] = True
    keep = ~inside | coated
    return keep, coated
