"""An unbonded packing compressed by a plate, run by LAMMPS and/or LIGGGHTS 3.8 (kind "granular").

``engine = "both"`` runs the same data file on both codes and compares the force on the plate; the
mapping of the contact law between them, and where they part, is in opalflow/granular/decks.py.
Frictionless contacts (``material.friction = 0``) make the plate force a sum of normal contact forces,
and the two engines agree to round-off; with friction the paths part at the first contact that slides
with damping, spins, or closes again on a partner it touched before (``granular_impacts`` measures each).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from opalflow.granular.decks import Contact, Wall, liggghts_executable, run_engine, write_decks, write_spheres, x_gamma_t
from opalflow.granular.result import CrossCheck, GranularResult, PlateScene
from opalflow.granular.spec import GranularWorkflow
from opalflow.lammps.engine import accelerated
from opalflow.packing import dense_random_packing
from opalflow.runs.record import RunRecord, finish
from opalflow.store import new_figure, save_figure

#: a plate-force row counts in the comparison when its force is above this fraction of the largest
FORCE_FLOOR = 1e-6


def build_scene(spec: GranularWorkflow, out: Path) -> PlateScene:
    """data.lmp, plate.stl, in.lammps and in.liggghts in ``out``; returns the scene's numbers."""
    k, m, p = spec.packing, spec.material, spec.plate
    box = np.full(3, k.box_diameters)
    pack = dense_random_packing(box, 1.0, k.solid_fraction, std=k.diameter_std, size_bins=4, seed=k.seed, tile_nm=0)
    x, d = pack.positions * k.diameter_m, pack.diameters * k.diameter_m
    floor = x[:, 2] < 0.75 * k.diameter_m
    top = float(np.max(x[:, 2] + d / 2))
    L = box * k.diameter_m
    bounds = ((0.0, float(L[0])), (0.0, float(L[1])), (-k.diameter_m, top + 2 * k.diameter_m))
    write_spheres(out / "data.lmp", f"{spec.name}: unbonded packing", np.where(floor, 2, 1), d, x,
                  m.density_kg_m3, bounds)
    write_decks(out, spec.name, Contact(m, m.friction), boundary="p p f", skin=0.2 * k.diameter_m,
                timestep=p.timestep_s, steps=p.steps, every=p.output_every, rotation=spec.rotation,
                walls=(Wall("plate", top, -1, p.speed_m_s),), box=bounds, observe="plate",
                start=("fix             hold held freeze",))
    return PlateScene(n_particles=int(len(x)), n_floor=int(floor.sum()), area_m2=float(L[0] * L[1]),
                      height_m=top - float(np.max(x[floor, 2] + d[floor] / 2)),
                      plate_travel_m=p.speed_m_s * p.steps * p.timestep_s, x_gamma_t=x_gamma_t(m.poisson_ratio))


def compare(a: np.ndarray, b: np.ndarray, tolerance: float = 1e-6) -> CrossCheck:
    """Plate forces of two engines row by row: the largest relative difference and where it first passes
    ``tolerance`` (relative to the larger force of the row; rows below FORCE_FLOOR of the peak skipped)."""
    n = min(len(a), len(b))
    fa, fb = a[:n, 1], b[:n, 1]
    scale = np.maximum(np.abs(fa), np.abs(fb))
    on = scale > FORCE_FLOOR * max(float(scale.max(initial=0.0)), 1e-300)
    rel = np.zeros(n)
    rel[on] = np.abs(fa[on] - fb[on]) / scale[on]
    over = np.flatnonzero(rel > tolerance)
    return CrossCheck(max_relative_difference=float(rel.max(initial=0.0)), tolerance=tolerance,
                      rows_compared=int(on.sum()), agree=not len(over),
                      first_step_over_tolerance=int(a[over[0], 0]) if len(over) else None)


def run_granular(spec: GranularWorkflow, out: Path, say=print, suffix: str | None = None) -> GranularResult:
    """The scene on LAMMPS (``suffix``: its accelerated styles; the packing never), LIGGGHTS or both."""
    t0 = time.perf_counter()
    engines = ["lammps", "liggghts"] if spec.engine == "both" else [spec.engine]
    if "liggghts" in engines:
        liggghts_executable("engine", spec.engine)
    out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(spec, out)
    RunRecord.new(spec, deck=dataclasses.asdict(scene), folder=out).begin(out)
    curves, walls = {}, {}
    for engine in engines:
        say(f"{spec.name}: {scene.n_particles} spheres, {spec.plate.steps} steps on {engine}")
        with accelerated(suffix if engine == "lammps" else None):
            curves[engine], walls[engine] = run_engine(engine, out)
    strain = {e: c[:, 0] * spec.plate.timestep_s * spec.plate.speed_m_s / scene.height_m for e, c in curves.items()}
    cc = compare(curves["lammps"], curves["liggghts"]) if len(engines) == 2 else None
    force = {e: float(c[-1, 1]) for e, c in curves.items()}
    result = GranularResult(
        workflow=spec.name, engines=engines, **dataclasses.asdict(scene), plate_force_N=force,
        plate_stress_Pa={e: f / scene.area_m2 for e, f in force.items()},
        final_strain=float(next(iter(strain.values()))[-1]), engine_s=walls, cross_check=cc,
        headline=", ".join(f"{e}: plate force {f:.6g} N" for e, f in force.items())
        + (f"; largest relative difference {cc.max_relative_difference:.2e}" if cc else ""),
        wall_s=time.perf_counter() - t0)

    def files(stage):
        fig, ax = new_figure(figsize=(5, 3.6))
        for e, c in curves.items():
            ax.plot(100 * strain[e], c[:, 1] / scene.area_m2, label=e, lw=1.2 if e == "lammps" else 0.8,
                    ls="-" if e == "lammps" else "--")
        ax.set_xlabel("plate strain (%)")
        ax.set_ylabel("plate stress (Pa)")
        ax.legend()
        save_figure(fig, stage("plate_force.png"))

    return finish(out, result, _report(spec, result), files=files)


def _report(spec: GranularWorkflow, s: GranularResult) -> str:
    m = spec.material
    lines = [f"# {spec.name}: unbonded packing compressed by a plate", "",
             f"{s.n_particles} spheres (d = {spec.packing.diameter_m:g} m +- {100 * spec.packing.diameter_std:g} %, "
             f"{s.n_floor} held at the bottom), E = {m.youngs_modulus_Pa:g} Pa, nu = {m.poisson_ratio:g}, "
             f"restitution {m.restitution:g}, friction {m.friction:g}; plate {spec.plate.speed_m_s:g} m/s for "
             f"{spec.plate.steps} steps of {spec.plate.timestep_s:g} s (strain {s.final_strain:.4f}). LAMMPS "
             f"tangential damping factor x_gamma,t = {s.x_gamma_t:.6f} (the mapping: opalflow/granular/decks.py).", "",
             "| engine | plate force at the end (N) | plate stress (Pa) | engine time (s) |", "|---|---|---|---|"]
    lines += [f"| {e} | {s.plate_force_N[e]:.10g} | {s.plate_stress_Pa[e]:.6g} | {s.engine_s[e]:.2f} |"
              for e in s.engines]
    cc = s.cross_check
    if cc:
        lines += ["", f"Cross-check over {cc.rows_compared} output rows: largest relative difference of the plate "
                  f"force {cc.max_relative_difference:.3e} (tolerance {cc.tolerance:g}): "
                  + ("they agree." if cc.agree else f"they part from step {cc.first_step_over_tolerance} "
                     "(tangential forces: the first contact that slides with damping, spins or closes again "
                     "on an earlier partner; `granular_impacts` measures each; frictionless contacts agree "
                     "to round-off).")]
    lines += ["", "![plate force](plate_force.png)", "",
              "Files: data.lmp (atom_style sphere, SI), plate.stl, in.lammps, in.liggghts (each runs alone: "
              "`lmp -in in.lammps`, `liggghts -in in.liggghts`), their logs."]
    return "\n".join(lines) + "\n"
