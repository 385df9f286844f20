"""Properties of a Tersoff set computed by LAMMPS (``pair_style tersoff``, ``units metal``).

A periodic diamond crystal of ``cells``^3 conventional cells is relaxed to zero pressure
(``fix box/relax iso``) for the lattice constant a0 and the cohesive energy; each elastic
constant is then a central second difference of the energy per atom (seed 003, eq. 16)

    d2E/de2 ~ (E(D+) - 2 E(0) + E(D-)) / e^2

under the deformations of eq. 14 and its relatives (see :class:`DiamondModel` for the
formulas B, C', C11, C12, C44^0, C44).  For C44 the atoms are relaxed (``minimize``) in
each sheared box, which is the internal relaxation; C44^0 keeps them on the affine
positions.  The strain ``e`` is scanned over decades: too small and round-off in E
(1e-16 relative) dominates, too large and the quartic terms do; the plateau between is
reported with the value.
"""
from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from opalflow.lammps.engine import session
from opalflow.tersoff.model import EV_PER_A3_GPA
from opalflow.tersoff.parameters import TersoffParameters, write_tersoff

SI_MASS = 28.0855      # g/mol (metal units)
POTENTIAL_FILE = "potential.tersoff"
MODULI_KEYS = ("B_GPa", "Cprime_GPa", "C11_GPa", "C12_GPa", "C44_0_GPa", "C44_GPa")

# strain paths: F(e) as (xx, yy, zz, xy) increments; relax = atoms minimised in the strained box
PATHS = {
    "iso": ((1, 1, 1, 0), False),
    "tet": ((1, -1, 0, 0), False),
    "shear": ((0, 0, 0, 1), False),
    "shear_relaxed": ((0, 0, 0, 1), True),
}


def setup_commands(a: float, cells: int, element: str, triclinic: bool = True) -> str:
    """Periodic diamond crystal of cells^3 conventional cells at lattice constant a, Tersoff potential."""
    region = f"prism 0 {cells} 0 {cells} 0 {cells} 0 0 0" if triclinic else f"block 0 {cells} 0 {cells} 0 {cells}"
    return f"""
units metal
atom_style atomic
atom_modify map array
boundary p p p
lattice diamond {a:.12g}
region cell {region}
create_box 1 cell
create_atoms 1 box
mass 1 {SI_MASS}
pair_style tersoff
pair_coeff * * {POTENTIAL_FILE} {element}
thermo_style custom step pe press
thermo_modify norm no
"""


class LammpsCrystal:
    """Energies per atom of the diamond crystal under homogeneous strain, from LAMMPS."""

    def __init__(self, lmp, a: float, cells: int):
        self.lmp, self.a, self.cells = lmp, a, cells
        self.n = lmp.get_natoms()
        self.x0 = np.array(lmp.gather_atoms("x", 1, 3), dtype=float)
        self.L = a * cells

    def energy(self, e: float = 0.0, path: str = "iso") -> float:
        """E per atom (eV) with F = I + e * increments of ``path``; atoms relaxed if the path says so."""
        (dxx, dyy, dzz, dxy), relax = PATHS[path]
        lmp, L = self.lmp, self.L
        lmp.command(f"change_box all x final 0 {L:.17g} y final 0 {L:.17g} z final 0 {L:.17g} "
                    "xy final 0 units box")
        lmp.scatter_atoms("x", 1, 3, (self.x0.size * ctypes.c_double)(*self.x0))
        lmp.command(f"change_box all x final 0 {L * (1 + e * dxx):.17g} y final 0 {L * (1 + e * dyy):.17g} "
                    f"z final 0 {L * (1 + e * dzz):.17g} xy final {L * e * dxy:.17g} remap units box")
        lmp.command("run 0 post no")
        if relax:
            lmp.command("minimize 0 1e-12 10000 100000")
        return lmp.get_thermo("pe") / self.n


@dataclass
class Evaluation:
    """LAMMPS properties of one parameter set."""

    a0_A: float
    Ec_eV: float
    values: dict[str, float]                  # at the chosen strain
    strain: float
    spread: dict[str, float]                  # max - min over the strains within a decade of it
    scan: dict[float, dict[str, float]] = field(default_factory=dict)   # strain -> properties
    scan_s: dict[float, float] = field(default_factory=dict)            # strain -> seconds
    seconds: float = 0.0                      # all of it: set-up, lattice relaxation, every strain


def relax_lattice(lmp, cells: int) -> float:
    """Zero-pressure lattice constant (A) by minimising with an isotropic box relaxation."""
    lmp.command("fix relax all box/relax iso 0.0 vmax 0.001")
    lmp.command("min_modify line quadratic")
    lmp.command("minimize 0 1e-11 10000 100000")
    lmp.command("unfix relax")
    return lmp.get_thermo("lx") / cells


def constants(d2: dict[str, float], omega: float) -> dict[str, float]:
    """Elastic constants (GPa) from second derivatives of E per atom along the PATHS (eV)."""
    k = EV_PER_A3_GPA / omega
    bulk, cp = d2["iso"] * k / 9.0, d2["tet"] * k / 4.0
    return {"B_GPa": bulk, "Cprime_GPa": cp, "C11_GPa": bulk + 4.0 * cp / 3.0,
            "C12_GPa": bulk - 2.0 * cp / 3.0, "C44_0_GPa": d2["shear"] * k, "C44_GPa": d2["shear_relaxed"] * k}


def evaluate(params: TersoffParameters, folder: str | Path, *, strain: float = 1e-3,
             scan: tuple[float, ...] = (), cells: int = 2, a_guess: float = 5.431,
             a: float | None = None) -> Evaluation:
    """Lattice constant, Ec and elastic constants of ``params`` by LAMMPS.

    The crystal is relaxed to zero pressure unless ``a`` fixes the lattice constant.
    ``scan`` adds the same evaluation at other strain sizes (timed one by one);
    ``strain`` is the one reported.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_tersoff(folder / POTENTIAL_FILE, params, "written by opalflow for this evaluation")
    t0 = time.perf_counter()
    with session(folder, log="log.properties.lammps") as lmp:
        if a is None:
            lmp.commands_string(setup_commands(a_guess, cells, params.element))
            a = relax_lattice(lmp, cells)
            lmp.command("clear")
        lmp.commands_string(setup_commands(a, cells, params.element))
        crystal = LammpsCrystal(lmp, a, cells)
        e0 = crystal.energy()
        omega = a ** 3 / 8.0
        strains = sorted(set(scan) | {strain})
        table, times = {}, {}
        for h in strains:
            t = time.perf_counter()
            d2 = {p: (crystal.energy(h, p) - 2.0 * e0 + crystal.energy(-h, p)) / h ** 2 for p in PATHS}
            table[h] = constants(d2, omega)
            times[h] = time.perf_counter() - t
    near = [h for h in strains if strain / 10.0 <= h <= strain * 10.0]
    spread = {k: max(table[h][k] for h in near) - min(table[h][k] for h in near) for k in MODULI_KEYS}
    return Evaluation(a0_A=a, Ec_eV=e0, values=table[strain], strain=strain, spread=spread,
                      scan=table if scan else {}, scan_s=times if scan else {},
                      seconds=time.perf_counter() - t0)
