"""An unbonded packing compressed by a plate, run by LAMMPS and/or LIGGGHTS 3.8 (kind "granular").

LIGGGHTS (Debian package ``liggghts``) is granular only: it has no bonded-particle model, so the bonded
scenes run on LAMMPS; a contact-only scene runs on either, and ``engine = "both"`` runs it on both and
compares the force on the plate.  The same data file (``atom_style sphere`` / ``granular``: id type
diameter density x y z, SI units) feeds both decks.

Mapping (one material, the plate made of it too, as LAMMPS's ``fix wall/gran`` assumes):

========================  ==========================================  ==========================================
quantity                  LIGGGHTS 3.8 (pair gran hertz, history)     LAMMPS (pair granular)
========================  ==========================================  ==========================================
normal force              4/3 Y* sqrt(R* d) d, Y* = E / (2 (1-nu^2))  hertz/material E e nu: the same E*
normal damping            -2 sqrt(5/6) beta sqrt(S_n m*),             damping coeff_restitution: the same
                          S_n = 2 Y* sqrt(R* d), beta(e)              (two-particle collisions agree to 1e-9)
tangential stiffness      k_t = 8 G* sqrt(R* d),                      mindlin NULL: k_t = 8 G* a, the same G*
                          G* = E / (2 (2-nu)(1+nu))
tangential damping        gamma_n sqrt(S_t / S_n)                     x_gamma,t gamma_n with
                                                                      x_gamma,t = sqrt(4 G* / Y*)
                                                                      = sqrt(4 (1-nu) / (2-nu))
Coulomb limit             on the elastic (history) force; a sliding   on the total (elastic + damping) force
                          contact has no tangential damping
plate                     fix mesh/surface/stress + move/mesh,        fix wall/gran/region, plane moving with
                          wall/gran with the same model               v_plate_dz, the same model
========================  ==========================================  ==========================================

Where they part: the tangential force.  Measured on two spheres in an oblique collision that sticks
(friction 1000), the tangential velocities differ by 1e-3 relative after 200 steps even with tangential
damping off in both, while the normal ones agree to 9 digits: the two codes update the tangential
history differently (its rotation into the contact plane and the contact-point radius of the relative
rotational velocity).  Frictionless contacts (``material.friction = 0``) make the plate force a sum of
normal contact forces only, and the two engines agree to round-off (tests/test_granular.py); with
friction the packings' paths part at the first contacts that carry a tangential force.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from opalflow.granular.spec import GranularWorkflow
from opalflow.lammps.engine import EngineError, log_tail, session
from opalflow.lammps.syntax import num
from opalflow.packing import dense_random_packing
from opalflow.spec import SpecError
from opalflow.store import json_text, new_figure, save_figure, staged_files, write_text_atomic
from opalflow.version import __version__

#: a plate-force row counts in the comparison when its force is above this fraction of the largest
FORCE_FLOOR = 1e-6


def liggghts_executable() -> str | None:
    return shutil.which("liggghts")


def x_gamma_t(nu: float) -> float:
    """LAMMPS's tangential damping factor that equals LIGGGHTS's sqrt(S_t / S_n) for one material."""
    return math.sqrt(4 * (1 - nu) / (2 - nu))


def build_scene(spec: GranularWorkflow, out: Path) -> dict:
    """data.lmp, plate.stl, in.lammps and in.liggghts in ``out``; returns the scene's numbers."""
    k, m, p = spec.packing, spec.material, spec.plate
    box = np.full(3, k.box_diameters)
    pack = dense_random_packing(box, 1.0, k.solid_fraction, std=k.diameter_std, size_bins=4, seed=k.seed, tile_nm=0)
    x, d = pack.positions * k.diameter_m, pack.diameters * k.diameter_m
    floor = x[:, 2] < 0.75 * k.diameter_m
    types = np.where(floor, 2, 1)
    top = float(np.max(x[:, 2] + d / 2))
    L = box * k.diameter_m
    travel = p.speed_m_s * p.steps * p.timestep_s
    zlo, zhi = -k.diameter_m, top + 2 * k.diameter_m
    rows = "\n".join(f"{i + 1} {types[i]} {float(d[i])!r} {m.density_kg_m3!r} " + " ".join(repr(float(c)) for c in x[i])
                     for i in range(len(x)))
    write_text_atomic(out / "data.lmp", f"opalflow {__version__} {spec.name}: unbonded packing (SI units)\n\n"
                      f"{len(x)} atoms\n2 atom types\n\n0 {float(L[0])!r} xlo xhi\n0 {float(L[1])!r} ylo yhi\n"
                      f"{zlo!r} {zhi!r} zlo zhi\n\nAtoms # sphere\n\n{rows}\n")
    facets = "".join(" facet normal 0 0 1\n  outer loop\n" + "".join(f"   vertex {a!r} {b!r} {top!r}\n" for a, b in tri)
                     + "  endloop\n endfacet\n" for tri in (((0.0, 0.0), (float(L[0]), 0.0), (float(L[0]), float(L[1]))),
                                                             ((0.0, 0.0), (float(L[0]), float(L[1])), (0.0, float(L[1])))))
    write_text_atomic(out / "plate.stl", f"solid plate\n{facets}endsolid plate\n")
    v = dict(E=num(m.youngs_modulus_Pa), nu=num(m.poisson_ratio), e=num(m.restitution), mu=num(m.friction),
             dt=num(p.timestep_s), steps=num(p.steps), every=num(p.output_every), speed=num(p.speed_m_s),
             skin=num(0.2 * k.diameter_m), top=num(top), xg=num(x_gamma_t(m.poisson_ratio)))
    contact = f"hertz/material {v['E']} {v['e']} {v['nu']} tangential mindlin NULL {v['xg']} {v['mu']} damping coeff_restitution"
    write_text_atomic(out / "in.lammps", f"""# opalflow {__version__}: {spec.name} on LAMMPS (units si)
units           si
atom_style      sphere
atom_modify     map array
boundary        p p f
newton          off
comm_modify     vel yes
read_data       data.lmp
# Hertz-Mindlin with the damping and tangential factor that equal LIGGGHTS's (opalflow/granular/run.py)
pair_style      granular
pair_coeff      * * {contact}
neighbor        {v['skin']} bin
neigh_modify    delay 0
timestep        {v['dt']}
group           floor type 2
group           mobile type 1
variable        plate_dz equal -{v['speed']}*time
region          plate plane 0 0 {v['top']} 0 0 -1 side in move NULL NULL v_plate_dz units box
fix             plate all wall/gran/region granular {contact} region plate contacts
fix             integrate mobile nve/sphere
compute         plate_fz all reduce sum f_plate[4]
variable        plate_force equal -c_plate_fz
thermo_style    custom step v_plate_force ke
thermo_modify   format float %.17g norm no
thermo          {v['every']}
run             {v['steps']}
""")
    write_text_atomic(out / "in.liggghts", f"""# opalflow {__version__}: {spec.name} on LIGGGHTS 3.8 (units si)
atom_style      granular
atom_modify     map array
boundary        p p f
newton          off
communicate     single vel yes
units           si
hard_particles  yes
read_data       data.lmp
neighbor        {v['skin']} bin
neigh_modify    delay 0
fix             m1 all property/global youngsModulus peratomtype {v['E']} {v['E']}
fix             m2 all property/global poissonsRatio peratomtype {v['nu']} {v['nu']}
fix             m3 all property/global coefficientRestitution peratomtypepair 2 {v['e']} {v['e']} {v['e']} {v['e']}
fix             m4 all property/global coefficientFriction peratomtypepair 2 {v['mu']} {v['mu']} {v['mu']} {v['mu']}
pair_style      gran model hertz tangential history
pair_coeff      * *
timestep        {v['dt']}
group           floor type 2
group           mobile type 1
fix             plate all mesh/surface/stress file plate.stl type 1
fix             move all move/mesh mesh plate linear 0. 0. -{v['speed']}
fix             wall all wall/gran model hertz tangential history mesh n_meshes 1 meshes plate
fix             integrate mobile nve/sphere
variable        plate_force equal f_plate[3]
thermo_style    custom step v_plate_force ke
thermo_modify   format float %.17g norm no
thermo          {v['every']}
run             {v['steps']}
""")
    return {"n_particles": int(len(x)), "n_floor": int(floor.sum()), "area_m2": float(L[0] * L[1]),
            "height_m": top - float(np.max(x[floor, 2] + d[floor] / 2)), "plate_travel_m": travel,
            "x_gamma_t": x_gamma_t(m.poisson_ratio)}


def thermo_rows(log: Path) -> np.ndarray:
    """The (step, plate force, kinetic energy) rows of a LAMMPS or LIGGGHTS log."""
    text = log.read_text(errors="replace")
    body = text.split("Step", 1)[1].split("Loop time", 1)[0]
    rows = [r.split() for r in body.splitlines()[1:]]
    return np.array([[float(w) for w in r[:3]] for r in rows if len(r) >= 3 and r[0].isdigit()])


def run_lammps(out: Path) -> float:
    t = time.perf_counter()
    with session(out, log="log.lammps") as lmp:
        lmp.file("in.lammps")
    return time.perf_counter() - t


def run_liggghts(out: Path) -> float:
    """LIGGGHTS unbuffered (piped, it drops the processor-local error lines), output kept in liggghts.out."""
    exe = liggghts_executable()
    if exe is None:
        raise SpecError("engine", "liggghts", "no 'liggghts' executable (Debian: apt-get install liggghts)")
    t = time.perf_counter()
    cmd = ([shutil.which("stdbuf"), "-o0", "-e0"] if shutil.which("stdbuf") else []) + \
        [exe, "-in", "in.liggghts", "-log", "log.liggghts", "-echo", "none"]
    with open(out / "liggghts.out", "wb") as f:
        code = subprocess.run(cmd, cwd=out, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT).returncode
    if code or not (out / "log.liggghts").exists() or "Loop time" not in (out / "log.liggghts").read_text(errors="replace"):
        raise EngineError(f"LIGGGHTS failed in {out} (exit {code})\n--- output tail ---\n{log_tail(out / 'liggghts.out')}")
    return time.perf_counter() - t


def compare(a: np.ndarray, b: np.ndarray, tolerance: float = 1e-6) -> dict:
    """Plate forces of two engines row by row: the largest relative difference and where it first passes
    ``tolerance`` (relative to the larger force of the row; rows below FORCE_FLOOR of the peak skipped)."""
    n = min(len(a), len(b))
    fa, fb = a[:n, 1], b[:n, 1]
    scale = np.maximum(np.abs(fa), np.abs(fb))
    on = scale > FORCE_FLOOR * max(float(scale.max(initial=0.0)), 1e-300)
    rel = np.zeros(n)
    rel[on] = np.abs(fa[on] - fb[on]) / scale[on]
    over = np.flatnonzero(rel > tolerance)
    return {"max_relative_difference": float(rel.max(initial=0.0)), "tolerance": tolerance,
            "rows_compared": int(on.sum()), "agree": not len(over),
            "first_step_over_tolerance": int(a[over[0], 0]) if len(over) else None}


def run_granular(spec: GranularWorkflow, out: Path, say=print) -> dict:
    t0 = time.perf_counter()
    engines = ["lammps", "liggghts"] if spec.engine == "both" else [spec.engine]
    if "liggghts" in engines and liggghts_executable() is None:
        raise SpecError("engine", spec.engine, "needs the 'liggghts' executable (Debian package liggghts), "
                        "which is not on PATH")
    out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(spec, out)
    write_text_atomic(out / "run.json", json_text({"workflow": spec.name, "spec": spec.to_dict(), **scene}))
    curves, walls = {}, {}
    for engine in engines:
        say(f"{spec.name}: {scene['n_particles']} spheres, {spec.plate.steps} steps on {engine}")
        walls[engine] = run_lammps(out) if engine == "lammps" else run_liggghts(out)
        curves[engine] = thermo_rows(out / f"log.{engine}")
    strain = {e: c[:, 0] * spec.plate.timestep_s * spec.plate.speed_m_s / scene["height_m"] for e, c in curves.items()}
    summary = {"workflow": spec.name, "engines": engines, **scene,
               "plate_force_N": {e: float(c[-1, 1]) for e, c in curves.items()},
               "plate_stress_Pa": {e: float(c[-1, 1]) / scene["area_m2"] for e, c in curves.items()},
               "final_strain": float(next(iter(strain.values()))[-1]), "engine_s": walls}
    if len(engines) == 2:
        summary["cross_check"] = compare(curves["lammps"], curves["liggghts"])
    cc = summary.get("cross_check")
    summary["headline"] = ", ".join(f"{e}: plate force {f:.6g} N" for e, f in summary["plate_force_N"].items()) + (
        f"; largest relative difference {cc['max_relative_difference']:.2e}" if cc else "")
    summary["wall_s"] = time.perf_counter() - t0
    with staged_files(out) as stage:
        fig, ax = new_figure(figsize=(5, 3.6))
        for e, c in curves.items():
            ax.plot(100 * strain[e], c[:, 1] / scene["area_m2"], label=e, lw=1.2 if e == "lammps" else 0.8,
                    ls="-" if e == "lammps" else "--")
        ax.set_xlabel("plate strain (%)")
        ax.set_ylabel("plate stress (Pa)")
        ax.legend()
        save_figure(fig, stage("plate_force.png"))
        stage("report.md").write_text(_report(spec, summary))
        stage("summary.json").write_text(json_text(summary))
    return summary


def _report(spec: GranularWorkflow, s: dict) -> str:
    m = spec.material
    lines = [f"# {spec.name}: unbonded packing compressed by a plate", "",
             f"{s['n_particles']} spheres (d = {spec.packing.diameter_m:g} m +- {100 * spec.packing.diameter_std:g} %, "
             f"{s['n_floor']} held at the bottom), E = {m.youngs_modulus_Pa:g} Pa, nu = {m.poisson_ratio:g}, "
             f"restitution {m.restitution:g}, friction {m.friction:g}; plate {spec.plate.speed_m_s:g} m/s for "
             f"{spec.plate.steps} steps of {spec.plate.timestep_s:g} s (strain {s['final_strain']:.4f}). LAMMPS "
             f"tangential damping factor x_gamma,t = {s['x_gamma_t']:.6f} (the mapping: opalflow/granular/run.py).", "",
             "| engine | plate force at the end (N) | plate stress (Pa) | engine time (s) |", "|---|---|---|---|"]
    lines += [f"| {e} | {s['plate_force_N'][e]:.10g} | {s['plate_stress_Pa'][e]:.6g} | {s['engine_s'][e]:.2f} |"
              for e in s["engines"]]
    cc = s.get("cross_check")
    if cc:
        lines += ["", f"Cross-check over {cc['rows_compared']} output rows: largest relative difference of the plate "
                  f"force {cc['max_relative_difference']:.3e} (tolerance {cc['tolerance']:g}): "
                  + ("they agree." if cc["agree"] else f"they part from step {cc['first_step_over_tolerance']} "
                     "(tangential forces: the codes differ in the tangential history and the Coulomb limit; "
                     "frictionless contacts agree to round-off).")]
    lines += ["", "![plate force](plate_force.png)", "",
              "Files: data.lmp (atom_style sphere, SI), plate.stl, in.lammps, in.liggghts (each runs alone: "
              "`lmp -in in.lammps`, `liggghts -in in.liggghts`), their logs."]
    return "\n".join(lines) + "\n"
