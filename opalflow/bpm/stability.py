"""Numerical stability of a bonded-particle scene: a short run of its real deck, with criteria that can fail.

The scene's deck (``in.lmp`` without its run block) runs ``steps`` time steps at the chosen time step
(the estimate times ``timestep_factor``), or as many as the plate needs to compress the sample to
``strain`` (a check of the dense, contact-dominated state: the whole path runs at that time step, so
the energy account below still starts from rest), and is judged by

- **finite**: every reported value is finite;
- **no lost particles**: LAMMPS stops on a lost atom (``thermo_modify lost error``);
- **energy account**: the kinetic energy (translation and rotation) never exceeds the work done on the
  particles by the plate and the drag, ``KE(t) <= W_plate(t) + W_drag(t)`` within ``tolerance`` of the
  largest work.  Bond, contact and dissipated energies are non-negative, so energy conservation
  implies this; an unstable integrator creates energy and breaks it within a few hundred steps.
  (LAMMPS reports no potential energy for ``bpm/rotational`` bonds or granular contacts, so the account
  is an inequality, not a balance.)
- **kinetic energy bounded**: the kinetic energy at the end is at most ``ke_growth`` times its largest
  value over the first half (no exponential growth), or below 1 % of the work.

:func:`bisect_timestep` finds the largest passing time step factor between a stable and an unstable one.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from opalflow.bpm.deck import CompressionDeck, compression_deck
from opalflow.bpm.scene import scene_of
from opalflow.bpm.spec import BpmWorkflow
from opalflow.lammps.datafile import write_data
from opalflow.lammps.engine import EngineError, script_commands, session
from opalflow.lammps.syntax import num, render
from opalflow.runs.result import optional, table_of
from opalflow.store import write_json_atomic, write_text_atomic


@dataclass
class Criterion:
    """One criterion of a short run: whether it passed and the figures it was judged by."""

    passed: bool
    figures: str


@dataclass
class StabilityResult:
    """One short run: its time step, the criteria (name -> :class:`Criterion`) and the samples."""

    timestep_s: float
    timestep_factor: float
    steps: int
    passed: bool
    criteria: dict[str, Criterion]
    seconds: float
    samples: dict[str, list[float]] = field(default_factory=dict)

    def failed(self) -> str:
        return ", ".join(k for k, c in self.criteria.items() if not c.passed)


def check_script(deck, factor: float, every: int) -> str:
    """The deck's in.lmp up to its run block, at ``factor`` x its time step, with the energy account."""
    text = deck.in_lmp.split("# --- run:")[0]
    dt = deck.dt_ns * factor
    text = text.replace(f"timestep        {num(deck.dt_ns)}\n", f"timestep        {num(dt)}\n", 1)
    drag = "0.0"
    if "damping" in deck.blocks:
        drag = "v_damp_fx*vx+v_damp_fy*vy+v_damp_fz*vz"
    return text + render("energy_account", plate_speed=num(deck.plate_speed_nm_ns), drag_power=drag,
                         every=num(every))


def steps_to_strain(deck: CompressionDeck, strain: float, factor: float = 1.0) -> int:
    """Time steps at ``factor`` x the deck's time step for the plate to compress the sample by ``strain``."""
    return int(math.ceil(strain * deck.height_nm / deck.plate_speed_nm_ns / (deck.dt_ns * factor)))


def run_check(deck: CompressionDeck, folder: Path, *, factor: float = 1.0, steps: int = 3000,
              strain: float | None = None, tolerance: float = 0.02, ke_growth: float = 100.0) -> StabilityResult:
    """Run ``steps`` steps (or up to ``strain``) of a scene's deck at ``factor`` x its time step in ``folder``."""
    if strain:
        steps = steps_to_strain(deck, strain, factor)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "snapshots").mkdir(exist_ok=True)
    write_data(folder / "data.lmp", deck.structure)
    every = max(1, steps // 300)
    script = check_script(deck, factor, every)
    (folder / "check.lmp").write_text(script)
    names = ("Step", "KinEng", "c_erot", "f_energy_account[1]", "f_energy_account[2]", "c_plate_fz",
             "v_intact_bonds")
    values, error = [], ""
    t0 = time.perf_counter()
    try:
        with session(folder, log="check.log") as lmp:
            for cmd in script_commands(script):
                lmp.command(cmd)
            lmp.command(f"run {every} post no")
            done = every
            while done < steps:
                lmp.command(f"run {every} pre no post no")
                done += every
                values.append([lmp.last_thermo()[k] for k in names])
    except EngineError as exc:
        error = str(exc).splitlines()[0]
    seconds = time.perf_counter() - t0
    dt_s = deck.dt_ns * factor * 1e-9
    v = np.array(values, float).reshape(-1, len(names))
    step, ke, erot, p_plate, p_drag = v[:, 0], v[:, 1], v[:, 2], v[:, 3], v[:, 4]
    # running means of the power since the fix was defined (step 0) -> work to each step
    w_in = (p_plate + p_drag) * step * deck.dt_ns * factor
    ke_tot = ke + erot - deck.initial_ke_zJ          # what the start gave is no energy the run created
    criteria = {}
    finite = bool(len(v)) and bool(np.all(np.isfinite(v)))
    criteria["finite"] = Criterion(finite, "all values finite" if finite else "non-finite values" if len(v) else
                                   "no values (LAMMPS stopped before the first output)")
    lost = "Lost atoms" in error or "lost" in error.lower()
    criteria["no lost particles"] = Criterion(not lost, error if lost else "none lost")
    if error and not lost:
        criteria["LAMMPS ran"] = Criterion(False, error)
    if len(v) and finite:
        scale = max(float(np.max(np.abs(w_in))), 1e-30)
        excess = float(np.max(ke_tot - w_in))
        criteria["energy account"] = Criterion(excess <= tolerance * scale,
                                               f"max(KE - W_in) = {excess:.3g} zJ ({100 * excess / scale:+.2f} % of "
                                               f"the largest work {scale:.3g} zJ; limit {100 * tolerance:g} %); "
                                               f"largest KE {float(np.max(ke_tot)):.3g} zJ")
        half = max(1, len(ke_tot) // 2)
        early = float(np.max(ke_tot[:half]))
        end = float(ke_tot[-1])
        bounded = end <= ke_growth * max(early, 1e-30) or end <= 0.01 * scale
        criteria["kinetic energy bounded"] = Criterion(bounded, f"KE end {end:.3g} zJ, largest over the first "
                                                                f"half {early:.3g} zJ (limit x{ke_growth:g})")
    passed = all(c.passed for c in criteria.values())
    samples = {"step": step.tolist(), "ke_zJ": ke_tot.tolist(), "work_in_zJ": w_in.tolist()}
    return StabilityResult(dt_s, factor, int(step[-1]) if len(step) else 0, passed, criteria, seconds, samples)


def bisect_timestep(deck: CompressionDeck, folder: Path, *, steps: int, strain: float | None = None, low: float = 1.0,
                    high: float = 4.0, iterations: int = 6, say=print) -> tuple[float, list[StabilityResult]]:
    """Largest passing time-step factor in [low, high] (relative to the estimate's limit x safety) by
    bisection; ``high`` is doubled until it fails (up to 64)."""
    runs = []

    def ok(f: float) -> bool:
        r = run_check(deck, folder / f"factor_{f:.4f}", factor=f, steps=steps, strain=strain)
        runs.append(r)
        say(f"  dt = {r.timestep_s:.3g} s (x{f:.3f}): {'pass' if r.passed else 'FAIL: ' + r.failed()}")
        return r.passed

    if not ok(low):
        return 0.0, runs
    while ok(high):
        low, high = high, high * 2
        if high > 64:
            return low, runs
    for _ in range(iterations):
        mid = math.sqrt(low * high)
        if ok(mid):
            low = mid
        else:
            high = mid
    return low, runs


@dataclass
class BisectionStep:
    """One run of the bisection: its time step (as a factor of the deck's and in seconds) and the verdict."""

    factor: float
    timestep_s: float
    passed: bool
    failed: str


@dataclass
class StabilityCheck:
    """What ``python -m opalflow check`` found (stability.json): the verdict at the deck's time step (x
    ``timestep_factor``), the estimator's limit and, with bisection, the largest stable time step beside it."""

    workflow: str
    passed: bool
    failed: str
    timestep_s: float
    timestep_factor: float
    timestep_estimate_s: float
    timestep_limit_estimate_s: float
    stiffest_mode: str
    steps: int
    strain: float | None
    run: StabilityResult
    headline: str = ""
    wall_s: float = 0.0
    timestep_stable_max_s: float | None = optional()       # the bisection's: only where it ran
    estimate_over_bisected: float | None = optional()
    bisection: list[BisectionStep] | None = optional()


def stability_check(spec: BpmWorkflow, out: Path, *, say=print, steps: int = 3000, timestep_factor: float = 1.0,
                    bisect: bool = False, strain: float | None = None) -> StabilityCheck:
    """The criteria at the deck's time step (x ``timestep_factor``) over ``steps`` steps or up to ``strain``
    and, with ``bisect``, the largest stable time step beside the estimate; writes stability.json and
    stability.md into ``out``."""
    t0 = time.perf_counter()
    s = scene_of(spec).structure(spec, say)
    deck = compression_deck(spec, s)
    if strain:
        steps = steps_to_strain(deck, strain, timestep_factor)
    upto = f" (to strain {strain:g})" if strain else ""
    say(f"stability check of {spec.name}: {s.n_particles} particles, {s.n_bonds} bonds, {steps} steps{upto} at "
        f"dt = {deck.dt_ns * timestep_factor * 1e-9:.3g} s (estimate x{timestep_factor:g}; the estimated limit is "
        f"{deck.timestep.limit_ns * 1e-9:.3g} s, stiffest: {deck.timestep.stiffest})")
    result = run_check(deck, out / "run", factor=timestep_factor, steps=steps, strain=strain)
    for name, c in result.criteria.items():
        say(f"  {'pass' if c.passed else 'FAIL'}  {name}: {c.figures}")
    check = StabilityCheck(spec.name, result.passed, result.failed(), result.timestep_s, timestep_factor,
                           deck.dt_ns * 1e-9, deck.timestep.limit_ns * 1e-9, deck.timestep.stiffest, result.steps,
                           strain, result)
    if bisect:
        say("bisection of the largest stable time step:")
        best, runs = bisect_timestep(deck, out / "bisection", steps=steps, strain=strain, say=say)
        check.timestep_stable_max_s = dt_max = best * deck.dt_ns * 1e-9
        check.estimate_over_bisected = ratio = check.timestep_limit_estimate_s / dt_max if dt_max else None
        check.bisection = [BisectionStep(r.timestep_factor, r.timestep_s, r.passed, r.failed()) for r in runs]
        say(f"largest stable dt found {dt_max:.3g} s; estimated limit {deck.timestep.limit_ns * 1e-9:.3g} s "
            f"(ratio {'-' if ratio is None else format(ratio, '.2f')}); the deck uses {deck.dt_ns * 1e-9:.3g} s")
    verdict = "stable" if result.passed else f"UNSTABLE ({result.failed()})"
    check.headline = f"{spec.name}: {verdict} at dt = {result.timestep_s:.3g} s over {result.steps} steps{upto}"
    check.wall_s = time.perf_counter() - t0
    lines = [f"# Stability check: {spec.name}", "", check.headline + ".", "",
             "| criterion | result | figures |", "|---|---|---|"]
    lines += [f"| {k} | {'pass' if c.passed else 'FAIL'} | {c.figures} |" for k, c in result.criteria.items()]
    if bisect:
        lines += ["", f"Largest stable time step found by bisection: {check.timestep_stable_max_s:.3g} s; "
                  f"the estimator's limit {check.timestep_limit_estimate_s:.3g} s "
                  f"(ratio {check.estimate_over_bisected:.2f}); the deck's time step "
                  f"{check.timestep_estimate_s:.3g} s.", "", "| factor | dt (s) | result |", "|---|---|---|"]
        lines += [f"| {r.factor:.3f} | {r.timestep_s:.3g} | {'pass' if r.passed else 'FAIL: ' + r.failed} |"
                  for r in check.bisection]
    lines += ["", "Criteria: opalflow/bpm/stability.py. Wall time "
              f"{check.wall_s:.1f} s."]
    write_json_atomic(out / "stability.json", table_of(check))
    write_text_atomic(out / "stability.md", "\n".join(lines) + "\n")
    return check
