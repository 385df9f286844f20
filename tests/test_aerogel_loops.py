"""Aerogels with loops: the jump stepping, the loop models and their counts, the fractal dimension where
the literature measures it (dilute R_g(N), g(r), S(q)), the periodic cube's tensor, the density study."""
import json
import math

import numpy as np
import pytest

import opalflow

from opalflow.aerogel.aggregation import aggregate, box_edge, gaussian_diameters
from opalflow.aerogel.fractal import pair_correlation, radius_of_gyration, structure_factor
from opalflow.aerogel.loops import deflect_dangling, loop_statistics, network_bonds, winding_rank
from opalflow.analysis.elasticity import isotropic_average
from opalflow.cli import main
from tests.conftest import assert_refused
from tests.test_aerogel import _gaps


def _agg(n, phi, seed=1, **kw):
    d = gaussian_diameters(n, 10.0, 1.0, np.random.default_rng(seed))
    return aggregate(d, box_edge(d, phi), seed=seed, **kw)


@pytest.fixture(scope="module")
def dilute():
    """6 000 spheres at solid fraction 0.002 with free-distance jumps (~3 s; fixed steps: ~7 min)."""
    return _agg(6000, 0.002, stepping="jump")


def test_jump_stepping_makes_touching_clusters_without_overlap_and_same_bytes(dilute):
    a = dilute
    assert a.clusters_left == 1 and a.jumps > 0 and len(a.contacts) == 5999 == a.collisions
    pairs, gap = _gaps(a)
    assert gap.min() > -1e-9
    touching = {tuple(p) for p in pairs[gap < 1e-6]}
    assert all(tuple(sorted(c)) in touching for c in a.contacts)
    b = _agg(6000, 0.002, stepping="jump")
    assert a.positions.tobytes() == b.positions.tobytes()


def test_jumps_cost_far_fewer_moves_than_fixed_steps():
    """At 0.002 a lone cluster jumps to the sphere of its free distance at once (its mean exit time booked
    on its own clock): measured 2.4 s against 379 s at 5 000 spheres (bench/results/aerogel.md)."""
    fixed, jump = _agg(800, 0.002, stepping="fixed"), _agg(800, 0.002, stepping="jump")
    assert jump.moves < fixed.moves / 5


def test_dilute_rg_of_n_is_the_dlca_value(dilute):
    """Jullien, Kolb and Botet 1984: 1.78 +- 0.05; a 6 000-sphere run is allowed [1.65, 1.95], with a
    crossover mass inside the clusters made and a fit range of at least a factor 3 in N."""
    fit, curve = radius_of_gyration(dilute)
    assert 1.65 < fit.D < 1.95 and fit.ci95[0] < fit.D < fit.ci95[1]
    assert math.isfinite(curve.crossover_mass) and fit.range[1] >= 3 * fit.range[0]
    assert fit.range[1] == pytest.approx(curve.crossover_mass / 3, rel=1e-9)


def test_a_dense_gel_has_no_dilute_range_and_says_so():
    fit, curve = radius_of_gyration(_agg(1500, 0.05))
    assert math.isnan(fit.D) and "no dilute range" in fit.note and curve.crossover_mass < 60


def test_gel_pair_correlation_and_structure_factor():
    """g(r) - 1 ~ r^(D - 3) with its cut-off divided out and S(q) ~ q^-D over the same window: a DLCA gel
    at 0.005 (5 000 spheres) gives 1.5-2.0 both ways; the correlation length is finite and above 6 d."""
    a = _agg(5000, 0.005, stepping="jump")
    g, gc = pair_correlation(a)
    s, sc = structure_factor(a, gc.xi_nm)
    assert 6 * 10.0 < gc.xi_nm < a.box / 2
    assert 1.5 < g.D < 2.0 and 1.5 < s.D < 2.0
    assert g.range == pytest.approx((2 * np.mean(a.diameters), gc.xi_nm / 2))
    # S(q) of the centres: the self term 1 at large q, the fractal excess at small q
    assert sc.S[0] > 10 * sc.S[-1]


def test_loop_statistics_count_independent_cycles():
    ring = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5]])       # a square and a separate pair
    st = loop_statistics(6, ring)
    assert st.loops == 1 and st.pieces == 2 and st.mean_coordination == pytest.approx(10 / 6)


def test_winding_rank_of_a_periodic_lattice_and_of_a_tree():
    from opalflow.bpm.bonds import find_bonds

    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3) * 10.0 + 5
    bonds = find_bonds(g, np.full(len(g), 10.0), np.full(3, 40.0), np.ones(3, bool), 1.001)
    assert winding_rank(g, bonds, 40.0) == 3
    xline = bonds[np.abs(g[bonds[:, 0], 1] - g[bonds[:, 1], 1]) + np.abs(g[bonds[:, 0], 2] - g[bonds[:, 1], 2]) == 0]
    assert winding_rank(g, xline, 40.0) == 1                      # rows along x only: wraps in x
    a = _agg(1500, 0.05)
    x, b = network_bonds(a, 1.001)
    assert winding_rank(x, b, a.box) == 0                          # a DLCA tree is a finite piece


def test_deflection_gives_each_dangling_sphere_a_second_contact_without_overlap():
    a = _agg(1500, 0.05)
    x0, b0 = network_bonds(a, 1.001)
    z0 = np.bincount(b0.ravel(), minlength=1500)
    d, counts = deflect_dangling(a, 1.001)
    x, b = network_bonds(d, 1.001)
    z = np.bincount(b.ravel(), minlength=1500)
    assert counts["dangling_before"] == int(np.sum(z0 == 1)) and counts["deflected"] > 0.8 * counts["dangling_before"]
    assert np.sum(z == 1) <= counts["dangling_before"] - counts["deflected"]
    assert _gaps(d)[1].min() > -1e-9
    # the bonds a deflected sphere had are kept: its distance to its anchor is unchanged
    moved = np.flatnonzero(np.any(d.positions != a.positions, axis=1))
    assert len(moved) == counts["deflected"]
    assert loop_statistics(1500, b).loops >= counts["deflected"]


def test_restructuring_closes_a_loop_at_mergers_without_overlap():
    a = _agg(1500, 0.05, restructure=True)
    assert a.clusters_left == 1
    assert _gaps(a)[1].min() > -1e-9
    x, b = network_bonds(a, 1.001)
    st = loop_statistics(1500, b)
    assert st.mean_coordination > 2.5 and st.loops_per_10k > 2000       # trees: 2.00 and ~7
    # the R_g of the last merger (running sums through the turns) is that of the final cluster, unwrapped
    # along the merger contacts (a tree)
    u = a.positions.copy()
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order

    c = a.contacts
    g = coo_matrix((np.ones(len(c)), (c[:, 0], c[:, 1])), shape=(1500, 1500)).tocsr()
    order, pred = breadth_first_order(g + g.T, 0, directed=False)
    for i in order[1:]:
        dd = a.positions[i] - a.positions[pred[i]]
        u[i] = u[pred[i]] + dd - a.box * np.round(dd / a.box)
    rg = math.sqrt(np.mean(np.sum((u - u.mean(0)) ** 2, 1)))
    assert a.merger_rg[-1] == pytest.approx(rg, rel=1e-6)


def test_loop_models_in_the_workflow_and_their_counts(tmp_path):
    """Every model's summary carries coordination and loops; same spec, same bytes; necks bond more the
    wider their gap."""
    seen = {}
    for model in ("none", "deflection", "restructuring", "necks"):
        for k in (1, 2):
            out = tmp_path / f"{model}{k}"
            assert main(["run", "aerogel_dlca", "--out", str(out), "--set", "aggregate.particles=1200",
                         "--set", "aggregate.solid_fraction=0.05", "--set", f'aggregate.loops="{model}"']) == 0
        assert (tmp_path / f"{model}1/aggregate.lmp").read_bytes() == (tmp_path / f"{model}2/aggregate.lmp").read_bytes()
        seen[model] = json.loads((tmp_path / f"{model}1/summary.json").read_text())
    assert seen["none"]["mean_coordination"] < 2.01 < seen["necks"]["mean_coordination"]
    assert min(seen[m]["loops_per_10k"] for m in ("deflection", "restructuring", "necks")) > 10 * max(
        seen["none"]["loops_per_10k"], 10)
    wide = tmp_path / "wide"
    assert main(["run", "aerogel_dlca", "--out", str(wide), "--set", "aggregate.particles=1200", "--set",
                 "aggregate.solid_fraction=0.05", "--set", 'aggregate.loops="necks"', "--set", "aggregate.neck_gap=0.3"]) == 0
    assert json.loads((wide / "summary.json").read_text())["mean_coordination"] > seen["necks"]["mean_coordination"]


@pytest.mark.parametrize("sets, field", [
    (['aggregate.loops="rings"'], "aggregate.loops"),
    (['aggregate.loops="necks"', "aggregate.neck_gap=0.8"], "aggregate.neck_gap"),
    (["aggregate.neck_gap=0"], "aggregate.neck_gap"),
    (['aggregate.stepping="leap"'], "aggregate.stepping"),
    (["aggregate.particles=20", "aggregate.solid_fraction=0.3"], "aggregate.particles"),
    (["sample.periodic_z=true"], "sample.periodic_z"),
])
def test_bad_loop_and_sample_input_is_refused_in_one_line(tmp_path, capsys, sets, field):
    assert_refused(capsys, ["run", "aerogel_compression", "--out", str(tmp_path / "x")], sets, field, tmp_path / "x")


def test_a_cube_that_does_not_wrap_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "cube"
    assert main(["run", "aerogel_compression", "--out", str(out), "--set", "sample.periodic_z=true", "--set",
                 "compression.method=static", "--set", "aggregate.particles=800"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("error: sample.periodic_z = True: this network wraps around the periodic cube in 0 of 3")
    assert not out.exists()


def test_a_wrapping_cube_gets_its_tensor_and_isotropic_moduli(tmp_path):
    """Restructured networks of 8 000 spheres at 0.05 wrap around the box (seed 1: in all three directions);
    their 6 x 6 tensor gives E and nu by Hill's average and the anisotropy index."""
    out = tmp_path / "cube"
    assert main(["run", "aerogel_compression", "--out", str(out), "--set", "sample.periodic_z=true", "--set",
                 "compression.method=static", "--set", "aggregate.particles=8000", "--set",
                 'aggregate.loops="restructuring"']) == 0
    s = json.loads((out / "summary.json").read_text())
    C = np.array(s["stiffness_tensor_GPa"])
    assert np.allclose(C, C.T, rtol=1e-6, atol=1e-9 * np.abs(C).max())
    assert np.all(np.linalg.eigvalsh(0.5 * (C + C.T)) > 0)
    iso = s["isotropic_average_GPa"]
    assert iso["reuss"]["E"] <= s["youngs_modulus_isotropic_GPa"] <= iso["voigt"]["E"]
    assert -1 < s["poisson_ratio_isotropic"] < 0.5 and s["anisotropy_index"] >= 0


def test_isotropic_average_of_known_tensors():
    E, nu = 2.0, 0.2
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[range(3), range(3)] = lam + 2 * mu
    C[range(3, 6), range(3, 6)] = mu
    iso = isotropic_average(C)
    assert iso.hill.E == pytest.approx(E) and iso.hill.nu == pytest.approx(nu)
    assert iso.anisotropy_index == pytest.approx(0, abs=1e-12)
    # silicon (C11 165.7, C12 63.9, C44 79.6 GPa): Voigt > Reuss, A^U = 0.24
    C = np.zeros((6, 6))
    C[:3, :3] = 63.9
    C[range(3), range(3)] = 165.7
    C[range(3, 6), range(3, 6)] = 79.6
    iso = isotropic_average(C)
    assert iso.voigt.G > iso.reuss.G and iso.anisotropy_index == pytest.approx(0.24, abs=0.01)


@pytest.mark.parametrize("chunk", [1 << 20, 7])
def test_bond_energy_parts_sum_to_the_quadratic_form(chunk, monkeypatch):
    """... whether the bonds are summed in one piece or in pieces of ``chunk`` (ENERGY_CHUNK)."""
    from opalflow.bpm import stiffness
    from opalflow.bpm.stiffness import BondNetwork

    monkeypatch.setattr(stiffness, "ENERGY_CHUNK", chunk)

    rng = np.random.default_rng(0)
    n, m = 30, 60
    i = rng.integers(0, n, m)
    j = (i + 1 + rng.integers(0, n - 1, m)) % n
    v = rng.normal(size=(m, 3))
    net = BondNetwork(n, i, j, v / np.linalg.norm(v, axis=1)[:, None], rng.uniform(1, 2, m), rng.uniform(1, 2, m),
                      rng.uniform(0.5, 1, m), rng.uniform(0.1, 0.3, m), rng.uniform(0.1, 0.3, m))
    x = rng.normal(size=6 * n)
    parts = net.energy_parts(x.reshape(n, 6)[:, :3], x.reshape(n, 6)[:, 3:])
    assert parts.total == pytest.approx(0.5 * x @ net.matvec(x), rel=1e-10)
    assert min(parts.stretching, parts.shear, parts.bending, parts.twisting) >= 0


def test_density_study_fits_each_loop_model(tmp_path):
    """Two loop models x 2 fractions x 2 seeds of small static slabs: a fit of m per model, both in one
    figure, the energy split and scatter reported."""
    out = tmp_path / "density"
    assert main(["run", "aerogel_density", "--out", str(out), "--set", "study.solid_fractions=[0.06, 0.12]",
                 "--set", "study.seeds=[1, 2]", "--set", 'study.set=["aggregate.particles=600"]',
                 "--set", "executor.workers=2"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert set(s["models"]) == {"none", "restructuring"}
    for m in s["models"].values():
        assert len(m["runs"]) == 4 and math.isfinite(m["fits"]["E"]["exponent"]) and m["scatter_max_min"] >= 1
        assert sum(m["energy_split"].values()) == pytest.approx(1.0, rel=1e-9)
    assert s["models"]["restructuring"]["loops_per_10k"] > 10 * max(s["models"]["none"]["loops_per_10k"], 10)
    assert (out / "density.png").stat().st_size > 0


def test_the_strength_study_as_shipped_runs_the_nonlinear_method_with_contacts(tmp_path):
    """aerogel_strength with its own settings (the nonlinear method, LAMMPS's bond law at finite rotation with
    Hertz-Mindlin contacts) on small slabs (600 spheres, 2 fractions x 2 seeds): every job is a Newton run with
    contacts that ends with the stress below half its peak, and the summary carries n and m with intervals."""
    import tomllib

    from opalflow.resources import WORKFLOWS

    shipped = tomllib.loads((WORKFLOWS / "aerogel_strength.toml").read_text())["study"]["set"]
    out, small = tmp_path / "strength", json.dumps(["aggregate.particles=600", *shipped])
    assert main(["run", "aerogel_strength", "--out", str(out), "--set", "study.solid_fractions=[0.06, 0.12]",
                 "--set", "study.seeds=[1, 2]", "--set", f"study.set={small}", "--set", "executor.workers=2"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["failed_jobs"] == {}
    jobs = [json.loads(p.read_text()) for p in sorted((out / "jobs").glob("*/summary.json"))]
    assert len(jobs) == 4
    for job in jobs:
        q = job["quasistatic"]
        assert q["resolver"] == "newton" and q["contacts"] == "hertz-mindlin (nonlinear)", q
        assert q["stopped"] == "stress fell below 0.5 of the peak", q
    for key in ("modulus_exponent", "strength_exponent"):
        lo, hi = s[f"{key}_ci95"]
        assert math.isfinite(s[key]) and lo < s[key] < hi
    assert "E from the quasistatic run's first load step" in (out / "report.md").read_text()     # no static jobs


def test_strength_study_gives_n_and_m_from_the_same_slabs(tmp_path):
    """aerogel_strength_linear on small slabs (one loop model, 2 fractions x 2 seeds): each slab's quasi-static run gives
    a strength, E equal to a static solve of the same slab (the same linear network), the energy to the peak as the area under
    its saw-tooth (the first event's peak: sigma eps / 2), and the summary's n and m with their intervals."""
    out = tmp_path / "strength"
    assert main(["run", "aerogel_strength_linear", "--out", str(out), "--set", "study.solid_fractions=[0.06, 0.12]",
                 "--set", "study.seeds=[1, 2]", "--set", 'study.loop_models=["restructuring"]',
                 "--set", 'study.set=["aggregate.particles=600", "bonds.smooth=false", "compression.strain_max=0.5"]',
                 "--set", "executor.workers=2"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["failed_jobs"] == {}
    runs = s["models"]["restructuring"]["runs"]
    assert len(runs) == 4 and all(r["loaded"]["method"] == "quasistatic" for r in runs)
    static = opalflow.run("aerogel_compression", tmp_path / "static", quiet=True, set={
        "aggregate.particles": 600, "aggregate.loops": "restructuring", "aggregate.solid_fraction": 0.06,
        "aggregate.seed": 1, "compression.method": "static", "compression.drop_loose": True})
    first = next(r for r in runs if (r["target_solid_fraction"], r["seed"]) == (0.06, 1))
    assert first["E_kPa"] == pytest.approx(static["youngs_modulus_GPa"] * 1e6, rel=1e-6)   # the same first solve
    for r in runs:
        q = r["loaded"]
        if q["broken_at_peak"] == 0:
            assert q["energy_to_peak_kJ_m3"] == pytest.approx(0.5 * q["strength_kPa"] * q["strain_at_peak"], rel=1e-9)
    for key in ("modulus_exponent", "strength_exponent"):
        lo, hi = s[f"{key}_ci95"]
        assert math.isfinite(s[key]) and lo < s[key] < hi
    assert [x["target_solid_fraction"] for x in s["models"]["restructuring"]["strength"]] == [0.06, 0.12]
    assert (out / "curves.png").stat().st_size > 0 and "sigma = a rho^n" in (out / "report.md").read_text()
