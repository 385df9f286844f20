"""The static solver of the bond network (opalflow/bpm/static.py, static_run.py): the analytic lattice,
the two solvers against each other, the assembled matrix against the operator, loose particles, the
workflow's outputs."""
import json

import numpy as np
import pytest

from opalflow.bpm.deck import loaded_sample
from opalflow.bpm.loading import LOADINGS
from opalflow.bpm.scene import scene_of
from opalflow.bpm.static import LooseParticlesError, assemble, solve_compression
from opalflow.bpm.stiffness import stiffness_network
from opalflow.cli import main
from opalflow.linalg.krylov import Stop
from opalflow.registry import load_spec
from opalflow.resources import WORKFLOWS

SMALL_OPAL = ["pores.arrangement=none", "pores.spacing_nm=300.0", "pores.diameter_nm=250.0", "pores.layers=1",
              "packing.seed=3"]


def scene(workflow: str, sets=()):
    spec = load_spec(WORKFLOWS / f"{workflow}.toml", list(sets))
    s = scene_of(spec).build(spec, lambda m: None)
    sample = loaded_sample(spec, s)
    return spec, sample, stiffness_network(sample.structure, sample.coefficients)


def test_lattice_modulus_is_the_analytic_one(tmp_path, capsys):
    """Simple-cubic lattice without contacts: E = E_b pi r_b^2 / a^2 (pi/4 E_b at r_b = a/2) within 0.1 %,
    through `python -m opalflow run lattice_sc --set compression.method=static`."""
    out = tmp_path / "static"
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=static"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    ref = summary["reference"]["youngs_modulus_specimen_GPa"]
    assert ref["value"] == pytest.approx(np.pi / 4 * 6.53, rel=1e-9)
    assert abs(ref["error"]) < 1e-3
    assert summary["method"] == "static" and summary["relative_residual"] < 1.1e-6
    # the static method draws its plots where asked (compression.plots = "all"), not by default
    files = {p.name for p in out.iterdir()}
    assert {"results.h5", "report.md", "data.lmp"} <= files and not any(f.endswith(".png") for f in files)
    assert 'Plots: none drawn (compression.plots = "auto"' in (out / "report.md").read_text()
    # uniaxial strain of a lattice: every vertical bond strained by -strain, horizontal ones not at all
    import h5py
    with h5py.File(out / "results.h5") as h:
        eps = h["static/bond_strain_per_strain"][:]
    vertical, horizontal = np.isclose(eps, -1.0, atol=1e-6), np.isclose(eps, 0.0, atol=1e-6)
    assert np.all(vertical | horizontal) and 0.25 < vertical.mean() < 0.4


def test_plots_are_drawn_where_asked(tmp_path, capsys):
    """``compression.plots = "all"``: the static run draws its three plots and its report names them, leaving the
    caller's matplotlib as it was (a Jupyter user's backend and figures: the plots are drawn without pyplot); a
    value not in auto/all/none is refused in one line before anything is written."""
    import matplotlib
    import matplotlib.pyplot as plt

    before = matplotlib.get_backend()
    matplotlib.use("svg")                     # (a backend of the caller's that is not the Agg of the plots)
    figures = plt.get_fignums()
    out = tmp_path / "plotted"
    try:
        assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=static",
                     "--set", "compression.plots=all"]) == 0
        assert matplotlib.get_backend() == "svg" and plt.get_fignums() == figures
    finally:
        matplotlib.use(before)
    assert {"displacement.png", "stress_hist.png", "bond_strain.png"} <= {p.name for p in out.iterdir()}
    assert "Plots: displacement.png, stress_hist.png, bond_strain.png." in (out / "report.md").read_text()
    capsys.readouterr()
    assert main(["run", "lattice_sc", "--out", str(tmp_path / "bad"), "--set", "compression.plots=some"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: compression.plots = 'some': must be one of auto, all, none (auto: all but for the static "
                   "method, whose solve the plots would outlast)"] and not (tmp_path / "bad").exists()


@pytest.mark.parametrize("workflow, sets", [("lattice_sc", ()), ("opal_quick", SMALL_OPAL)])
def test_assembled_matrix_is_the_operator(workflow, sets):
    _, _, net = scene(workflow, sets)
    K = assemble(net)
    x = np.random.default_rng(0).normal(size=6 * net.n_particles)
    assert np.allclose(K @ x, net.matvec(x), rtol=0, atol=1e-10 * np.abs(K).max() * np.abs(x).max())
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()


def test_every_solver_gives_the_same_modulus():
    _, sample, net = scene("opal_quick", SMALL_OPAL)
    s = sample.structure
    args = (net, s.positions, LOADINGS["plate"].supports(sample))
    direct = solve_compression(*args, solver="direct", say=lambda m: None)      # the factor: exact to round-off
    assert direct.residual < 1e-12
    amg = solve_compression(*args, solver="amg", energy_tol=0, say=lambda m: None)
    assert amg.residual < 1.01e-6 and amg.modulus_MPa == pytest.approx(direct.modulus_MPa, rel=1e-6)
    for solver in ("block-amg", "cg", "cg-jax"):
        other = solve_compression(*args, solver=solver, energy_tol=0, say=lambda m: None)    # the residual rule
        assert other.modulus_MPa == pytest.approx(direct.modulus_MPa, rel=1e-6), solver
        assert other.residual < 1.01e-6 and other.iterations > amg.iterations, solver
    # linear: half the strain, half the stress, the same modulus
    half = solve_compression(*args, strain=5e-5, solver="amg", say=lambda m: None)
    assert half.stress_MPa == pytest.approx(amg.stress_MPa / 2, rel=1e-6)


@pytest.mark.parametrize("solver", ["block-amg", "cg"])   # (amg: one level at this size, exact at once)
def test_the_energy_stop_bounds_the_modulus_error(solver):
    """CG's energy stop (static.Stop): E from the energy is an upper bound of the exact E (the direct
    factor's) and its error is near the tolerance asked for, with fewer iterations than the residual rule."""
    _, sample, net = scene("opal_quick", SMALL_OPAL)
    s = sample.structure
    args = (net, s.positions, LOADINGS["plate"].supports(sample))
    exact = solve_compression(*args, solver="direct", say=lambda m: None).modulus_MPa
    by_residual = solve_compression(*args, solver=solver, energy_tol=0, say=lambda m: None)
    for tol in (1e-5, 1e-7):
        res = solve_compression(*args, solver=solver, rtol=1e-14, energy_tol=tol, say=lambda m: None)
        error = res.modulus_MPa / exact - 1
        assert -1e-12 < error < 3 * tol, (tol, error)
        # (the estimate takes the decreases of Stop.window steps at least: where the residual rule stops sooner,
        # block-amg's block Gauss-Seidel on this small sample, 8 iterations, the energy stop comes just after)
        assert res.iterations < max(by_residual.iterations, Stop().window + 2), (tol, res.iterations)
        assert res.stress_MPa == pytest.approx(res.modulus_MPa * res.strain, rel=1e-12)


def test_a_floating_cluster_is_refused_in_one_line(tmp_path, capsys):
    """Bonds of a few particles removed so that one is held by none: the static run says how many
    particles are loose before solving, exit 2."""
    _, sample, net = scene("lattice_sc")
    s = sample.structure
    mobile = np.flatnonzero(~s.groups["substrate"])
    lone = mobile[len(mobile) // 2]
    keep = (s.bonds[:, 0] != lone) & (s.bonds[:, 1] != lone)
    net.i, net.j = net.i[keep], net.j[keep]
    for name in ("n", "L", "a_r", "a_s", "bend", "twist"):
        setattr(net, name, getattr(net, name)[keep])
    args = (net, s.positions, LOADINGS["plate"].supports(sample))
    with pytest.raises(LooseParticlesError, match="1 particles have no bond path to the substrate"):
        solve_compression(*args)
    said = []
    res = solve_compression(*args, drop_loose=True, say=said.append)
    assert res.loose == 1 and "1 loose particles" in said[0] and res.residual < 1.01e-6
    assert np.all(res.u[lone] == 0)


def test_static_settings_are_checked(tmp_path, capsys):
    out = tmp_path / "x"
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=quasi"]) == 2
    assert "compression.method = 'quasi'" in capsys.readouterr().err
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=static",
                 "--set", "compression.solver=lu"]) == 2
    assert "compression.solver" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("workflow, sets", [("opal_quick", SMALL_OPAL), ("quickstart", ())])
def test_static_solution_is_an_equilibrium_of_lammps(tmp_path, workflow, sets):
    """The solution put into LAMMPS (positions + u, quaternions from theta, bpm/rotational with the deck's
    coefficients, no contacts): every free particle is in equilibrium (force and torque below 1e-3 of the
    largest bond force and torque: second-order terms at strain 1e-4) and the force LAMMPS's bonds exert on
    the top layer is the static reaction."""
    from bpm_probe import lammps_response

    _, sample, net = scene(workflow, sets)
    s = sample.structure
    res = solve_compression(net, s.positions, LOADINGS[sample.loading].supports(sample), say=lambda m: None)
    f, tau = lammps_response(tmp_path, s, sample.coefficients, res.u, res.theta)
    scale_f = np.abs(net.bond_forces(res.u, res.theta)).max()
    free = ~s.groups["substrate"] & ~sample.top_layer
    assert np.abs(f[free]).max() < 1e-3 * scale_f
    top = sample.top_layer & ~s.groups["substrate"]
    assert np.abs(f[top][:, :2]).max() < 1e-3 * scale_f
    assert np.abs(tau[~s.groups["substrate"]]).max() < 1e-3 * scale_f * net.L.mean()
    assert f[top, 2].sum() / sample.area_nm2 == pytest.approx(res.stress_MPa, rel=1e-3)


def test_jax_operator_in_chunks_is_the_operator():
    """The JAX operator, run over the bonds in chunks with zero-stiffness padding, equals the numpy one."""
    from opalflow.bpm.static import _operator

    _, _, net = scene("opal_quick", SMALL_OPAL)
    free = np.ones(6 * net.n_particles, bool)
    free[::7] = False
    x = np.random.default_rng(3).normal(size=free.size)
    ref = _operator(net, free, False)[0](x)
    for chunk in (997, 1 << 21):
        got = np.asarray(_operator(net, free, True, chunk=chunk)[0](x))
        assert np.allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max()), chunk


def test_loose_particles_are_refused_before_anything_is_written(tmp_path, capsys):
    """The quickstart at d = 40 nm has one particle no bond holds: the static run says so in one line,
    exit 2, no folder; compression.drop_loose = true solves without it."""
    out = tmp_path / "run"
    sets = ["--set", "packing.diameter_nm=40.0", "--set", "compression.method=static"]
    assert main(["run", "quickstart", "--out", str(out), *sets]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: structure: 1 particles have no bond path to the substrate")
    assert not out.exists()
    assert main(["run", "quickstart", "--out", str(out), *sets, "--set", "compression.drop_loose=true"]) == 0
    assert json.loads((out / "summary.json").read_text())["loose_particles_left_out"] == 1


def test_periodic_lattice_stiffness_tensor_is_analytic(tmp_path, capsys):
    """A simple-cubic lattice periodic in x, y and z: C11 = C22 = C33 = E_b pi r_b^2 / a^2, C12 = 0 and
    C44 = ks / (2 a^2) (a shear strains the y and z bonds sideways; no particle turns, by symmetry)."""
    from opalflow.materials import material

    out = tmp_path / "t"
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=static",
                 "--set", "lattice.periodic_z=true"]) == 0
    s = json.loads((out / "summary.json").read_text())
    C = np.array(s["stiffness_tensor_GPa"])
    m = material("silica")
    a, r_b = 20.0, 10.0
    E_b, nu = m.bond_youngs_modulus_GPa, m.bond_poisson_ratio
    c11 = E_b * np.pi * r_b**2 / a**2
    c44 = E_b / (2 * (1 + nu)) * np.pi * r_b**2 / (2 * a**2)
    assert np.allclose(np.diag(C)[:3], c11, rtol=1e-9) and np.allclose(np.diag(C)[3:], c44, rtol=1e-9)
    assert np.abs(C - np.diag(np.diag(C))).max() < 1e-9 * c11
    assert abs(s["reference"]["youngs_modulus_GPa"]["error"]) < 1e-9
    assert "| zz |" in (out / "report.md").read_text()
    assert main(["run", "lattice_sc", "--out", str(tmp_path / "d"), "--set", "lattice.periodic_z=true"]) == 2
    assert "lattice.periodic_z = True: needs compression.method" in capsys.readouterr().err


def test_stiffness_tensor_of_a_disordered_periodic_network():
    """A periodic FCC lattice with jittered positions: the particles relax (CG iterations), C is symmetric
    and positive definite, below the affine (unrelaxed) tensor, and amg and cg agree."""
    from opalflow.bpm.deck import bond_model
    from opalflow.bpm.static import solve_tensor

    spec = load_spec(WORKFLOWS / "lattice_sc.toml", ["lattice.arrangement=fcc", "lattice.cells_z=4",
                                                     "bonds.cutoff_factor=1.2", "compression.method=static",
                                                     "lattice.periodic_z=true"])
    s = scene_of(spec).build(spec, lambda m: None)
    s.positions += np.random.default_rng(7).normal(0, 0.4, s.positions.shape)
    data, _, coeffs = bond_model(spec, s)
    net = stiffness_network(data, coeffs)
    volume = float(np.prod(data.box_lengths))
    amg = solve_tensor(net, data.positions, volume, solver="amg", say=lambda m: None)
    cg = solve_tensor(net, data.positions, volume, solver="cg", say=lambda m: None)
    C = amg.C_GPa
    assert min(amg.iterations) > 0 and amg.residual < 1e-7
    assert np.allclose(C, C.T, atol=1e-6 * C.max()) and np.linalg.eigvalsh(C).min() > 0
    assert np.allclose(cg.C_GPa, C, atol=1e-6 * C.max())
    # the affine tensor: the same loadings without relaxation (iterations capped at zero)
    affine = solve_tensor(net, data.positions, volume, solver="cg", maxiter=0, say=lambda m: None).C_GPa
    assert np.linalg.eigvalsh(affine - C).min() > -1e-9 * C.max() and np.trace(affine - C) > 1e-3 * np.trace(C)


def test_jax_path_runs_on_the_default_device():
    """cg-jax keeps the operator, the preconditioner and the CG vectors as JAX arrays on JAX's default
    device: the same code runs on a GPU where JAX has one (this machine: the CPU; bench/results says where a GPU
    figure was measured)."""
    import jax

    from opalflow.bpm.static import _operator

    _, _, net = scene("opal_quick", SMALL_OPAL)
    free = np.ones(6 * net.n_particles, bool)
    matvec, dot, array = _operator(net, free, True)
    y = matvec(array(np.ones(free.size)))
    assert isinstance(y, jax.Array) and y.devices() == {jax.devices()[0]}
    assert isinstance(dot(y, y), jax.Array)


@pytest.mark.parametrize("bs,dtype", [(1, np.float64), (3, np.float32), (6, np.float64)])
def test_own_gauss_seidel_sweeps_are_pyamgs(bs, dtype):
    """The V-cycle's sweeps (one share of the rows: the sequential sweep), forward from x = 0 and backward from
    any x, against pyamg's block Gauss-Seidel on a random block-sparse SPD matrix; the forward sweep's residual
    b - A x (the matrix read once: the blocks the sweep did not use) against scipy's product."""
    from pyamg.relaxation.relaxation import block_gauss_seidel

    from opalflow.linalg.multigrid import smoothers

    rng = np.random.default_rng(3)
    n = 40
    A = _spd_bsr(n, bs, 4, 0.15).astype(dtype)
    b = rng.random(n * bs).astype(dtype)
    first, backward = smoothers(A)
    tol = dict(rtol=1e-4, atol=1e-5) if dtype == np.float32 else dict(rtol=1e-12, atol=1e-12)
    x, r = first(b)
    ref = np.zeros_like(b)
    block_gauss_seidel(A, ref, b, iterations=1, sweep="forward", blocksize=bs)
    assert np.allclose(x, ref, **tol) and np.allclose(r, b - A @ x, **tol) and r.dtype == dtype
    assert np.abs(r).max() > 0.05 * np.abs(b).max()          # (not the zero of an exact solve)
    x0 = rng.random(n * bs).astype(dtype)
    ref, x = x0.copy(), x0.copy()
    block_gauss_seidel(A, ref, b, iterations=1, sweep="backward", blocksize=bs)
    backward(x, b)
    assert np.allclose(x, ref, **tol) and not np.allclose(x, x0)


def _spd_bsr(n: int, bs: int, seed: int, density: float = 0.1):
    import scipy.sparse as sp

    M = sp.random(n * bs, n * bs, density=density, random_state=seed)
    return (M @ M.T + 4 * sp.identity(n * bs)).tobsr(blocksize=(bs, bs))


@pytest.mark.parametrize("bs", [3, 6])
def test_hybrid_sweeps_are_each_shares_own_and_the_same_on_any_number_of_threads(bs, monkeypatch):
    """Above PARTS_MIN_ROWS a sweep is hybrid: each share of the rows is a sequential Gauss-Seidel sweep of its own
    block of A, the other shares' unknowns as the sweep found them (moved to the right-hand side: zero for the
    forward sweep from x = 0); one thread and two give the same digits, the forward sweep's residual too (b - A x
    to the rounding, from the blocks the sweep did not use)."""
    from pyamg.relaxation.relaxation import block_gauss_seidel

    from opalflow.linalg import multigrid

    monkeypatch.setattr(multigrid, "PARTS_MIN_ROWS", 1)
    monkeypatch.setattr(multigrid, "SWEEP_PARTS", 3)
    rng = np.random.default_rng(8)
    n = 30
    A = _spd_bsr(n, bs, 9)
    b, x0 = rng.random(n * bs), rng.random(n * bs)
    at = multigrid._shares(n) * bs
    assert len(at) == 4
    (one, r1), (two, r2) = multigrid.smoothers(A, 1)[0](b), multigrid.smoothers(A, 2)[0](b)
    assert np.array_equal(one, two) and np.array_equal(r1, r2)
    assert np.allclose(r1, b - A @ one, rtol=0, atol=1e-12) and np.abs(r1).max() > 0.05
    back1, back2 = x0.copy(), x0.copy()
    multigrid.smoothers(A, 1)[1](back1, b)
    multigrid.smoothers(A, 2)[1](back2, b)
    assert np.array_equal(back1, back2) and not np.allclose(back1, x0)
    for x, start, direction in ((one, np.zeros_like(x0), "forward"), (back1, x0, "backward")):
        for lo, hi in zip(at[:-1], at[1:]):
            own = A.tocsr()[lo:hi, lo:hi].tobsr(blocksize=(bs, bs))
            rest = start.copy()
            rest[lo:hi] = 0.0
            ref = start[lo:hi].copy()
            block_gauss_seidel(own, ref, b[lo:hi] - (A @ rest)[lo:hi], iterations=1, sweep=direction, blocksize=bs)
            assert np.allclose(x[lo:hi], ref, rtol=1e-12), (direction, lo)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_hierarchy_is_pyamgs_without_its_copies(dtype, monkeypatch):
    """The hierarchy (opalflow.linalg.multigrid.hierarchy: the prolongation smoothed in one pass over A, no
    scaled copies of it) against pyamg's smoothed_aggregation_solver with the same options, on a 3D Laplacian
    of 3 x 3 blocks with rigid-body modes: the finest P and the first coarse matrix to the rounding, as many
    levels; one thread and two (hybrid shares) give the same digits.  (Deeper levels may aggregate otherwise:
    pyamg's aggregation follows the order of a row's columns, which its products leave unsorted.)"""
    import pyamg
    import scipy.sparse as sp

    from opalflow.bpm.static import rigid_body_modes
    from opalflow.linalg import multigrid

    monkeypatch.setattr(multigrid, "PARTS_MIN_ROWS", 1)
    A = sp.kron(pyamg.gallery.poisson((14, 12, 10), format="csr"), np.eye(3) + 0.1).tobsr(blocksize=(3, 3))
    A = A.astype(dtype)
    grid = np.stack(np.meshgrid(np.arange(14), np.arange(12), np.arange(10), indexing="ij"), -1).reshape(-1, 3)
    B = rigid_body_modes(grid.astype(float)).reshape(-1, 6, 6)[:, :3, :].reshape(-1, 6).astype(dtype)
    ref = pyamg.smoothed_aggregation_solver(A, B=B, strength=("symmetric", {"theta": 0.0}), max_coarse=100,
                                            smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
                                            improve_candidates=None, presmoother=None, postsmoother=None)
    monkeypatch.setattr(multigrid, "MAX_COARSE", 100)
    one, two = multigrid.hierarchy(A, B, 1), multigrid.hierarchy(A, B, 2)
    assert len(one.levels) == len(ref.levels) >= 3
    tol = 1e-5 if dtype == np.float32 else 1e-12
    for got, want in ((one.levels[0].P, ref.levels[0].P), (one.levels[1].A, ref.levels[1].A)):
        assert got.dtype == dtype and got.blocksize == want.blocksize
        assert abs(got - want).max() <= tol * abs(want).max()
    for a, b in zip(one.levels, two.levels):
        assert (a.A != b.A).nnz == 0
    P = one.levels[0].P
    whole = (P.T @ A @ P).tobsr(blocksize=(6, 6))
    monkeypatch.setattr(multigrid, "SWEEP_PARTS", 5)           # (slabs: the rows in shares)
    slabs = multigrid.galerkin(A, P)
    assert slabs.blocksize == (6, 6) and slabs.has_canonical_format
    assert abs(slabs - whole).max() <= tol * abs(whole).max()


def test_fused_cg_vectors_are_numpys_expressions(monkeypatch):
    """pcg's fused vector work (large numpy vectors: opalflow.linalg.krylov._Vectors, by shares on threads)
    against its numpy expressions on a random SPD system with a Jacobi preconditioner: the same iterations and
    solution to the rounding, one thread and two to the digit, the right-hand side left as it was."""
    import scipy.sparse as sp

    from opalflow.linalg import krylov

    n = 3000
    M = sp.random(n, n, density=0.002, random_state=3)
    K = (M @ M.T + sp.identity(n)).tocsr()
    b = np.random.default_rng(4).normal(size=n)
    d = 1.0 / K.diagonal()

    def solve(threads):
        kept = b.copy()
        x, its = krylov.pcg(lambda v: K @ v, lambda r: d * r, b, Stop(1e-10), lambda k, r: None, threads=threads)
        assert np.array_equal(b, kept)
        return x, its

    plain = solve(1)
    monkeypatch.setattr(krylov, "VECTOR_MIN", 100)
    one, two = solve(1), solve(2)
    assert one[1] == plain[1] > 10 and np.linalg.norm(one[0] - plain[0]) <= 1e-8 * np.linalg.norm(plain[0])
    assert np.array_equal(one[0], two[0]) and np.linalg.norm(K @ one[0] - b) <= 1e-9 * np.linalg.norm(b)


def test_transfers_are_p_and_its_transpose_on_any_number_of_threads(monkeypatch):
    """The V-cycle's P e and P^T r (pyamg's R dropped) against scipy's products, one thread and two alike."""
    import scipy.sparse as sp

    from opalflow.linalg import multigrid

    monkeypatch.setattr(multigrid, "PARTS_MIN_ROWS", 1)
    P = sp.random(60 * 3, 7 * 6, density=0.2, random_state=10).tobsr(blocksize=(3, 6))
    rng = np.random.default_rng(11)
    r, e = rng.random(P.shape[0]), rng.random(P.shape[1])
    (down1, up1), (down2, up2) = multigrid.transfers(P, 1), multigrid.transfers(P, 2)
    assert np.allclose(down1(r), P.T @ r, rtol=1e-12) and np.allclose(up1(e), P @ e, rtol=1e-12)
    assert np.array_equal(down1(r), down2(r)) and np.array_equal(up1(e), up2(e))


def test_v_cycle_of_hybrid_sweeps_is_symmetric(monkeypatch):
    """w . V(v) = v . V(w) and v . V(v) > 0 for the V-cycle whose sweeps are hybrid (several shares) and whose
    restriction is P^T from P, on a 3D Laplacian of 3 x 3 blocks (a stiffness-like matrix: a hybrid sweep, Jacobi
    between its shares, converges where the coupling across them is weak; the samples' shares are contiguous
    slabs of particles): the preconditioner CG needs."""
    import pyamg
    import scipy.sparse as sp

    from opalflow.linalg import multigrid

    monkeypatch.setattr(multigrid, "PARTS_MIN_ROWS", 1)
    A = sp.kron(pyamg.gallery.poisson((10, 10, 6), format="csr"), np.eye(3)).tobsr(blocksize=(3, 3))
    B = np.kron(np.ones((600, 1)), np.eye(3))
    ml = pyamg.smoothed_aggregation_solver(A, B=B, max_coarse=20, presmoother=None, postsmoother=None)
    assert len(ml.levels) > 1
    V = multigrid.v_cycle(ml, 2)
    rng = np.random.default_rng(13)
    v, w = rng.random(1800), rng.random(1800)
    assert w @ V(v) == pytest.approx(v @ V(w), rel=1e-10) and v @ V(v) > 0


def test_bond_operator_on_threads_is_the_operator(monkeypatch):
    """K x with the bonds in two threads' shares (each into a sum of its own) is K x on one, to rounding."""
    from opalflow.bpm import stiffness

    _, _, net = scene("opal_quick", SMALL_OPAL)
    x = np.random.default_rng(7).normal(size=6 * net.n_particles)
    one = net.matvec(x)
    monkeypatch.setattr(stiffness, "PARTS_MIN_BONDS", 1)
    two = net.matvec(x, 2)
    assert np.allclose(two, one, rtol=0, atol=1e-12 * np.abs(one).max()) and not np.array_equal(two, x * 0)


def test_bond_operator_blocks_are_rows_of_the_product(monkeypatch):
    """The bond operator's blocks (stiffness.BLOCKS): "ut" is K's translation rows of (0, theta), "t" its rotation rows
    of x, each with the rest zero; a bond masked out by ``alive`` counts nowhere (the product of the network with
    its stiffness zeroed), on one thread and on two."""
    from dataclasses import replace

    from opalflow.bpm import stiffness

    _, _, net = scene("opal_quick", SMALL_OPAL)
    x = np.random.default_rng(14).normal(size=(net.n_particles, 6))
    alive = np.random.default_rng(15).random(len(net.L)) > 0.2
    cut = replace(net, a_r=net.a_r * alive, a_s=net.a_s * alive, bend=net.bend * alive, twist=net.twist * alive)
    rotations = x.copy()
    rotations[:, :3] = 0.0
    for threads, parts_min in ((1, stiffness.PARTS_MIN_BONDS), (2, 1)):
        monkeypatch.setattr(stiffness, "PARTS_MIN_BONDS", parts_min)
        full = cut.matvec(x.ravel()).reshape(-1, 6)
        scale = np.abs(full).max()
        ut = net.matvec(x.ravel(), threads, alive, "ut").reshape(-1, 6)
        t = net.matvec(x.ravel(), threads, alive, "t").reshape(-1, 6)
        assert np.allclose(ut[:, :3], cut.matvec(rotations.ravel()).reshape(-1, 6)[:, :3], rtol=0, atol=1e-12 * scale)
        assert np.allclose(t[:, 3:], full[:, 3:], rtol=0, atol=1e-12 * scale)
        assert not ut[:, 3:].any() and not t[:, :3].any() and np.abs(ut).max() > 1e-3 * scale
        assert np.allclose(net.matvec(x.ravel(), threads, alive).reshape(-1, 6), full, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("threads", [1, 2])
def test_block_amg_preconditioner_is_symmetric_and_positive(threads):
    """CG needs M^-1 symmetric positive definite: the block Gauss-Seidel sweep over rotations, translations and
    rotations again is (w . M v = v . M w to the float32 V-cycle's rounding; a sweep that skipped the last
    rotation step's product, t, u and not t again, is not: checked), and v . M v > 0."""
    from opalflow.bpm.static import block_amg_preconditioner

    _, sample, net = scene("opal_quick", SMALL_OPAL)
    supports = LOADINGS["plate"].supports(sample)
    free = ~supports.held.ravel()
    M = block_amg_preconditioner(net, free, sample.structure.positions, threads)
    rng = np.random.default_rng(8)
    v, w = (np.where(free, rng.normal(size=free.size), 0.0) for _ in range(2))
    Mv, Mw = M(v), M(w)
    assert w @ Mv == pytest.approx(v @ Mw, rel=1e-5, abs=1e-7 * np.sqrt((Mv @ Mv) * (w @ w)))
    assert v @ Mv > 0 and w @ Mw > 0 and np.all(Mv[~free] == 0)


def test_particle_stress_of_the_intact_bonds_is_that_of_their_network():
    """particle_stress with ``alive`` (the quasi-static run's fracture pictures, no copy of the network) is
    particle_stress over the network of the intact bonds alone, to the digit."""
    from opalflow.bpm.static_run import particle_stress

    _, sample, net = scene("opal_quick", SMALL_OPAL)
    rng = np.random.default_rng(16)
    u, theta = rng.normal(size=(net.n_particles, 3)), rng.normal(size=(net.n_particles, 3))
    alive = rng.random(len(net.L)) > 0.3
    volumes = sample.structure.particle_volumes()
    got = particle_stress(net, u, theta, volumes, alive)
    assert np.array_equal(got, particle_stress(net.part(alive), u, theta, volumes))
    assert not np.array_equal(got, particle_stress(net, u, theta, volumes))
