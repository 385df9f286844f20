"""Single impacts on LAMMPS and LIGGGHTS: where the two Hertz-Mindlin laws agree and where they part.

After Chung and Ooi's single-impact benchmarks for DEM codes (Y. C. Chung, J. Y. Ooi, Granular Matter
13, 643-656 (2011)): one sphere thrown at a held sphere of the same size, run on both engines from the
same data file; the projectile's velocity and spin are compared at every output step.  Five cases,
each one difference of the mapping table in opalflow/granular/decks.py at a time:

- ``head_on``: normal force and damping only;
- ``oblique_sticking``: friction 1e3 (the contact never slides), spheres that do not spin (``fix nve``);
- ``oblique_spinning``: the same with spin (``fix nve/sphere``);
- ``oblique_sliding``: no spin, ``material.friction`` (the contact slides);
- ``second_contact``: as ``oblique_sticking``, but a wall above sends the projectile back onto the
  same sphere: a second contact of the same pair.

The held sphere is frozen (``fix freeze`` in both codes), so each contact uses the projectile's mass as
its effective mass, as for a fixed obstacle; the head-on case also gives the restitution coefficient
against the one asked for.  Contact time (Hertz; Johnson, Contact Mechanics, 1985, eq. 11.24):
t_c = 2.94 delta_max / v, delta_max = (15 m* v^2 / (16 E* R*^(1/2)))^(2/5).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.granular.decks import Contact, Wall, liggghts_executable, run_engine, write_decks, write_spheres
from opalflow.granular.result import ImpactCase, ImpactsResult
from opalflow.granular.spec import ImpactsWorkflow
from opalflow.runs.record import RunRecord, finish
from opalflow.store import new_figure, save_figure

#: a friction coefficient no impact here reaches: the contact sticks throughout
STICKING_FRICTION = 1e3
#: the engines agree where the projectile's velocity and spin differ by less than this, relative to the
#: impact speed (spin times the radius), at every output step
TOLERANCE = 1e-6


@dataclass(frozen=True)
class Case:
    name: str
    oblique: bool
    sticking: bool
    rotation: bool
    second_contact: bool
    why: str


CASES = (
    Case("head_on", False, False, True, False, "normal Hertz force and damping: the same law in both"),
    Case("oblique_sticking", True, True, False, False,
         "k_t = 8 G* a, the history update and x_gamma,t map exactly while the contact sticks and nothing spins "
         "(a damped contact at a steep angle, 60 degrees, slides in its last steps, where the damped normal force "
         "has passed zero before the overlap: then Coulomb parts them as in oblique_sliding)"),
    Case("oblique_spinning", True, True, True, False,
         "spin: the relative velocity at the contact uses R omega in LAMMPS, (R - d/2) omega in LIGGGHTS"),
    Case("oblique_sliding", True, False, False, False,
         "sliding: Coulomb caps the elastic force in LIGGGHTS, elastic + damping in LAMMPS (the same without damping)"),
    Case("second_contact", True, True, False, True,
         "LIGGGHTS keeps the tangential history of the pair's first contact into its second; LAMMPS starts from zero"),
)


def contact_time(spec: ImpactsWorkflow) -> float:
    """Hertz contact time of the projectile on a fixed sphere of the same size (module docstring)."""
    i, m = spec.impact, spec.material
    mass = m.density_kg_m3 * math.pi / 6 * i.diameter_m ** 3
    e_star = m.youngs_modulus_Pa / (2 * (1 - m.poisson_ratio ** 2))
    r_star = i.diameter_m / 4
    delta_max = (15 * mass * i.speed_m_s ** 2 / (16 * e_star * math.sqrt(r_star))) ** 0.4
    return 2.94 * delta_max / i.speed_m_s


def build_case(spec: ImpactsWorkflow, case: Case, out: Path) -> tuple[float, int, float, float]:
    """data.lmp, the decks and the wall of one case in ``out``; its time step (s), steps, contact time (s) and
    friction."""
    i, m = spec.impact, spec.material
    d, v = i.diameter_m, i.speed_m_s
    theta = math.radians(i.angle_deg) if case.oblique else 0.0
    gap, wall_gap = 0.01 * d, 0.05 * d
    t_c = contact_time(spec)
    dt = t_c / i.steps_per_contact
    duration = gap / v + 1.5 * t_c
    walls: tuple[Wall, ...] = ()
    if case.second_contact:
        rise = m.restitution * v * math.cos(theta) ** 2
        duration += 1.3 * (wall_gap / rise + wall_gap / (m.restitution * rise)) + 2 * t_c
        walls = (Wall("lid", d * math.cos(theta) + d / 2 + wall_gap, -1),)
    steps = math.ceil(duration / dt)
    box = ((-3 * d, 3 * d),) * 3
    write_spheres(out / "data.lmp", f"{spec.name} {case.name}: projectile (2) and held sphere (1)", (2, 1), (d, d),
                  ((0.0, 0.0, 0.0), (d * math.sin(theta), 0.0, d * math.cos(theta) + gap)), m.density_kg_m3, box)
    contact = Contact(m, STICKING_FRICTION if case.sticking else m.friction)
    write_decks(out, f"{spec.name} {case.name}", contact, boundary="f f f", skin=0.2 * d, timestep=dt, steps=steps,
                every=max(1, steps // 400), rotation=case.rotation, walls=walls, box=box, observe="projectile",
                start=(f"set             atom 2 vx 0.0 vy 0.0 vz {-v!r}", "fix             hold held freeze"))
    return dt, steps, t_c, contact.friction


def difference(a: np.ndarray, b: np.ndarray, speed: float, radius: float) -> np.ndarray:
    """Per output row: |velocity difference| / speed and |spin difference| radius / speed, the larger."""
    n = min(len(a), len(b))
    dv = np.hypot(a[:n, 1] - b[:n, 1], a[:n, 2] - b[:n, 2]) / speed
    dw = np.abs(a[:n, 3] - b[:n, 3]) * radius / speed
    return np.maximum(dv, dw)


def run_impacts(spec: ImpactsWorkflow, out: Path, say=print) -> ImpactsResult:
    liggghts_executable("kind", "granular_impacts")
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    RunRecord.new(spec, folder=out).begin(out)
    i, m = spec.impact, spec.material
    rows, diffs = [], {}
    for case in CASES:
        folder = out / case.name
        folder.mkdir(exist_ok=True)
        dt, steps, t_c, friction = build_case(spec, case, folder)
        say(f"{spec.name}: {case.name}, {steps} steps on lammps and liggghts")
        curves = {e: run_engine(e, folder)[0] for e in ("lammps", "liggghts")}
        lammps = curves["lammps"]
        diff = difference(lammps, curves["liggghts"], i.speed_m_s, i.diameter_m / 2)
        diffs[case.name] = (lammps[: len(diff), 0], diff)
        over = np.flatnonzero(diff > TOLERANCE)
        rows.append(ImpactCase(
            case.name, dt, steps, t_c, friction, case.rotation, float(diff.max(initial=0.0)),
            "agree" if not len(over) else "part", case.why, int(lammps[over[0], 0]) if len(over) else None,
            {e: {"vx": float(c[-1, 1]), "vz": float(c[-1, 2]), "omegay": float(c[-1, 3])} for e, c in curves.items()},
            {e: c[-1, 2] / i.speed_m_s for e, c in curves.items()} if case.name == "head_on" else None))
    head = rows[0].restitution["lammps"]
    result = ImpactsResult(
        workflow=spec.name, cases=rows, tolerance=TOLERANCE, restitution_asked=m.restitution,
        restitution_measured=head, restitution_error=head / m.restitution - 1,
        headline=", ".join(f"{r.case} {r.verdict} ({r.max_relative_difference:.1e})" for r in rows),
        wall_s=time.perf_counter() - t0)

    def files(stage):
        fig, ax = new_figure(figsize=(6, 3.8))
        for name, (steps, diff) in diffs.items():   # second_contact dashed: it starts as oblique_sticking
            dashed = name == "second_contact"
            ax.semilogy(steps, np.maximum(diff, 1e-17), label=name, lw=1.2 if dashed else 1.8, ls="--" if dashed else "-")
        ax.axhline(TOLERANCE, color="0.5", ls=":", lw=0.8)
        ax.set_xlabel("step")
        ax.set_ylabel("|LAMMPS - LIGGGHTS| / impact speed")
        ax.legend(fontsize=7)
        save_figure(fig, stage("impacts.png"))

    return finish(out, result, _report(spec, result), files=files)


def _report(spec: ImpactsWorkflow, s: ImpactsResult) -> str:
    i, m = spec.impact, spec.material
    lines = [f"# {spec.name}: single impacts on LAMMPS and LIGGGHTS", "",
             f"A sphere (d = {i.diameter_m:g} m, {m.density_kg_m3:g} kg/m^3, E = {m.youngs_modulus_Pa:g} Pa, "
             f"nu = {m.poisson_ratio:g}, restitution {m.restitution:g}) thrown at {i.speed_m_s:g} m/s at a held "
             f"sphere of the same size, head-on or at {i.angle_deg:g} degrees to the line of centres "
             "(after Chung and Ooi, Granular Matter 13, 643 (2011)). The engines agree where the projectile's "
             f"velocity and spin differ by less than {s.tolerance:g} of the impact speed at every output step.",
             "", "| case | friction | spin | steps | largest difference | verdict | why |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r.case} | {r.friction:g} | {'yes' if r.rotation else 'no'} | {r.steps} | "
              f"{r.max_relative_difference:.2e} | {r.verdict}"
              + (f" (step {r.first_step_over_tolerance})" if r.first_step_over_tolerance is not None else "")
              + f" | {r.why} |" for r in s.cases]
    lines += ["", f"Head-on restitution: asked {s.restitution_asked:g}, measured {s.restitution_measured:.6f} "
              f"(error {100 * s.restitution_error:+.2f} %; the damping of both codes, -2 sqrt(5/6) beta "
              "sqrt(S_n m*), gives the asked value only approximately for a Hertz contact).", "",
              "![impacts](impacts.png)", "",
              "Files: one folder per case with data.lmp, in.lammps, in.liggghts and their logs; the mapping of "
              "the contact law between the codes is in opalflow/granular/decks.py."]
    return "\n".join(lines) + "\n"
