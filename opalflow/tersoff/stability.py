"""Stability check of a Tersoff set by molecular dynamics (seed 003, section 3).

"A cube of 4 x 4 x 4 unit cells is modeled for 0.01 nanoseconds with four different
boundary conditions: fully periodic, periodic in x and y but not z, periodic only in x,
and non-periodic."  Here: 512 atoms at the zero-pressure lattice constant, velocities
drawn for twice the set temperature (equipartition brings it to the set temperature),
NVE (velocity Verlet, 1 fs default) for 10 ps.  Non-periodic directions are cut open
(free surfaces) and the box is padded by one lattice constant with fixed walls (``f``):
an atom that flies beyond the padding is lost.

A boundary passes when
- the NVE total energy stays within ``max_drift_eV`` per atom of its start (a set whose
  forces are not smooth, or whose time step is too long, heats up),
- the crystal is kept: at least ``min_fourfold`` of the interior atoms (more than one
  lattice constant from every free surface) have exactly 4 neighbours within the
  first/second-shell midpoint, and their RMS displacement from the start is below
  ``max_rms_A``,
- no atom is lost.
"""
from __future__ import annotations

import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.lammps.engine import session
from opalflow.progress import Progress
from opalflow.tersoff.parameters import TersoffParameters, write_tersoff
from opalflow.tersoff.properties import POTENTIAL_FILE, relax_lattice, setup_commands

BOUNDARIES = ("ppp", "ppf", "pff", "fff")


@dataclass
class Criteria:
    max_drift_eV: float = 1e-3
    min_fourfold: float = 0.95
    max_rms_A: float = 0.5


@dataclass
class BoundaryResult:
    boundary: str
    temperature_K: float
    passed: bool
    reason: str
    drift_eV_per_atom: float
    fourfold_interior: float
    rms_interior_A: float
    atoms_lost: int
    mean_temperature_K: float
    seconds: float


def run_boundary(params: TersoffParameters, folder: str | Path, boundary: str, *,
                 temperature_K: float = 300.0, cells: int = 4, time_ps: float = 10.0,
                 timestep_fs: float = 1.0, seed: int = 12345, criteria: Criteria | None = None,
                 progress: bool = False) -> BoundaryResult:
    """MD of the 4x4x4 crystal with ``boundary`` (e.g. 'ppf'); pass/fail with the figures."""
    if len(boundary) != 3 or set(boundary) - {"p", "f"}:
        raise ValueError(f"boundary {boundary!r}: three letters of p (periodic) and f (free)")
    criteria = criteria or Criteria()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_tersoff(folder / POTENTIAL_FILE, params, "written by opalflow for this stability run")
    steps = int(round(time_ps * 1000.0 / timestep_fs))
    t0 = time.perf_counter()
    with session(folder, log=f"log.stability_{boundary}_{temperature_K:g}K.lammps") as lmp:
        lmp.commands_string(setup_commands(5.431, 1, params.element))
        a = relax_lattice(lmp, 1)
        lmp.command("clear")
        lmp.commands_string(setup_commands(a, cells, params.element, triclinic=False))
        length = a * cells
        free = [ax for ax, code in zip("xyz", boundary) if code == "f"]
        if free:
            lmp.command(f"change_box all boundary {' '.join(boundary)}")
            lmp.command("change_box all " + " ".join(f"{ax} final {-a:.12g} {length + a:.12g}" for ax in free)
                        + " units box")
        # neighbours: within the first/second-shell midpoint, or the potential's range if shorter
        shell = min(a * (math.sqrt(3.0) / 4.0 + 1.0 / math.sqrt(2.0)) / 2.0, params.cutoff())
        lmp.commands_string(f"""
timestep {timestep_fs / 1000.0:.12g}
compute disp all displace/atom
minimize 0 1e-8 1000 10000
velocity all create {2.0 * temperature_K:.12g} {seed} mom yes rot yes dist gaussian
fix nve all nve
compute coord all coord/atom cutoff {shell:.12g}
thermo_style custom step temp pe etotal atoms
thermo_modify lost ignore norm no
run 0 post no
""")
        n0 = lmp.get_natoms()
        x0 = np.array(lmp.gather_atoms("x", 1, 3), dtype=float).reshape(-1, 3)
        interior = np.ones(len(x0), dtype=bool)
        for ax in free:
            i = "xyz".index(ax)
            interior &= (x0[:, i] > a - 1e-6) & (x0[:, i] < length - a - 1e-6)
        drift, temps = _integrate(lmp, steps, f"stability {boundary} {temperature_K:g} K: ", progress)
        lost = n0 - lmp.get_natoms()
        if lost == 0:
            coord = np.array(lmp.gather("c_coord", 1, 1), dtype=float)
            disp = np.array(lmp.gather("c_disp", 1, 4), dtype=float).reshape(-1, 4)[:, 3]
            fourfold = float(np.mean(coord[interior] == 4))
            rms = float(np.sqrt(np.mean(disp[interior] ** 2)))
        else:       # atom order is gone with the lost atoms; the run has failed anyway
            fourfold, rms = math.nan, math.nan
    reasons = _failures(criteria, lost, n0, drift, fourfold, rms)
    return BoundaryResult(boundary=boundary, temperature_K=temperature_K, passed=not reasons,
                          reason="; ".join(reasons) or "ok", drift_eV_per_atom=drift,
                          fourfold_interior=fourfold, rms_interior_A=rms, atoms_lost=int(lost),
                          mean_temperature_K=float(np.mean(temps)) if temps else math.nan,
                          seconds=time.perf_counter() - t0)


def _integrate(lmp, steps: int, label: str, progress: bool) -> tuple[float, list[float]]:
    """Run ``steps`` NVE steps in 20 chunks: the largest energy drift per atom (inf once the energy is not
    finite: the run stops there) and the temperature after each chunk."""
    e0 = lmp.get_thermo("etotal")
    drift, temps = 0.0, []
    chunk = max(1, steps // 20)
    meter = Progress(steps, 0, label)
    step = 0
    while step < steps:
        n = min(chunk, steps - step)
        lmp.command(f"run {n} pre {'yes' if step == 0 else 'no'} post no")
        step += n
        natoms = max(lmp.get_natoms(), 1)
        etot = lmp.get_thermo("etotal")
        drift = max(drift, abs(etot - e0) / natoms) if math.isfinite(etot) else math.inf
        temps.append(lmp.get_thermo("temp"))
        if progress:
            meter.update(step)
        if not math.isfinite(etot):
            break
    return drift, temps


def _failures(criteria: Criteria, lost: int, n0: int, drift: float, fourfold: float, rms: float) -> list[str]:
    """Why a boundary's MD fails the criteria (none: it passes); with atoms lost nothing else can be judged."""
    if lost:
        return [f"{lost} of {n0} atoms lost (flew out of the box padded by one lattice constant)"]
    reasons = []
    if not drift <= criteria.max_drift_eV:
        reasons.append(f"energy drift {drift:.3g} eV/atom > {criteria.max_drift_eV:g}")
    if not fourfold >= criteria.min_fourfold:
        reasons.append(f"4-coordinated interior fraction {fourfold:.3f} < {criteria.min_fourfold:g}")
    if not rms <= criteria.max_rms_A:
        reasons.append(f"interior RMS displacement {rms:.3g} A > {criteria.max_rms_A:g} A")
    return reasons


def _run_job(job) -> BoundaryResult:
    params, folder, boundary, temperature, kwargs = job
    return run_boundary(params, folder, boundary, temperature_K=temperature, **kwargs)


def check(params: TersoffParameters, folder: str | Path, *, boundaries=BOUNDARIES, temperatures_K=(300.0,),
          workers: int = 0, say=None, **kwargs) -> list[BoundaryResult]:
    """Every boundary at every temperature, each in its own subfolder, ``workers`` processes at once.

    ``kwargs`` go to :func:`run_boundary` (cells, time_ps, timestep_fs, seed, criteria).
    """
    folder = Path(folder)
    jobs = [(params, folder / f"{b}_{t:g}K", b, t, kwargs) for t in temperatures_K for b in boundaries]
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    results = []
    pool = None
    if workers > 1:   # spawn, not fork: the caller may hold JAX's threads (python -m opalflow is safe;
        # scripts that call this need the usual ``if __name__ == "__main__":`` guard)
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        for r in (pool.map if pool else map)(_run_job, jobs):
            results.append(r)
            if say:
                say(f"stability {r.boundary} at {r.temperature_K:g} K: {'pass' if r.passed else 'FAIL'} "
                    f"({r.reason}; drift {r.drift_eV_per_atom:.2g} eV/atom, 4-fold {r.fourfold_interior:.3f}, "
                    f"RMS {r.rms_interior_A:.3f} A, {r.seconds:.1f} s)")
    finally:
        if pool:
            pool.shutdown()
    return results
