"""The opal build end to end: CLI outputs, bonds and statistics."""
import json
import tomllib

import numpy as np
import pytest

from opalflow.opal.scene import build_opal, structure_statistics
from opalflow.cli import main
from opalflow.resources import DATA, WORKFLOWS
from opalflow.registry import load_spec

from conftest import brute_force_pairs

REF = tomllib.loads((DATA / "reference" / "dosta2022.toml").read_text())

SUMMARY_KEYS = {"n_particles", "n_bonds", "box_nm", "packing_fraction", "porosity",
                "bonds_per_particle", "particles_per_um3", "bonds_per_um3", "max_overlap_fraction",
                "n_by_material", "density_kg_m3", "timings_s"}


def test_info_lists_packages(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for pkg in ("BPM", "GRANULAR", "MANYBODY"):
        assert any(line.split() == [pkg, "yes"] for line in out.splitlines())


def test_list_shows_workflows(capsys):
    assert main(["list"]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert {"opal_fcc", "opal_fcc_coated20", "opal_random", "opal_quick"} <= set(names)


def test_build_writes_deck_and_summary(tmp_path):
    out = tmp_path / "run"
    assert main(["build", "opal_quick", "--out", str(out), "--set", "packing.seed=4"]) == 0
    assert (out / "data.lmp").stat().st_size > 0
    assert "read_data       data.lmp" in (out / "in.lmp").read_text()
    assert (out / "run.sh").stat().st_mode & 0o100 and (out / "resume.lmp").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert set(summary["timings_s"]) >= {"packing", "pores", "bonds", "write"}
    assert summary["spec"]["packing"]["seed"] == 4
    assert not list(out.glob("*.tmp"))


def test_bonds_are_all_pairs_within_cutoff(quick_structure, quick_spec):
    s = quick_structure
    cutoff = quick_spec.bonds.cutoff_factor * quick_spec.packing.diameter_nm
    expected = brute_force_pairs(s.positions, cutoff, s.box_lengths, s.periodic)
    assert np.array_equal(s.bonds, expected)
    # some bonds cross the periodic x or y faces
    dx = np.abs(s.positions[s.bonds[:, 0], :2] - s.positions[s.bonds[:, 1], :2])
    assert (dx > s.box_lengths[:2] / 2).any()


def test_a_minimum_bond_length_leaves_the_closer_pairs_unbonded(quick_structure, quick_spec):
    """bonds.min_length_factor f: the pairs at least f d apart within the cutoff, MUSEN's bonding by surface gap."""
    from opalflow.bpm.bonds import find_bonds

    s, d = quick_structure, quick_spec.packing.diameter_nm
    kept = find_bonds(s.positions, s.diameters, s.box_lengths, s.periodic, 1.75, 1.005)
    lengths = np.linalg.norm(s.minimum_image(s.positions[kept[:, 1]] - s.positions[kept[:, 0]]), axis=1)
    assert np.all(lengths >= 1.005 * d) and 0 < len(kept) < s.n_bonds
    near = s.bond_lengths() < 1.005 * d
    assert len(kept) == s.n_bonds - near.sum()


def test_network_statistics_of_a_simple_cubic_lattice():
    """On the simple-cubic lattice (spacing d, all sides periodic) every number is known: 13 bonds a particle
    within 1.75 d (6 at d, 12 at sqrt(2) d, 8 at sqrt(3) d, half each), 6 of 26 at contact, and g(r) in a
    shell of +-2.5 % r is the shell's neighbours over the ideal gas's count there."""
    from opalflow.bpm.bonds import SHELL, find_bonds, network_statistics

    d, n = 10.0, 6
    grid = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) * d + d / 2
    box, diameters = np.full(3, n * d), np.full(len(grid), d)
    bonds = find_bonds(grid, diameters, box, [True] * 3, 1.75)
    st = network_statistics(grid, diameters, box, [True] * 3, bonds, np.pi / 6)
    shell = 4 / 3 * np.pi * ((1 + SHELL) ** 3 - (1 - SHELL) ** 3)
    assert st.bonds_per_particle == 13 and st.near_contact_bond_share == pytest.approx(6 / 26)
    assert st.g_at_d == pytest.approx(6 / shell) and st.g_at_sqrt3_d == pytest.approx(8 / (shell * 3**1.5))


def test_the_build_report_states_the_network(quick_structure, capsys):
    st = structure_statistics(quick_structure).network
    assert 5 < st.bonds_per_particle < 12 and 0.05 < st.near_contact_bond_share < 0.5
    assert st.g_at_d > 3 * st.g_at_sqrt3_d > 0     # the contact peak above the second shell


def test_bond_types_by_material(coated_quick):
    _, s = coated_quick
    titania = s.groups["coating"]
    touches = titania[s.bonds[:, 0]] | titania[s.bonds[:, 1]]
    assert np.all(s.bond_types[touches] == 2) and np.all(s.bond_types[~touches] == 1)
    assert s.bond_type_names == ["silica", "titania"]


def test_quick_statistics(quick_structure):
    st = structure_statistics(quick_structure)
    assert abs(st.packing_fraction - 0.62) <= REF["tolerance"]["solid_fraction"]
    assert st.max_overlap_fraction <= REF["tolerance"]["max_overlap_fraction"]
    assert 0.7 < st.porosity < 0.85
    assert st.density_kg_m3 == pytest.approx((1 - st.porosity) * 1297.0, rel=1e-9)


@pytest.mark.slow
def test_standard_fcc_sample_matches_paper():
    """Acceptance 2: the paper's standard sample, d = 15 nm, 3 layers, 8.05 um^2 (~30 s)."""
    s, _ = build_opal(load_spec(WORKFLOWS / "opal_fcc.toml"))
    st = structure_statistics(s)
    ref, tol = REF["structure"], REF["tolerance"]
    assert abs(st.packing_fraction - ref["packing_solid_fraction"]) <= tol["solid_fraction"]
    assert st.particles_per_um3 == pytest.approx(ref["fcc_particles_per_um3"], rel=tol["per_um3_relative"])
    assert st.bonds_per_um3 == pytest.approx(ref["fcc_bonds_per_um3"], rel=tol["per_um3_relative"])
    assert st.max_overlap_fraction <= tol["max_overlap_fraction"]
    assert s.box_lengths[0] * s.box_lengths[1] / 1e6 == pytest.approx(ref["sample_area_um2"], rel=0.001)
    assert st.sample_height_nm / 1e3 == pytest.approx(ref["sample_height_um"], rel=0.002)


def test_open_sides_have_no_bonds_across(tmp_path):
    spec = load_spec(WORKFLOWS / "opal_quick.toml", ["boundary.sides=open"])
    s, _ = build_opal(spec)
    assert not s.periodic.any()
    dx = np.abs(s.positions[s.bonds[:, 0], :2] - s.positions[s.bonds[:, 1], :2])
    assert dx.max() <= spec.bonds.cutoff_factor * spec.packing.diameter_nm
    periodic = build_opal(load_spec(WORKFLOWS / "opal_quick.toml"))[0]
    assert s.n_bonds < periodic.n_bonds and s.n_particles == periodic.n_particles
    from opalflow.bpm.deck import compression_deck
    assert "boundary        m m f" in compression_deck(spec, s).in_lmp


def test_a_structure_reordered_is_the_same_structure(quick_structure):
    """Structure.reordered: the same particles (positions, types, groups) in the new order, the same bonds between
    the same particles (i < j, sorted, each with its type), nothing lost."""
    s = quick_structure
    order = s.cell_order(2.0 * float(np.mean(s.diameters)))
    r = s.reordered(order)
    assert sorted(order.tolist()) == list(range(s.n_particles)) and not np.array_equal(order, np.arange(s.n_particles))
    assert np.array_equal(r.positions, s.positions[order]) and np.array_equal(r.types, s.types[order])
    assert all(np.array_equal(r.groups[k], v[order]) for k, v in s.groups.items())
    assert np.all(r.bonds[:, 0] < r.bonds[:, 1]) and np.all(np.diff(r.bonds[:, 0] * r.n_particles + r.bonds[:, 1]) > 0)

    def pairs(x):           # each bond as its two particles' positions and its type, in any order
        ends = np.sort(np.stack([x.positions[x.bonds[:, 0]], x.positions[x.bonds[:, 1]]], axis=1), axis=1)
        rows = np.column_stack([ends.reshape(len(x.bonds), 6), x.bond_types])
        return rows[np.lexsort(rows.T[::-1])]
    assert np.array_equal(pairs(r), pairs(s))
    # cell order: each particle's bonded neighbours lie nearer in memory than in the builder's order
    assert np.mean(np.abs(np.diff(r.bonds, axis=1))) < np.mean(np.abs(np.diff(s.bonds, axis=1)))


def test_the_compiled_bond_kernels_give_numpys_digits(quick_structure, monkeypatch):
    """Structure.bond_vectors (neighbors.separations) compiled (from KERNEL_MIN_PAIRS) and numpy's (below): the same
    minimum-image vectors to the last digit, across the periodic faces; reordered's bond order by its counting sort
    is numpy's stable sort of the keys (i n + j), ties (a bond listed twice) as they were."""
    import opalflow.neighbors as neighbors
    import opalflow.structure as structure

    s = quick_structure
    assert s.periodic.any() and 0 < s.n_bonds < neighbors.KERNEL_MIN_PAIRS
    plain = s.bond_vectors()
    assert np.max(np.abs(plain)) < 0.5 * s.box_lengths.min()            # minimum image: no box-long vectors
    wraps = np.abs(s.positions[s.bonds[:, 1]] - s.positions[s.bonds[:, 0]]).max(axis=1) > 0.5 * s.box_lengths.min()
    assert wraps.any()                                                  # some bonds cross a periodic face
    monkeypatch.setattr(neighbors, "KERNEL_MIN_PAIRS", 1)
    assert np.array_equal(s.bond_vectors(), plain)
    rng = np.random.default_rng(3)
    n = s.n_particles
    b = np.concatenate([s.bonds, s.bonds[:50]])[rng.permutation(s.n_bonds + 50)]
    lo, hi = b.min(axis=1), b.max(axis=1)
    sort = np.argsort(lo * n + hi, kind="stable")
    rows, order = structure._sorted_bonds(b, n)
    assert np.array_equal(order, sort) and np.array_equal(rows, np.column_stack([lo[sort], hi[sort]]))


def test_a_large_build_is_put_in_cell_order_and_solves_the_same(monkeypatch, tmp_path):
    """A scene's build of ORDER_MIN_PARTICLES or more comes in cell order (not a data file's: its ids kept), and
    the static method gives the same modulus on it to rounding."""
    from opalflow.api import run
    from opalflow.bpm import scene as bpm_scene

    monkeypatch.setenv("OPALFLOW_CACHE", "off")
    plain = run("quickstart", tmp_path / "plain", set={"compression.method": "static"}, quiet=True)
    monkeypatch.setattr(bpm_scene, "ORDER_MIN_PARTICLES", 1000)
    ordered = run("quickstart", tmp_path / "ordered", set={"compression.method": "static"}, quiet=True)
    assert ordered["n_bonds"] == plain["n_bonds"] and ordered["youngs_modulus_GPa"] == pytest.approx(
        plain["youngs_modulus_GPa"], rel=1e-9)
    from opalflow.lammps.datafile import read_data

    a, b = read_data(tmp_path / "plain" / "data.lmp"), read_data(tmp_path / "ordered" / "data.lmp")
    assert not np.array_equal(a.positions, b.positions)
    assert np.array_equal(np.sort(a.positions, axis=0), np.sort(b.positions, axis=0))
