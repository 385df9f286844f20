"""LAMMPS's own bpm/rotational forces and torques for given displacements, rotations and velocities of a
structure: the reference the linearised bond network is tested against (test_stiffness, test_static)."""
import numpy as np

from opalflow.lammps.datafile import write_data
from opalflow.lammps.engine import session
from opalflow.lammps.syntax import num


def quaternion(rot: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(rot, axis=1)
    axis = rot / np.where(angle > 0, angle, 1)[:, None]
    return np.column_stack([np.cos(angle / 2), np.sin(angle / 2)[:, None] * axis])


def lammps_response(tmp_path, s, coeffs, u, theta, v=None, omega=None, bond_lines=None):
    """Forces and torques LAMMPS's bpm/rotational (or the style of ``bond_lines``) gives at x + u, rotations
    theta and velocities v, omega;
    with velocities, less those it gives at rest: ``acos`` of a cosine that rounds to 1 - 1e-16 makes a
    shear angle of ~1.5e-8 rad in a random direction at rest (elastic_forces), ~1.5e-8 ks per bond (a
    displaced bond has none: its angle is far from 0)."""
    write_data(tmp_path / "data.lmp", s)
    lines = ["units nano", "atom_style bpm/sphere", "boundary p p f" if s.periodic[0] else "boundary f f f",
             "newton on off",
             "comm_modify vel yes cutoff 200", "special_bonds lj 0.0 1.0 1.0 coul 1.0 1.0 1.0",
             "read_data data.lmp",
             *(bond_lines or ["bond_style bpm/rotational normalize yes smooth yes break yes",
                              *(f"bond_coeff {t + 1} " + " ".join(num(x) for x in c.values())
                                for t, c in enumerate(coeffs))]),
             "pair_style zero 200.0", "pair_coeff * *", "run 0"]
    with session(tmp_path) as lmp:
        for line in lines:
            lmp.command(line)          # bond reference states are stored at this first run
        nlocal = lmp.extract_global("nlocal")       # the arrays hold ghost atoms after the local ones

        def atoms(name):
            return lmp.numpy.extract_atom(name)[:nlocal]

        ids = atoms("id").copy()
        order = np.argsort(ids)
        f0 = atoms("f")[order].copy()
        tau0 = atoms("torque")[order].copy()
        x = atoms("x")
        q = atoms("quat")
        x[order] += u
        q[order] = quaternion(theta)
        if v is not None:
            atoms("v")[order] = v
            atoms("omega")[order] = omega
        lmp.command("run 0")
        f = atoms("f")[order].copy()
        tau = atoms("torque")[order].copy()
    if v is not None:
        f, tau = f - f0, tau - tau0
    return f, tau
