"""LAMMPS and LIGGGHTS 3.8 decks of one contact-only scene, and the two engines that run them.

LIGGGHTS (Debian package ``liggghts``) is granular only: it has no bonded-particle model, so the bonded
scenes run on LAMMPS; a contact-only scene runs on either.  The same data file (``atom_style sphere`` /
``granular``: id type diameter density x y z, SI units) feeds both decks; walls are planes normal to z
(a LAMMPS ``fix wall/gran/region`` plane, a LIGGGHTS ``fix mesh/surface/stress`` from an STL file).

Mapping (one material, the walls made of it too, as LAMMPS's ``fix wall/gran`` assumes; the effective
moduli of two equal bodies: Y* = E / (2 (1-nu^2)), G* = E / (4 (2-nu)(1+nu)); sources: LIGGGHTS 3.8
src/normal_model_hertz.h, tangential_model_history.h, surface_model_default.h; LAMMPS
src/GRANULAR/granular_model.cpp, gran_sub_mod_tangential.cpp, gran_sub_mod_damping.cpp):

========================  ==========================================  ==========================================
quantity                  LIGGGHTS 3.8 (pair gran hertz, history)     LAMMPS (pair granular)
========================  ==========================================  ==========================================
normal force              4/3 Y* sqrt(R* d) d                         hertz/material E e nu: the same E*
normal damping            -2 sqrt(5/6) beta sqrt(S_n m*),             damping coeff_restitution: the same
                          S_n = 2 Y* sqrt(R* d), beta(e)
tangential stiffness      k_t = 8 G* sqrt(R* d)                       mindlin NULL: k_t = 8 G* a, the same G*
tangential damping        gamma_n sqrt(S_t / S_n), S_t = 8 G* a       x_gamma,t gamma_n with
                                                                      x_gamma,t = sqrt(4 G* / Y*)
                                                                      = sqrt(2 (1-nu) / (2-nu))
Coulomb limit             on the elastic (history) force; a sliding   on the total (elastic + damping) force
                          contact has no tangential damping
rotational part of the    (R - d/2) omega: the contact point          R omega (the torque uses R - d/2)
relative velocity         (torque arm the same)
history of a contact      kept from an earlier contact of the same    zero: each contact starts anew
that closes again         pair (measured, not documented)
========================  ==========================================  ==========================================

Where they agree and where they part is measured by the ``granular_impacts`` workflow
(opalflow/granular/impacts.py, Chung and Ooi's single-impact benchmarks): normal impacts and sticking
impacts of spheres that do not rotate agree to round-off; spin, sliding with damping and a second
contact of the same pair each part them.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.granular.spec import GranularMaterialSpec
from opalflow.lammps.engine import EngineError, log_tail, session
from opalflow.lammps.syntax import num
from opalflow.spec import SpecError
from opalflow.store import write_text_atomic
from opalflow.version import __version__

#: what the decks print each output step: the plate's force, or the projectile's (atom 2) velocity and spin
OBSERVABLES = {"plate": ("plate_force",), "projectile": ("vx", "vz", "omegay")}


@dataclass(frozen=True)
class Wall:
    """A plane z = ``z`` (m); ``normal`` +1 when the particles lie above it, -1 below; ``speed`` (m/s)
    moves it along -z (a plate pressing down)."""

    name: str
    z: float
    normal: int
    speed: float = 0.0


@dataclass(frozen=True)
class Contact:
    """The contact law of one scene: the material and the friction coefficient it runs with."""

    material: GranularMaterialSpec
    friction: float

    @property
    def lammps(self) -> str:
        m = self.material
        return (f"hertz/material {num(m.youngs_modulus_Pa)} {num(m.restitution)} {num(m.poisson_ratio)} "
                f"tangential mindlin NULL {num(x_gamma_t(m.poisson_ratio))} {num(self.friction)} "
                "damping coeff_restitution")


def liggghts_executable(where: str, value) -> str:
    """The path of ``liggghts``; refuses ``where = value`` in one line where it is not on PATH."""
    exe = shutil.which("liggghts")
    if exe is None:
        raise SpecError(where, value, "needs the 'liggghts' executable (Debian package liggghts), which is not on PATH")
    return exe


def x_gamma_t(nu: float) -> float:
    """LAMMPS's tangential damping factor that equals LIGGGHTS's sqrt(S_t / S_n) for one material:
    S_t / S_n = 8 G* a / (2 Y* a) with the effective moduli of two equal bodies (the table above)."""
    return math.sqrt(2 * (1 - nu) / (2 - nu))


def write_spheres(path: Path, title: str, types, diameters, positions, density: float, box) -> None:
    """An ``atom_style sphere`` data file (SI); ``box`` is ((xlo, xhi), (ylo, yhi), (zlo, zhi))."""
    rows = "\n".join(f"{i + 1} {int(t)} {float(d)!r} {density!r} " + " ".join(repr(float(c)) for c in x)
                     for i, (t, d, x) in enumerate(zip(types, diameters, positions)))
    bounds = "".join(f"{float(lo)!r} {float(hi)!r} {a}lo {a}hi\n" for (lo, hi), a in zip(box, "xyz"))
    write_text_atomic(path, f"opalflow {__version__} {title} (SI units)\n\n{len(types)} atoms\n2 atom types\n\n"
                      f"{bounds}\nAtoms # sphere\n\n{rows}\n")


def write_plane_stl(path: Path, wall: Wall, box) -> None:
    """The wall as two triangles over the box's x-y extent (LIGGGHTS meshes)."""
    (x0, x1), (y0, y1) = ((float(lo), float(hi)) for lo, hi in box[:2])
    tris = (((x0, y0), (x1, y0), (x1, y1)), ((x0, y0), (x1, y1), (x0, y1)))
    facets = "".join(f" facet normal 0 0 {wall.normal}\n  outer loop\n"
                     + "".join(f"   vertex {a!r} {b!r} {float(wall.z)!r}\n" for a, b in tri)
                     + "  endloop\n endfacet\n" for tri in tris)
    write_text_atomic(path, f"solid {wall.name}\n{facets}endsolid {wall.name}\n")


def write_decks(out: Path, title: str, contact: Contact, *, boundary: str, skin: float, timestep: float,
                steps: int, every: int, rotation: bool, walls: tuple[Wall, ...], box, observe: str,
                start: tuple[str, ...] = ()) -> None:
    """in.lammps and in.liggghts (and one STL per wall) for data.lmp in ``out``: type 2 is held, type 1
    moves; ``start`` are commands both codes take as they are (``set atom 2 vx ...``)."""
    m = contact.material
    integrate = "nve/sphere" if rotation else "nve"
    common = (f"neighbor        {num(skin)} bin\nneigh_modify    delay 0\ntimestep        {num(timestep)}\n"
              "group           held type 2\ngroup           mobile type 1\n" + "".join(f"{c}\n" for c in start))
    tail = (f"thermo_style    custom step {' '.join('v_' + q for q in OBSERVABLES[observe])} ke\n"
            f"thermo_modify   format float %.17g norm no\nthermo          {num(every)}\nrun             {num(steps)}\n")
    lmp_walls, lig_walls = [], []
    for w in walls:
        move = ""
        if w.speed:
            lmp_walls.append(f"variable        {w.name}_dz equal -{num(w.speed)}*time")
            move = f" move NULL NULL v_{w.name}_dz units box"
        lmp_walls += [f"region          {w.name} plane 0 0 {num(w.z)} 0 0 {w.normal} side in{move}",
                      f"fix             {w.name} all wall/gran/region granular {contact.lammps} region {w.name} contacts"]
        write_plane_stl(out / f"{w.name}.stl", w, box)
        lig_walls.append(f"fix             {w.name} all mesh/surface/stress file {w.name}.stl type 1")
        if w.speed:
            lig_walls.append(f"fix             {w.name}_move all move/mesh mesh {w.name} linear 0. 0. -{num(w.speed)}")
    if walls:
        lig_walls.append(f"fix             walls all wall/gran model hertz tangential history mesh n_meshes "
                         f"{len(walls)} meshes {' '.join(w.name for w in walls)}")
    if observe == "plate":
        lmp_obs = ["compute         plate_fz all reduce sum f_plate[4]", "variable        plate_force equal -c_plate_fz"]
        lig_obs = ["variable        plate_force equal f_plate[3]"]
    else:
        lmp_obs = ["group           projectile id 2", "compute         spin all property/atom omegay",
                   "compute         omegay projectile reduce sum c_spin", "variable        omegay equal c_omegay",
                   "variable        vx equal vx[2]", "variable        vz equal vz[2]"]
        lig_obs = ["variable        vx equal vx[2]", "variable        vz equal vz[2]",
                   "variable        omegay equal omegay[2]"]
    lines = "\n".join
    write_text_atomic(out / "in.lammps", f"""# opalflow {__version__}: {title} on LAMMPS (units si)
units           si
atom_style      sphere
atom_modify     map array
boundary        {boundary}
newton          off
comm_modify     vel yes
read_data       data.lmp
# Hertz-Mindlin with the damping and tangential factor that equal LIGGGHTS's (opalflow/granular/decks.py)
pair_style      granular
pair_coeff      * * {contact.lammps}
{common}{lines(lmp_walls)}
fix             integrate mobile {integrate}
{lines(lmp_obs)}
{tail}""")
    pair = lambda v: " ".join([num(v)] * 4)  # noqa: E731 (the 2 x 2 type pairs of one material)
    write_text_atomic(out / "in.liggghts", f"""# opalflow {__version__}: {title} on LIGGGHTS 3.8 (units si)
atom_style      granular
atom_modify     map array
boundary        {boundary}
newton          off
communicate     single vel yes
units           si
hard_particles  yes
read_data       data.lmp
fix             m1 all property/global youngsModulus peratomtype {num(m.youngs_modulus_Pa)} {num(m.youngs_modulus_Pa)}
fix             m2 all property/global poissonsRatio peratomtype {num(m.poisson_ratio)} {num(m.poisson_ratio)}
fix             m3 all property/global coefficientRestitution peratomtypepair 2 {pair(m.restitution)}
fix             m4 all property/global coefficientFriction peratomtypepair 2 {pair(contact.friction)}
pair_style      gran model hertz tangential history
pair_coeff      * *
{common}{lines(lig_walls)}
fix             integrate mobile {integrate}
{lines(lig_obs)}
{tail}""")


def thermo_rows(log: Path) -> np.ndarray:
    """The numeric thermo rows (step, observables..., ke) of a LAMMPS or LIGGGHTS log."""
    text = log.read_text(errors="replace")
    body = text.split("Step", 1)[1].split("Loop time", 1)[0]
    rows = [r.split() for r in body.splitlines()[1:]]
    width = max((len(r) for r in rows), default=0)
    return np.array([[float(w) for w in r] for r in rows if len(r) == width and r[0].isdigit()])


def run_lammps(out: Path) -> float:
    t = time.perf_counter()
    with session(out, log="log.lammps") as lmp:
        lmp.file("in.lammps")
    return time.perf_counter() - t


def run_liggghts(out: Path) -> float:
    """LIGGGHTS unbuffered (piped, it drops the processor-local error lines), output kept in liggghts.out."""
    exe = liggghts_executable("engine", "liggghts")
    t = time.perf_counter()
    cmd = ([shutil.which("stdbuf"), "-o0", "-e0"] if shutil.which("stdbuf") else []) + \
        [exe, "-in", "in.liggghts", "-log", "log.liggghts", "-echo", "none"]
    with open(out / "liggghts.out", "wb") as f:
        code = subprocess.run(cmd, cwd=out, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT).returncode
    if code or not (out / "log.liggghts").exists() or "Loop time" not in (out / "log.liggghts").read_text(errors="replace"):
        raise EngineError(f"LIGGGHTS failed in {out} (exit {code})\n--- output tail ---\n{log_tail(out / 'liggghts.out')}")
    return time.perf_counter() - t


def run_engine(engine: str, out: Path) -> tuple[np.ndarray, float]:
    """Run the scene in ``out`` on ``engine``: its thermo rows and wall time."""
    wall = run_lammps(out) if engine == "lammps" else run_liggghts(out)
    return thermo_rows(out / f"log.{engine}"), wall
