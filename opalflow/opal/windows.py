"""Checks of the pore geometry of a built opal: coating depth and interpore windows."""
from __future__ import annotations

import numpy as np

from opalflow.neighbors import kdtree
from opalflow.opal.pores import periodic_images, union_depth
from opalflow.structure import Structure


def window_openings(s: Structure, pore_radius: float) -> np.ndarray:
    """Free radius (nm) of every window between two pores whose cut balls overlap.

    A window lies in the plane halfway between two pore centres closer than
    2 (R_pore + R_part).  Each particle that crosses that plane covers a disc of
    radius sqrt(r^2 - h^2) there; the free radius is the smallest distance from the
    pore-pore axis to the edge of such a disc (negative: the window is closed).
    """
    centres = np.asarray(s.meta["pore_centres_nm"]).reshape(-1, 3)
    if len(centres) < 2:
        return np.zeros(0)
    r_max = float(s.diameters.max()) / 2
    reach = 2 * (pore_radius + r_max)
    n = len(centres)
    box = s.box_lengths[:2]
    shifts = [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)]
    size = np.where(s.periodic, s.box_lengths, 3 * s.box_lengths + 1.0)
    tree = kdtree(s.positions - s.box_lo, boxsize=size)
    out = []
    for i in range(n):
        for sx, sy in shifts:
            for j in range(i, n):
                if j == i and (sx, sy) <= (0, 0):
                    continue  # each unordered pair once; no pore with itself
                o = centres[j] + np.array([sx * box[0], sy * box[1], 0.0])
                sep = np.linalg.norm(o - centres[i])
                if sep < reach:
                    out.append(_free_radius(s, tree, centres[i], o, sep, pore_radius, r_max))
    return np.array(out)


def _free_radius(s, tree, c, o, sep, pore_radius, r_max) -> float:
    mid, axis = (c + o) / 2, (o - c) / sep
    rim = np.sqrt(max((pore_radius + r_max) ** 2 - (sep / 2) ** 2, 0.0))
    idx = np.asarray(tree.query_ball_point(_wrap(mid - s.box_lo, s), rim + 4 * r_max), dtype=np.int64)
    if not len(idx):
        return np.inf
    rel = s.minimum_image(s.positions[idx] - mid)
    h = rel @ axis
    rad = s.diameters[idx] / 2
    crossing = np.abs(h) < rad
    rho = np.linalg.norm(rel - h[:, None] * axis, axis=1)
    footprint = np.sqrt(np.maximum(rad**2 - h**2, 0.0))
    return float(np.min((rho - footprint)[crossing])) if crossing.any() else np.inf


def _wrap(point: np.ndarray, s: Structure) -> np.ndarray:
    p = point.copy()
    for k in np.flatnonzero(s.periodic):
        p[k] %= s.box_lengths[k]
    return p


def coating_surface_distance(s: Structure, pore_radius: float) -> np.ndarray:
    """Distance (nm) from each coating particle's centre to the exposed pore-wall surface.

    The pore wall is the surface of the union of the pore balls (radius R_pore, not
    the cut radius), computed exactly with the rim construction of
    :func:`opalflow.opal.pores.union_depth`; the paper's rule keeps it below
    L_coat + R_part.
    """
    coated = s.groups.get("coating")
    if coated is None or not coated.any():
        return np.zeros(0)
    images = periodic_images(np.asarray(s.meta["pore_centres_nm"]), s.box_lengths[:2])
    return np.abs(union_depth(s.positions[coated], images, pore_radius, reach=pore_radius))
