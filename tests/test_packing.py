"""Dense random packing: solid fraction, overlaps, periodicity, reproducibility."""
import math

import numpy as np
import pytest

from opalflow import neighbors
from opalflow.neighbors import neighbour_counts, pairs_within
from opalflow.packing import dense_random_packing, max_pair_overlap, tile_count

BOX = np.array([600.0, 520.0, 400.0])


@pytest.fixture(scope="module")
def tiled():
    return dense_random_packing(BOX, 30.0, 0.62, seed=3, tile_nm=260.0, coprime_with=(2, 6))


def test_solid_fraction_and_overlap(tiled):
    assert abs(tiled.solid_fraction - 0.62) <= 0.005
    # overlaps checked over the whole replicated box, periodic in x and y only
    worst = max_pair_overlap(tiled.positions, tiled.diameters, BOX, periodic=(True, True, False))
    assert worst <= 0.01
    assert tiled.positions[:, 2].max() < BOX[2] and tiled.positions.min() >= 0


def test_tile_counts_are_coprime_with_pore_columns(tiled):
    nx, ny = round(BOX[0] / tiled.tile[0]), round(BOX[1] / tiled.tile[1])
    assert math.gcd(nx, 2) == 1 and math.gcd(ny, 6) == 1
    assert tile_count(3048.0, 380.0, 8) in (7, 9)


def test_whole_box_packing_is_periodic_in_x_and_y():
    p = dense_random_packing(BOX, 40.0, 0.62, seed=1, tile_nm=0.0)
    # pairs across the x and y faces exist and do not overlap
    pairs = pairs_within(p.positions, 40.0 * 1.05, BOX, (True, True, False))
    dx = np.abs(p.positions[pairs[:, 0], 0] - p.positions[pairs[:, 1], 0])
    assert (dx > BOX[0] / 2).sum() > 10
    assert max_pair_overlap(p.positions, p.diameters, BOX, (True, True, False)) <= 0.01


@pytest.mark.parametrize("box,periodic", [(BOX, (True, True, False)), (np.array([75.0, 520.0, 120.0]), (True,) * 3)])
def test_the_cell_list_finds_the_trees_pairs_and_counts(monkeypatch, tiled, box, periodic):
    """pairs_within and neighbour_counts by the cell list (from CELL_MIN_POINTS points: the paper's samples) give
    the k-d trees' pairs and counts to the last one: a packing periodic in x and y (pairs across both faces, none
    across z), and a box of one cell along x and two along z, periodic in all three (each cell visited once), the
    neighbours of half the points."""
    x = np.mod(tiled.positions, box)
    radii = np.array([29.25, 30.75, 50.66, 52.5])              # (g(r)'s shells at d and sqrt(3) d)
    centres = np.random.default_rng(1).random(len(x)) < 0.5
    tree = pairs_within(x, 52.5, box, periodic), neighbour_counts(x, centres, radii, box, periodic)
    monkeypatch.setattr(neighbors, "CELL_MIN_POINTS", 0)
    cells = pairs_within(x, 52.5, box, periodic), neighbour_counts(x, centres, radii, box, periodic)
    assert len(tree[0]) > 5 * len(x) and np.array_equal(tree[0], cells[0])
    assert np.all(np.diff(tree[1]) > 0) and tree[1][0] >= centres.sum() and np.array_equal(tree[1], cells[1])
    across = np.abs(x[cells[0][:, 0]] - x[cells[0][:, 1]]) > box / 2
    assert np.all((across.sum(axis=0) > 10) == np.array(periodic))


def test_same_seed_same_bytes_other_seed_other_packing():
    a = dense_random_packing(BOX, 40.0, 0.62, seed=5, tile_nm=0.0)
    b = dense_random_packing(BOX, 40.0, 0.62, seed=5, tile_nm=0.0)
    c = dense_random_packing(BOX, 40.0, 0.62, seed=6, tile_nm=0.0)
    assert a.positions.tobytes() == b.positions.tobytes()
    assert len(a.positions) == len(c.positions)
    assert not np.allclose(a.positions, c.positions)


def test_size_distribution():
    p = dense_random_packing(BOX, 40.0, 0.60, std=4.0, size_bins=6, seed=2, tile_nm=0.0)
    assert len(np.unique(p.diameters)) == 6
    assert abs(p.diameters.mean() - 40.0) < 1.0
    assert 2.5 < p.diameters.std() < 4.5
    assert abs(p.solid_fraction - 0.60) <= 0.005
    assert max_pair_overlap(p.positions, p.diameters, BOX, (True, True, False)) <= 0.01


def test_the_papers_generator_stops_at_its_target_with_pairs_still_overlapping():
    """packing.method = "musen" (MUSEN's package generator's rule): the solid fraction is kept, the same seed gives
    the same bytes, and it stops as soon as the largest overlap is below the target (checked every 10 small
    steps: just below it), with pairs still overlapping, more than FIRE leaves (checked every 200 steps, it
    overshoots): the pairs MUSEN's default bonding leaves unbonded."""
    box = np.array([320.0, 320.0, 320.0])
    a = dense_random_packing(box, 40.0, 0.62, seed=4, tile_nm=0.0, method="musen")
    b = dense_random_packing(box, 40.0, 0.62, seed=4, tile_nm=0.0, method="musen")
    fire = dense_random_packing(box, 40.0, 0.62, seed=4, tile_nm=0.0)
    assert a.positions.tobytes() == b.positions.tobytes() and abs(a.solid_fraction - 0.62) <= 0.005
    assert 0.0045 < max_pair_overlap(a.positions, a.diameters, box, (True, True, True)) < 0.005

    def overlapping(p):
        return len(pairs_within(p.positions, 40.0, box, (True, True, True))) / len(p.positions)
    assert overlapping(a) > 2.0 > 1.5 * overlapping(fire)


def test_an_unknown_packing_method_is_one_line(tmp_path, capsys):
    from opalflow.cli import main

    assert main(["build", "quickstart", "--out", str(tmp_path / "no"), "--set", 'packing.method="jamming"']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "packing.method" in err[0] and "fire, musen" in err[0]
    assert not (tmp_path / "no").exists()
