"""The batched Tersoff against LAMMPS ``pair_style tersoff`` on the same samples.

LAMMPS takes a restricted triclinic cell (a along x, b in the xy plane), so each sample is
turned into that frame (H = R U, QR with a positive diagonal; positions R^T x), run for one
force evaluation, and its forces and virial are turned back with R.  Energies compare
directly; the virial is compared in eV (sum r (x) dE/dr), converted from LAMMPS's pressure with
LAMMPS's own nktv2p, so the unit constant is not part of the difference.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from opalflow.lammps.engine import session
from opalflow.tersoff.model import EV_PER_A3_GPA
from opalflow.tersoff.parameters import TersoffParameters, write_tersoff
from opalflow.tersoff.polycrystal.result import LammpsCheck
from opalflow.tersoff.polycrystal.samples import Samples, random_rotations
from opalflow.tersoff.properties import SI_MASS


def lammps_frame(cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (rotation) and U (upper triangular, positive diagonal) with cell = R U."""
    r, u = np.linalg.qr(cell)
    sign = np.sign(np.diag(u))
    return r * sign, sign[:, None] * u


def lammps_sample(folder: Path, params: TersoffParameters, x: np.ndarray,
                  cell: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Energy (eV), forces (N, 3; eV/A) and virial (3, 3; eV) of one sample by LAMMPS, in the sample's frame."""
    r, u = lammps_frame(cell)
    xl = x @ r                                    # R^T x for every atom
    write_tersoff(folder / "potential.tersoff", params, "batched-Tersoff check")
    lines = ["sample (opalflow batched-Tersoff check)", "", f"{len(x)} atoms", "1 atom types", "",
             f"0 {float(u[0, 0])!r} xlo xhi", f"0 {float(u[1, 1])!r} ylo yhi", f"0 {float(u[2, 2])!r} zlo zhi",
             f"{float(u[0, 1])!r} {float(u[0, 2])!r} {float(u[1, 2])!r} xy xz yz", "", "Masses", "", f"1 {SI_MASS}", "", "Atoms # atomic", ""]
    frac = np.linalg.solve(u, xl.T).T % 1.0      # wrapped into the cell: LAMMPS wants atoms inside
    xw = frac @ u.T
    lines += [f"{i + 1} 1 {float(p[0])!r} {float(p[1])!r} {float(p[2])!r}" for i, p in enumerate(xw)]
    (folder / "sample.data").write_text("\n".join(lines) + "\n")
    with session(folder, log="log.check.lammps") as lmp:
        lmp.commands_string(f"""
units metal
atom_style atomic
atom_modify map array sort 0 0
boundary p p p
read_data sample.data
pair_style tersoff
pair_coeff * * potential.tersoff {params.element}
compute virial all pressure NULL virial
thermo_style custom step pe c_virial[1]
thermo_modify norm no
run 0 post no
""")
        energy = lmp.get_thermo("pe")
        p = np.array(lmp.numpy.extract_compute("virial", 0, 1), dtype=float)
        nktv2p = lmp.extract_global("nktv2p")
        ids = np.array(lmp.numpy.extract_atom("id"))[:len(x)]
        f = np.array(lmp.numpy.extract_atom("f"))[:len(x)][np.argsort(ids)]
    volume = abs(np.linalg.det(u))
    pl = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    virial = -pl * volume / nktv2p               # sum r (x) dE/dr = -W (eV)
    return energy, f @ r.T, r @ virial @ r.T


def compare_with_lammps(samples: Samples, params: TersoffParameters, folder: Path, count: int = 4,
                        strain: float = 0.01, displacement_A: float = 0.05, seed: int = 7) -> LammpsCheck:
    """Largest relative differences batched - LAMMPS over ``count`` random samples.

    Each sample: a uniformly random rotation, a random symmetric strain with entries up to
    ``strain``, Gaussian thermal displacements of ``displacement_A`` (A) per component.
    Relative: |difference| / the largest magnitude of that quantity in the sample.
    """
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    rot = random_rotations(count, seed)
    eps = rng.uniform(-strain, strain, (count, 3, 3))
    eps = 0.5 * (eps + eps.transpose(0, 2, 1))
    cells = np.einsum("eab,ebc->eac", np.eye(3) + eps, samples.reference_cells(rot))
    x = samples.positions(cells) + rng.normal(0.0, displacement_A, (count, samples.n, 3))
    ev = samples.evaluate(x, cells)
    worst = np.zeros(3)                          # energy, forces, virial
    for e in range(count):
        energy, forces, virial_ref = lammps_sample(folder, params, x[e], cells[e])
        virial = ev.stress[e] * abs(np.linalg.det(cells[e])) / EV_PER_A3_GPA
        worst = np.maximum(worst, [abs(ev.energy[e] - energy) / abs(energy),
                                   np.abs(ev.forces[e] - forces).max() / np.abs(forces).max(),
                                   np.abs(virial - virial_ref).max() / np.abs(virial_ref).max()])
    return LammpsCheck(count, strain, displacement_A, *(float(w) for w in worst))
