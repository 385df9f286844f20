"""Pores, coating and substrate: geometry of eqs. 1 and 2."""
import math

import numpy as np
import pytest

from opalflow.opal.scene import build_opal, structure_statistics
from opalflow.opal.pores import fcc_centres, periodic_images, union_depth
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec

A = 762.0


def test_fcc_lattice_geometry():
    c = fcc_centres(A, A, layers=3, cells_x=2, cells_y=1, z0=30.0)
    assert len(c) == 3 * 2 * 2 * 1
    box = np.array([2 * A, A * math.sqrt(3)])
    img = periodic_images(c, box)
    d = np.linalg.norm(c[:, None, :] - img[None, :, :], axis=-1)
    d[d < 1e-6] = np.inf
    # every pore has its nearest neighbours at the spacing
    assert np.allclose(d.min(axis=1), A)
    # layers: spacing a sqrt(2/3), lowest pore touching the substrate
    levels = np.unique(np.round(c[:, 2], 6))
    assert np.allclose(np.diff(levels), A * math.sqrt(2 / 3))
    assert levels[0] == pytest.approx(30.0 + A / 2)
    # middle layer: 12 neighbours at a (6 in plane, 3 above, 3 below), as in FCC
    mid = np.flatnonzero(np.isclose(c[:, 2], levels[1]))
    assert all(np.sum(np.isclose(d[m], A)) == 12 for m in mid)


def test_union_depth_single_ball_and_window():
    centres = periodic_images(np.array([[0.0, 0.0, 0.0], [700.0, 0.0, 0.0]]), np.array([1e5, 1e5]))
    R = 388.5
    pts = np.array([[-100.0, 0.0, 0.0],    # inside the first ball only
                    [350.0, 0.0, 0.0],     # centre of the window between the two balls
                    [350.0, 0.0, 100.0]])  # in the window plane, off axis
    depth = union_depth(pts, centres, R, reach=50.0)
    assert depth[0] == pytest.approx(R - 100.0)
    rim = math.sqrt(R**2 - 350.0**2)
    assert depth[1] == pytest.approx(rim)
    assert depth[2] == pytest.approx(rim - 100.0)


def _pore_surface_distance(points, centres, R, n=20000):
    """Distance to the exposed surface of the union of pore balls, by sampling it."""
    rng = np.random.default_rng(0)
    surf = []
    for c in centres:
        v = rng.normal(size=(n, 3))
        s = c + R * v / np.linalg.norm(v, axis=1)[:, None]
        covered = np.zeros(n, bool)
        for o in centres:
            if o is not c and np.linalg.norm(o - c) < 2 * R:
                covered |= np.linalg.norm(s - o, axis=1) < R - 1e-9
        surf.append(s[~covered])
    surf = np.vstack(surf)
    from scipy.spatial import cKDTree
    return cKDTree(surf).query(points)[0]


def test_coating_close_to_pore_surface_and_windows_open(coated_quick):
    spec, s = coated_quick
    titania = s.groups["coating"]
    assert titania.sum() > 100
    R = spec.pores.diameter_nm / 2
    r_part = spec.packing.diameter_nm / 2
    L = spec.coating.thickness_nm
    box = s.box_lengths[:2]
    images = periodic_images(s.meta["pore_centres_nm"], box)
    near = images[np.linalg.norm(images[:, :2] - box / 2, axis=1) < 3 * R]
    dist = _pore_surface_distance(s.positions[titania], near, R)
    # a surface sample spacing of ~10 nm bounds the sampling error
    assert dist.max() <= L + r_part + 10.0
    # windows: between touching pores the opening must stay free of particles
    rc = R + r_part
    rim = math.sqrt(rc**2 - (spec.pores.spacing_nm / 2) ** 2)
    centres = s.meta["pore_centres_nm"]
    free = []
    for i, c in enumerate(centres):
        d = np.linalg.norm(images - c, axis=1)
        for o in images[np.isclose(d, spec.pores.spacing_nm)]:
            mid, axis = (c + o) / 2, (o - c) / np.linalg.norm(o - c)
            rel = s.minimum_image(s.positions - mid)
            h = rel @ axis
            rho = np.linalg.norm(rel - h[:, None] * axis, axis=1)
            slab = np.abs(h) < r_part
            free.append(rho[slab].min() if slab.any() else np.inf)
    free = np.array(free)
    # the coating narrows the cut window by about L; a particle centre never sits within
    # rim - L - R_part of the window axis
    assert free.min() > rim - L - r_part - 1.0
    assert np.median(free) > 0


def test_substrate_is_bottom_layers_and_never_cut(quick_structure, quick_spec):
    s = quick_structure
    d = quick_spec.packing.diameter_nm
    sub = s.groups["substrate"]
    assert np.all(s.positions[sub, 2] < quick_spec.substrate.layers * d)
    assert np.all(s.positions[~sub, 2] >= quick_spec.substrate.layers * d)
    assert s.type_names[1] == "substrate" and np.all(s.types[sub] == 2)
    # the substrate is complete: its areal density matches the packing's
    expected = 0.62 * s.box_lengths[0] * s.box_lengths[1] * 2 * d / (math.pi / 6 * d**3)
    assert sub.sum() == pytest.approx(expected, rel=0.05)


def test_no_particle_inside_a_pore(quick_structure, quick_spec):
    s = quick_structure
    images = periodic_images(s.meta["pore_centres_nm"], s.box_lengths[:2])
    from scipy.spatial import cKDTree
    sample = ~s.groups["substrate"]
    dmin = cKDTree(images).query(s.positions[sample])[0]
    R = quick_spec.pores.diameter_nm / 2
    assert dmin.min() > R + s.diameters.max() / 2


@pytest.mark.parametrize("target", [0.49, 0.63])
def test_random_pores_reach_target_porosity(target):
    spec = load_spec(WORKFLOWS / "opal_random.toml",
                     [f"pores.porosity={target}", "packing.diameter_nm=40.0", "packing.tile_nm=400.0"])
    s, _ = build_opal(spec)
    stats = structure_statistics(s)
    assert abs(stats.porosity - target) <= 0.01
    c = s.meta["pore_centres_nm"]
    img = periodic_images(c, s.box_lengths[:2])
    d = np.linalg.norm(c[:, None, :] - img[None, :, :], axis=-1)
    d[d < 1e-6] = np.inf
    assert d.min() >= spec.pores.diameter_nm * (1 - 1e-9)


def test_window_checker_sees_open_and_closed_windows(quick_structure, quick_spec):
    from opalflow.opal.windows import window_openings
    from opalflow.structure import Structure

    R = quick_spec.pores.diameter_nm / 2
    free = window_openings(quick_structure, R)
    assert len(free) == 18  # 4 pores: 12 in-plane windows + 6 between the two layers
    assert free.min() > 0
    # a particle put in the middle of a window closes it
    s = quick_structure
    c = s.meta["pore_centres_nm"]
    pair = [(i, j) for i in range(len(c)) for j in range(i + 1, len(c))
            if abs(np.linalg.norm(c[i] - c[j]) - 2 * R) < 1e-6]
    i, j = pair[0]
    mid = (c[i] + c[j]) / 2
    blocked = Structure(positions=np.vstack([s.positions, mid]), diameters=np.append(s.diameters, 60.0),
                        types=np.append(s.types, 1), densities=np.append(s.densities, s.densities[0]),
                        box_lo=s.box_lo, box_hi=s.box_hi, periodic=s.periodic, meta=s.meta)
    assert window_openings(blocked, R).min() < 0
