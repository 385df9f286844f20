"""The linearised bpm/rotational bond network (opalflow/bpm/stiffness.py) against LAMMPS itself:
forces and torques of small random displacements and rotations, symmetry, rigid-body modes."""
import numpy as np
import pytest

from bpm_probe import lammps_response

from opalflow.bpm.stiffness import damping_network, mass_diagonal, spring_network, stiffness_network
from opalflow.materials import bond_coefficients
from opalflow.structure import Structure


def cluster(seed: int = 4) -> tuple[Structure, list]:
    """Six particles of 60 nm in a random cluster, bonded to their neighbours within 1.3 d, two bond
    types of different stiffness (bonds in every direction, unequal lengths)."""
    rng = np.random.default_rng(seed)
    d = 60.0
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.85, 0], [0.5, 0.3, 0.8], [1.5, 0.6, 0.4], [-0.4, 0.7, 0.6]]) * d
    x += rng.normal(0, 3.0, x.shape) + 500.0
    pairs = [(a, b) for a in range(6) for b in range(a + 1, 6) if np.linalg.norm(x[a] - x[b]) < 1.3 * d]
    s = Structure(positions=x, diameters=np.full(6, d), types=np.ones(6), densities=np.full(6, 2.2e-3),
                  box_lo=np.zeros(3), box_hi=np.full(3, 1000.0), periodic=np.zeros(3, bool), bonds=pairs,
                  bond_types=[1 + k % 2 for k in range(len(pairs))], type_names=["silica"],
                  bond_type_names=["a", "b"])
    coeffs = [bond_coefficients("silica", 0.6 * d / 2, 62.0, 0.25, 200.0, 0.3),
              bond_coefficients("silica", 0.4 * d / 2, 58.0, 0.25, 200.0, 0.7)]
    return s, coeffs


def test_stiffness_is_lammps_linearisation(tmp_path):
    s, coeffs = cluster()
    net = stiffness_network(s, coeffs)
    assert net.i.size >= 9
    rng = np.random.default_rng(1)
    eps = 1e-5
    u = rng.normal(0, 1.0, (6, 3)) * 60.0 * eps
    theta = rng.normal(0, 1.0, (6, 3)) * eps
    f_lmp, tau_lmp = lammps_response(tmp_path, s, coeffs, u, theta)
    f, tau = net.forces(u, theta)
    scale_f, scale_t = np.abs(f_lmp).max(), np.abs(tau_lmp).max()
    assert scale_f > 0 and scale_t > 0
    # second-order terms are eps ~ 1e-5 of the first-order ones
    assert np.abs(f - f_lmp).max() < 1e-4 * scale_f
    assert np.abs(tau - tau_lmp).max() < 1e-4 * scale_t


def test_damping_is_lammps_linearisation(tmp_path):
    """At the reference positions, forces are the damping matrix times the velocities alone."""
    s, coeffs = cluster()
    net = damping_network(s, coeffs)
    rng = np.random.default_rng(2)
    v = rng.normal(0, 1.0, (6, 3))
    omega = rng.normal(0, 0.02, (6, 3))
    zero = np.zeros((6, 3))
    f_lmp, tau_lmp = lammps_response(tmp_path, s, coeffs, zero, zero, v, omega)
    f, tau = net.forces(v, omega)
    # the data file holds positions to ~1e-9 relative: bond directions differ by that much
    assert np.abs(f - f_lmp).max() < 1e-7 * np.abs(f_lmp).max()
    assert np.abs(tau - tau_lmp).max() < 1e-7 * np.abs(tau_lmp).max()


@pytest.mark.parametrize("which", [stiffness_network, damping_network])
def test_matrix_is_symmetric_with_six_rigid_body_modes(which):
    s, coeffs = cluster()
    net = which(s, coeffs)
    K = np.column_stack([net.matvec(e) for e in np.eye(36)])
    assert np.allclose(K, K.T, atol=1e-12 * np.abs(K).max())
    from opalflow.bpm.static import diagonal_blocks, rotation_diagonal
    assert np.allclose(diagonal_blocks(net), np.array([K[6 * k:6 * k + 6, 6 * k:6 * k + 6] for k in range(6)]))
    # (block-amg's rotational block Jacobi: the kernel's blocks are K's)
    assert np.allclose(rotation_diagonal(net), np.array([K[6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] for k in range(6)]))
    # rigid translations and rotations: u = t + w x (x - c), theta = w
    c = s.positions.mean(axis=0)
    for k in range(6):
        t, w = np.eye(6)[k, :3], np.eye(6)[k, 3:]
        u = t + np.cross(w, s.positions - c)
        x = np.hstack([u, np.tile(w, (6, 1))]).ravel()
        assert np.abs(K @ x).max() < 1e-10 * np.abs(K).max() * np.abs(x).max()
    eig = np.linalg.eigvalsh(K / np.sqrt(np.outer(mass_diagonal(s), mass_diagonal(s))))
    assert np.sum(np.abs(eig) < 1e-9 * eig.max()) == 6 and eig.min() > -1e-9 * eig.max()


def test_assembled_blocks_are_the_operators_matrix():
    """block_matrix's K (6 x 6 blocks, numpy) and K_uu (3 x 3 blocks, the numba pass of block-amg) against the
    matrix-free operator's matrix, prescribed dofs decoupled with their diagonal kept."""
    from opalflow.bpm.static import block_matrix

    s, coeffs = cluster()
    net = stiffness_network(s, coeffs)
    K = np.column_stack([net.matvec(e) for e in np.eye(36)])
    free = np.ones((6, 6), bool)
    free[0] = False
    free[3, [1, 2, 4]] = False

    def decoupled(K, f):
        return K * np.outer(f, f) + np.diag(np.where(f, 0.0, np.diag(K)))

    t = (6 * np.arange(6)[:, None] + np.arange(3)).ravel()
    for part, dofs, mask in (("all", np.arange(36), free), ("translation", t, free[:, :3])):
        A = block_matrix(net, mask, part=part)[0].toarray()
        assert np.abs(A - decoupled(K[np.ix_(dofs, dofs)], mask.ravel())).max() < 1e-12 * np.abs(K).max()


def test_the_sorted_layout_and_the_kernels_are_the_same_arrays(monkeypatch):
    """block_layout by numpy's stable sort (small networks) and by the numba kernel (large ones) give the same
    (indptr, indices, pos), two bonds between one pair in bond order; and the direct factor of the whole K
    on its free dofs solves what the decoupled K solves."""
    from opalflow.bpm import static
    from opalflow.bpm.stiffness import BondNetwork
    from opalflow.linalg.direct import Factor

    rng = np.random.default_rng(3)
    n, m = 300, 1500
    i = rng.integers(0, n - 1, m)
    j = np.maximum(i + 1, rng.integers(0, n, m))
    i, j = np.concatenate([i, i[:7]]), np.concatenate([j, j[:7]])          # seven pairs bonded twice
    nv = rng.normal(size=(len(i), 3))
    nv /= np.linalg.norm(nv, axis=1)[:, None]
    ones = np.ones(len(i))
    net = BondNetwork(n, i, j, nv, ones, ones, 0.3 * ones, 0.1 * ones, 0.1 * ones)
    by_sort = static.block_layout(net)
    monkeypatch.setattr(static, "LAYOUT_SORT_MAX_BONDS", 0)
    by_kernel = static.block_layout(net)
    assert [a.dtype for a in by_sort] == [a.dtype for a in by_kernel]
    assert all(np.array_equal(a, b) for a, b in zip(by_sort, by_kernel))
    free = np.ones(6 * n, bool)
    free[:60] = False
    b = np.where(free, rng.normal(size=6 * n), 0.0)
    whole, decoupled = static.block_matrix(net)[0], static.block_matrix(net, free)[0]
    x = Factor(whole, free).solve(b)
    assert np.abs(x[~free]).max() == 0.0
    assert np.allclose(x, Factor(decoupled).solve(b), rtol=0, atol=1e-9 * np.abs(x).max())


def test_bond_forces_by_numpy_and_by_the_kernel_agree(monkeypatch):
    """BondNetwork.bond_forces by numpy (small networks) and by the numba pass (large ones): the same F for
    random displacements, rotations and a per-bond stretch, and F is what the operator's matrix applies."""
    from opalflow.bpm import stiffness

    s, coeffs = cluster()
    net = stiffness_network(s, coeffs)
    rng = np.random.default_rng(5)
    u, theta, stretch = rng.normal(size=(6, 3)), rng.normal(size=(6, 3)), rng.normal(size=(len(net.L), 3))
    by_numpy = [net.bond_forces(u, theta), net.bond_forces(u, theta, stretch)]
    monkeypatch.setattr(stiffness, "NUMPY_MAX_BONDS", -1)
    by_kernel = [net.bond_forces(u, theta), net.bond_forces(u, theta, stretch)]
    for a, b in zip(by_numpy, by_kernel):
        assert np.abs(a - b).max() < 1e-13 * np.abs(b).max()
    f, _ = net.forces(u, theta)             # f_j += F, f_i -= F
    tally = np.zeros((6, 3))
    np.add.at(tally, net.j, by_numpy[0])
    np.add.at(tally, net.i, -by_numpy[0])
    assert np.abs(tally - f).max() < 1e-12 * np.abs(f).max()


@pytest.mark.parametrize("mode", ["kr", "ks", "kt", "kb"])
def test_each_bond_mode_alone_and_the_error_falls_with_the_amplitude(tmp_path, mode):
    """One bond mode at a time (the other three stiffnesses zero): LAMMPS's forces and torques against
    K u at amplitudes 1e-3 .. 1e-6 d (and rad).  The error is second order: it falls tenfold per decade
    (measured: 2e-3, 2e-4, 2e-5 for each mode) until LAMMPS's own angles lose digits: elastic_forces
    takes the shear, bending and twisting angles as acos of cosines, whose absolute error is ~1e-16 /
    angle, a relative floor of ~1e-16 / angle^2 (1e-4 at 1e-6 rad: measured 9e-5 shear, 4e-4 bending and
    twisting; the axial mode, from a length, stays second order: 1.8e-6)."""
    import dataclasses

    s, coeffs = cluster()
    coeffs = [dataclasses.replace(c, **{k: 0.0 for k in ("kr", "ks", "kt", "kb") if k != mode}) for c in coeffs]
    net = stiffness_network(s, coeffs)
    rng = np.random.default_rng(5)
    du, dth = rng.normal(0, 1.0, (6, 3)) * 60.0, rng.normal(0, 1.0, (6, 3))
    errors = []
    for k, eps in enumerate((1e-3, 1e-4, 1e-5, 1e-6)):
        (tmp_path / str(k)).mkdir()
        f_lmp, tau_lmp = lammps_response(tmp_path / str(k), s, coeffs, du * eps, dth * eps)
        f, tau = net.forces(du * eps, dth * eps)
        scale = max(np.abs(f_lmp).max(), np.abs(tau_lmp).max() / 60.0)
        errors.append(max(np.abs(f - f_lmp).max(), np.abs(tau - tau_lmp).max() / 60.0) / scale)
    print(mode, " ".join(f"{e:.1e}" for e in errors))
    assert errors[0] > 5 * errors[1] > 25 * errors[2]
    assert errors[2] <= 3e-5 and errors[3] <= 1e-3
    if mode == "kr":
        assert errors[3] <= 1e-5


def test_spring_bonds_are_lammps_linearisation(tmp_path):
    """bond_style bpm/spring (normalize yes): forces against K u, no torques at all; its damping against
    C v at rest."""
    s, _ = cluster()
    k, gamma = [800.0, 1300.0], [7.0, 11.0]
    lines = ["bond_style bpm/spring normalize yes smooth yes break yes",
             *(f"bond_coeff {t + 1} {k[t]} 0.5 {gamma[t]}" for t in range(2))]
    net = spring_network(s, k)
    rng = np.random.default_rng(6)
    u, theta = rng.normal(0, 1.0, (6, 3)) * 60.0 * 1e-5, rng.normal(0, 1.0, (6, 3)) * 1e-5
    (tmp_path / "k").mkdir()
    f_lmp, tau_lmp = lammps_response(tmp_path / "k", s, None, u, theta, bond_lines=lines)
    f, tau = net.forces(u, theta)
    assert np.abs(f - f_lmp).max() < 1e-4 * np.abs(f_lmp).max()
    assert not tau.any() and not tau_lmp.any()
    v = rng.normal(0, 1.0, (6, 3))
    zero = np.zeros((6, 3))
    (tmp_path / "c").mkdir()
    f_lmp, _ = lammps_response(tmp_path / "c", s, None, zero, zero, v, zero, bond_lines=lines)
    f, _ = spring_network(s, gamma, normalize=False).forces(v, zero)
    assert np.abs(f - f_lmp).max() < 1e-7 * np.abs(f_lmp).max()
