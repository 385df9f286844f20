"""The nonlinear quasi-static method (opalflow/bpm/nonlinear.py): LAMMPS's bpm/rotational law at finite rotation
agrees with the linear network to first order, gives no force under a rigid motion, balances its forces, and a
run of it finds the strength of a small aerogel slab."""
import numpy as np
import pytest

import opalflow
from opalflow.bpm.nonlinear import bond_loads, internal_force, quat_from_rotation, quat_rotate
from opalflow.bpm.stiffness import BondNetwork


def _network(seed=0, n=30, m=60):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 10, (n, 3))
    i = rng.integers(0, n, m)
    j = (i + 1 + rng.integers(0, n - 1, m)) % n
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    r0 = X[lo] - X[hi]
    L = np.linalg.norm(r0, axis=1)
    return X, BondNetwork(n, lo, hi, r0 / L[:, None], L, rng.uniform(1, 2, m), rng.uniform(0.5, 1, m),
                          rng.uniform(0.1, 0.3, m), rng.uniform(0.1, 0.3, m)), rng


def test_small_motions_give_the_linear_networks_forces():
    """The error of the finite-rotation law against K x falls as the motion's size: first order exact."""
    X, net, rng = _network()
    x = rng.normal(size=(net.n_particles, 6))
    errors = []
    for h in (1e-3, 1e-4, 1e-5):
        g = internal_force(net, bond_loads(net, h * x[:, :3], quat_from_rotation(h * x[:, 3:])))
        k = net.matvec(h * x.ravel()).reshape(-1, 6)
        errors.append(np.abs(g - k).max() / np.abs(k).max())
    assert errors[0] < 2e-3 and errors[1] < errors[0] / 5 and errors[2] < errors[1] / 5


def test_a_rigid_motion_loads_no_bond_and_forces_balance():
    """Turned by 0.6 rad and moved, the network carries nothing (atan2 angles: no acos noise); under any motion
    the bonds' forces sum to zero (action and reaction)."""
    X, net, rng = _network(1)
    R = quat_from_rotation(np.tile([0.3, -0.2, 0.5], (net.n_particles, 1)))
    u = quat_rotate(R, X) + 5.0 - X
    assert np.abs(internal_force(net, bond_loads(net, u, R))).max() < 1e-10
    x = 0.05 * rng.normal(size=(net.n_particles, 6))
    g = internal_force(net, bond_loads(net, x[:, :3], quat_from_rotation(x[:, 3:])))
    assert np.abs(g[:, :3].sum(axis=0)).max() < 1e-9 * np.abs(g).max()


def test_a_nonlinear_run_finds_the_first_break_of_an_aerogel_slab(tmp_path):
    """300 spheres, no contacts: E within 5 % of the linear method's, a strength, and the linear method's first
    break within 25 % of the nonlinear one's strain (the two part as the branches turn)."""
    sets = {"aggregate.particles": 300, "compression.method": "quasistatic", "bonds.smooth": False,
            "compression.strain_max": 0.5, "contacts.enabled": False}
    lin = opalflow.run("aerogel_compression", tmp_path / "lin", set=sets, quiet=True)
    nl = opalflow.run("aerogel_compression", tmp_path / "nl", set={**sets, "compression.geometry": "nonlinear"},
                      quiet=True)
    assert nl["quasistatic"]["resolver"] == "newton" and nl["strength_MPa"] > 0
    assert nl["youngs_modulus_GPa"] == pytest.approx(lin["youngs_modulus_GPa"], rel=0.05)
    assert nl["strain_at_peak"] == pytest.approx(lin["strain_at_peak"], rel=0.25)


def test_nonlinear_geometry_is_the_quasistatic_methods():
    with pytest.raises(opalflow.spec.SpecError, match="compression.geometry"):
        opalflow.build("aerogel_compression", "/tmp/never", set={"compression.geometry": "nonlinear"}, quiet=True)
