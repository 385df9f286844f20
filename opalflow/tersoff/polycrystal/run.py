"""Kinds ``polycrystal_tension`` and ``polycrystal_waves``: the last stage of seed 003.

Each run folder gets ``results.h5`` (every dataset with ``units``, tables with ``columns``),
``summary.json`` (``youngs_modulus_GPa``, ``poisson_ratio`` or the three ``wave_speed_*_m_s``,
``wall_s``; written last), ``report.md`` beside the references, the plots, ``.vtu`` meshes, and
``jobs/``: each experiment a :class:`opalflow.runs.jobs.Job` (its own spec, one mesh and seed, in a folder named by
its label and spec hash, with its record and its result: :class:`TensionRun`, :class:`WaveRun`,
:class:`Measured` of :mod:`opalflow.tersoff.polycrystal.result`), so ``--resume`` skips what is done with the same
inputs, a changed experiment runs anew, and ``status`` lists them; the run's own result is a :class:`TensionResult`
or :class:`WavesResult`.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from opalflow.analysis.elasticity import VOIGT
from opalflow.progress import Progress
from opalflow.runs.jobs import Job, job_record, prepare
from opalflow.runs.record import RunRecord, finish
from opalflow.runs.result import typed
from opalflow.store import RESULTS, SUMMARY, h5_bytes, new_figure, save_figure
from opalflow.tersoff.parameters import load_parameters
from opalflow.tersoff.polycrystal.crystal import (Crystal, check_sample_hessian, longitudinal_speed_nm_ps,
                                                  single_crystal)
from opalflow.tersoff.polycrystal.dynamics import M_PER_S, Bounds, Polycrystal, polycrystal_bounds, speeds
from opalflow.tersoff.polycrystal.mesh import block
from opalflow.tersoff.polycrystal.output import plot_mesh, write_vtu
from opalflow.tersoff.polycrystal.result import (REFERENCE, LammpsCheck, Measured, Realised, RelaxationComparison,
                                                 Stats, TensionExperiment, TensionResult, TensionRun, WaveExperiment,
                                                 WaveRun, WavesResult)
from opalflow.tersoff.polycrystal.samples import Samples, random_rotations, relax_md, relax_minimize
from opalflow.tersoff.polycrystal.spec import PolycrystalWorkflow, TensionWorkflow, WavesWorkflow
from opalflow.version import __version__



def setup(spec: PolycrystalWorkflow, out: Path) -> tuple:
    """The potential, its single crystal, the batched samples and the crystal's bounds; every check is made
    before the run folder is started."""
    params = load_parameters(spec.tersoff.potential, spec.tersoff.element)
    crystal = single_crystal(params, spec.tersoff.potential)
    samples = Samples(params.values(), params.cutoff(), crystal.a0_A)
    check_sample_hessian(samples, spec.tersoff.potential)
    start_folder(out, spec)
    return params, crystal, samples, polycrystal_bounds(*crystal.constants, samples.density_kg_m3)


def start_folder(out: Path, spec: PolycrystalWorkflow) -> None:
    """The run folder with ``run.json`` (the spec, for ``--resume``) and ``jobs/`` (one folder per experiment)."""
    (out / "jobs").mkdir(parents=True, exist_ok=True)
    RunRecord.new(spec, folder=out).begin(out)


def experiment_job(spec: PolycrystalWorkflow, label: str, at: tuple = (), **sections) -> Job:
    """An experiment as a job: the run's spec with the sections that make it one experiment (``tension``,
    ``samples``, ``waves`` replaced), named by its label, so its spec hash is that of what it computes."""
    return Job(label, dataclasses.replace(spec, name=label, description="", **sections), at)


def run_experiments(jobs: list[Job], out: Path, resume: bool, compute, kind: type, say) -> list:
    """Each job's result (of class ``kind``), in order: read from its folder where ``--resume`` finds it done with
    the same spec hash, else ``compute(job)`` (its record running, then finished with the result as its summary)."""
    done, todo = prepare(jobs, out)
    if not resume:
        todo, done = jobs, {}
    results = {label: typed(kind, {k: v for k, v in summary.items() if k != "state"})
               for label, summary in done.items()}
    for label in results:
        say(f"{label}: done before (resume)")
    for job in todo:
        folder = job.folder(out)
        (job_record(folder) or RunRecord.job(job.spec, job.label, job.key)).begin(folder, launcher="in-process")
        results[job.label] = result = compute(job)
        finish(folder, dataclasses.asdict(result),
               f"# {job.label}\n\nAn experiment of the run in {out} (its {SUMMARY} holds the result).")
    return [results[j.label] for j in jobs]


def realised_bounds(pc: Polycrystal) -> dict[str, Realised]:
    """Voigt and Reuss bounds of E_x and nu for the orientations this mesh actually drew.

    Voigt: uniform strain, <C> (volume average) inverted; Reuss: uniform stress, <C^-1>.
    E_x = 1/S_11, nu = -(S_12 + S_13) / (2 S_11) (the mean lateral contraction).
    """
    c6 = np.stack([[pc.stiffness_tensors[:, i, j, k, l] for (k, l) in VOIGT] for (i, j) in VOIGT]).transpose(2, 0, 1)
    w = pc.volume0 / pc.volume0.sum()
    s_voigt = np.linalg.inv(np.einsum("e,eab->ab", w, c6))
    s_reuss = np.einsum("e,eab->ab", w, np.linalg.inv(c6))
    return {name: Realised(1.0 / s[0, 0], -(s[0, 1] + s[0, 2]) / (2.0 * s[0, 0]))
            for name, s in (("voigt", s_voigt), ("reuss", s_reuss))}


def slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y against x (with an intercept)."""
    return float(np.polyfit(x, y, 1)[0])


# ---------------------------------------------------------------- tension
def tension_job(spec: TensionWorkflow, samples: Samples, crystal: Crystal, cubes: int, cube_nm: float, seed: int,
                say, label: str) -> tuple[TensionRun, Polycrystal]:
    """One tension experiment: periodic along x, free sides; stress-strain and volume-strain."""
    t = spec.tension
    t0 = time.perf_counter()
    mesh = block((cubes, cubes, cubes), cube_nm, (True, False, False))
    pc = Polycrystal(mesh, samples, random_rotations(mesh.elements, seed), crystal.constants,
                     spec.samples.relaxation, spec.samples.force_tol_eV_A)
    length = cubes * cube_nm
    dt = pc.stable_timestep(t.timestep_safety)
    gamma = t.damping * math.pi * longitudinal_speed_nm_ps(crystal) / length
    points = int(round(t.max_strain / t.strain_step))
    rate_ps = t.strain_rate_per_ns * 1e-3
    deform = max(1, math.ceil(t.strain_step / (rate_ps * dt)))
    volume0 = pc.volume()
    rows = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0, 0]]
    steps = 0
    meter = Progress(points * (deform + 100) if t.method == "dynamic" else points, 0, f"  {label}: ", say=say,
                     unit="macro step")
    for k in range(1, points + 1):
        relax = 0
        if t.method == "static":
            _stretch(pc, mesh.box[0] * (1.0 + k * t.strain_step))
            relax = pc.solve_static(t.residual_tol)
            meter.update(k)
        else:
            for _ in range(deform):
                _stretch(pc, pc.box[0] + mesh.box[0] * t.strain_step / deform)
                pc.verlet(dt, gamma)
                steps += 1
                meter.update(steps, extra=f" (stretching to strain {k * t.strain_step:g})")
            while pc.residual > t.residual_tol:
                if relax >= t.max_relax_steps:
                    raise RuntimeError(f"{label}: residual {pc.residual:.3g} after {relax} relaxation steps at strain "
                                       f"{k * t.strain_step:g} (tension.max_relax_steps = {t.max_relax_steps})")
                pc.verlet(dt, gamma)
                relax += 1
                steps += 1
                meter.update(steps, extra=f" (strain {k * t.strain_step:g}, residual {pc.residual:.1e})")
            meter.total = steps + (points - k) * (deform + relax)
        s = pc.mean_stress()
        rows.append([pc.box[0] / mesh.box[0] - 1.0, *(s[a, b] for a, b in VOIGT), pc.volume() / volume0,
                     pc.residual, relax, pc.evaluations])
    curve = np.array(rows, dtype=float)
    strain, sxx, vol = curve[:, 0], curve[:, 1], curve[:, 7]
    e_mod = slope(strain, sxx)
    nu = 0.5 * (1.0 - slope(strain, vol - 1.0))
    wall = time.perf_counter() - t0
    return TensionRun(cubes, cube_nm, seed, mesh.elements, length, t.method, dt, gamma, deform, steps, pc.evaluations,
                      e_mod, nu, realised_bounds(pc), wall,
                      ["strain", "sxx_GPa", "syy_GPa", "szz_GPa", "syz_GPa", "sxz_GPa", "sxy_GPa", "volume_ratio",
                       "residual", "relax_steps", "sample_evaluations"], curve.tolist(),
                      wall / max(steps, 1) if t.method == "dynamic" else None), pc


def _stretch(pc: Polycrystal, length: float) -> None:
    """Set the periodic length along x, every vertex remapped affinely (as LAMMPS fix deform remap x)."""
    ratio = length / pc.box[0]
    pc.box[0] = length
    pc.x[:, 0] *= ratio


def relaxation_comparison(samples: Samples, seed: int, force_tol: float, count: int = 8) -> RelaxationComparison:
    """Both steady states of eq. 8 on ``count`` elements strained by 0.5 % in random directions."""
    rng = np.random.default_rng(seed)
    rot = random_rotations(count, seed + 1000)
    eps = rng.normal(0.0, 0.005, (count, 3, 3))
    eps = 0.5 * (eps + eps.transpose(0, 2, 1))
    cells = np.einsum("eab,ebc->eac", np.eye(3) + eps, samples.reference_cells(rot))
    x = samples.positions(cells)
    t = time.perf_counter()
    mini = relax_minimize(samples, x, cells, rot, force_tol)
    t_min = time.perf_counter() - t
    t = time.perf_counter()
    md, _ = relax_md(samples, x, cells, force_tol)
    t_md = time.perf_counter() - t
    return RelaxationComparison(
        elements=count, strain_rms=0.005, minimize_evaluations=mini.evaluations, minimize_s=t_min,
        md_steps=md.evaluations, md_s=t_md,
        max_stress_difference_GPa=float(np.abs(mini.evaluation.stress - md.evaluation.stress).max()),
        max_stress_GPa=float(np.abs(mini.evaluation.stress).max()))


def tension_jobs(spec: TensionWorkflow) -> list[Job]:
    """Each mesh x orientation seed as a job (``at``: its index in ``tension.cubes``, cubes, cube edge, seed)."""
    t = spec.tension
    return [experiment_job(spec, f"tension_{6 * n ** 3}el_{h:g}nm_seed{seed}", (i, n, h, seed),
                           tension=dataclasses.replace(t, cubes=[n], cube_nm=[h]),
                           samples=dataclasses.replace(spec.samples, seeds=[seed], lammps_check=0))
            for i, (n, h) in enumerate(zip(t.cubes, t.cube_nm)) for seed in spec.samples.seeds]


def run_tension(spec: TensionWorkflow, out: Path, say=print, resume: bool = False) -> TensionResult:
    t0 = time.perf_counter()
    params, crystal, samples, bounds = setup(spec, out)
    t = spec.tension
    say(f"polycrystal tension with {spec.tersoff.potential}: a0 = {crystal.a0_A:.5f} A, C11 {crystal.C11_GPa:.1f}, "
        f"C12 {crystal.C12_GPa:.1f}, C44 {crystal.C44_GPa:.1f} GPa; Voigt E {bounds.voigt.E_GPa:.1f}, "
        f"Reuss E {bounds.reuss.E_GPa:.1f} GPa")
    check = _lammps_check(spec, params, samples, out)
    relax_cmp = relaxation_comparison(samples, spec.samples.seeds[0], spec.samples.force_tol_eV_A)
    say(f"relaxation: minimize {relax_cmp.minimize_evaluations} evaluations, damped MD {relax_cmp.md_steps} "
        f"steps; stresses differ by {relax_cmp.max_stress_difference_GPa:.1e} GPa")
    todo, last = tension_jobs(spec), {}

    def compute(job: Job) -> TensionRun:
        i, n, h, seed = job.at
        label = f"[{todo.index(job) + 1}/{len(todo)}] {6 * n ** 3} elements, edge {n * h:g} nm, seed {seed}"
        say(f"{label}: {t.method}")
        run, last[i] = tension_job(spec, samples, crystal, n, h, seed, say, label)
        say(f"{label}: E = {run.youngs_modulus_GPa:.2f} GPa, nu = {run.poisson_ratio:.4f} ({run.macro_steps} macro "
            f"steps, {run.evaluations} sample evaluations, {run.wall_s:.1f} s)")
        return run

    jobs = run_experiments(todo, out, resume, compute, TensionRun, say)
    result = _tension_result(spec, jobs, bounds, check, relax_cmp, crystal, samples)

    def files(stage):
        _plot_curves(stage("stress_strain.png"), stage("volume_strain.png"), jobs)
        for i, pc in last.items():
            n, h = t.cubes[i], t.cube_nm[i]
            write_vtu(stage(f"mesh_{6 * n ** 3}el_{h:g}nm.vtu"), pc)
        if last:
            i, pc = next(iter(last.items()))
            plot_mesh(stage("mesh.png"), pc, f"{pc.mesh.elements} elements at strain {t.max_strain:g} "
                      f"(seed {spec.samples.seeds[-1]})")
        stage(RESULTS).write_bytes(_tension_h5(jobs))
        result.wall_s = time.perf_counter() - t0

    return finish(out, result, lambda: _tension_report(spec, result, jobs), files=files)


def _lammps_check(spec: PolycrystalWorkflow, params, samples: Samples, out: Path) -> LammpsCheck | None:
    if spec.samples.lammps_check == 0:
        return None
    from opalflow.tersoff.polycrystal.check import compare_with_lammps
    return compare_with_lammps(samples, params, out / "lammps_check", count=spec.samples.lammps_check)


def _tension_result(spec, jobs: list[TensionRun], bounds: Bounds, check, relax_cmp, crystal, samples) -> TensionResult:
    groups: dict[tuple, list[TensionRun]] = {}
    for j in jobs:
        groups.setdefault((j.cubes, j.cube_nm), []).append(j)
    experiments = [TensionExperiment(
        elements=6 * n ** 3, cubes=n, cube_nm=h, edge_nm=n * h,
        youngs_modulus_GPa=Stats.of([j.youngs_modulus_GPa for j in js]),
        poisson_ratio=Stats.of([j.poisson_ratio for j in js]), wall_s=Stats.of([j.wall_s for j in js]),
        s_per_macro_step=Stats.of([j.s_per_macro_step for j in js]) if js[0].s_per_macro_step else None,
        inside_realised_bounds=all(j.bounds_realised["reuss"].E_GPa <= j.youngs_modulus_GPa
                                   <= j.bounds_realised["voigt"].E_GPa for j in js))
        for (n, h), js in groups.items()]
    e_all, nu_all = Stats.of([j.youngs_modulus_GPa for j in jobs]), Stats.of([j.poisson_ratio for j in jobs])
    e, nu = e_all.mean, nu_all.mean
    return TensionResult(
        youngs_modulus_GPa=e, poisson_ratio=nu, youngs_modulus=e_all, poisson=nu_all, experiments=experiments,
        error_vs_reference={"youngs_modulus_relative": (e - REFERENCE["youngs_modulus_GPa"]) / 160.0,
                            "poisson_ratio_absolute": nu - REFERENCE["poisson_ratio"]},
        bounds=bounds, inside_bounds=bounds.reuss.E_GPa <= e <= bounds.voigt.E_GPa,
        single_crystal=crystal, density_kg_m3=samples.density_kg_m3, lammps_check=check,
        relaxation_comparison=relax_cmp, potential=spec.tersoff.potential, method=spec.tension.method,
        spec=spec.to_dict(),
        headline=(f"E = {e:.2f} +- {e_all.std:.2f} GPa ({100 * (e - 160.0) / 160.0:+.1f} % of 160; Voigt "
                  f"{bounds.voigt.E_GPa:.1f}, Reuss {bounds.reuss.E_GPa:.1f}), nu = {nu:.4f} +- "
                  f"{nu_all.std:.4f} (0.22), {len(jobs)} runs"))


def _plot_curves(stress_path: Path, volume_path: Path, jobs: list[TensionRun]) -> None:
    for path, col, ylabel, ref in ((stress_path, 1, "sigma_xx (GPa)", lambda e: REFERENCE["youngs_modulus_GPa"] * e),
                                   (volume_path, 7, "V / V0 - 1", lambda e: (1 - 2 * REFERENCE["poisson_ratio"]) * e)):
        fig, ax = new_figure(figsize=(6, 4.5))
        for j in jobs:
            c = np.array(j.curve)
            ax.plot(c[:, 0] * 100, c[:, col] - (1.0 if col == 7 else 0.0), "o-", ms=3, lw=1,
                    label=f"{j.elements} el, {j.edge_nm:g} nm, seed {j.seed}")
        e = np.linspace(0, max(np.array(j.curve)[:, 0].max() for j in jobs), 20)
        ax.plot(e * 100, ref(e), "k--", label="linear elasticity, E = 160 GPa, nu = 0.22 (seed 003)")
        ax.set_xlabel("strain (%)")
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        ax.set_title("Polycrystal tension: " + ("stress-strain (Fig. 3)" if col == 1 else "volume-strain (Fig. 4)"))
        save_figure(fig, path)


def _tension_h5(jobs: list[TensionRun]) -> bytes:
    units = ["1", "GPa", "GPa", "GPa", "GPa", "GPa", "GPa", "1", "1", "1", "1"]

    def write(h):
        for j in jobs:
            g = h.create_group(f"tension_{j.elements}el_{j.cube_nm:g}nm_seed{j.seed}")
            d = g.create_dataset("curve", data=np.array(j.curve))
            d.attrs["columns"] = j.curve_columns
            d.attrs["units"] = units
            for key, unit in (("youngs_modulus_GPa", "GPa"), ("poisson_ratio", "1"), ("timestep_ps", "ps"),
                              ("wall_s", "s")):
                s = g.create_dataset(key, data=getattr(j, key))
                s.attrs["units"] = unit
    return h5_bytes(write)


def _bounds_rows(bounds: Bounds) -> list[str]:
    rows = ["| average | E (GPa) | nu | G (GPa) | plate (m/s) | rod (m/s) | shear (m/s) |", "|---|---|---|---|---|---|---|"]
    for name in ("voigt", "hill", "reuss"):
        b = getattr(bounds, name)
        rows.append(f"| {name.capitalize()} | {b.E_GPa:.2f} | {b.nu:.4f} | {b.G_GPa:.2f} | "
                    f"{b.wave_speed_plate_m_s:.0f} | {b.wave_speed_rod_m_s:.0f} | {b.wave_speed_shear_m_s:.0f} |")
    return rows


def _crystal_lines(result: TensionResult | WavesResult, spec, bounds: Bounds) -> list[str]:
    c = result.single_crystal
    lines = [f"Potential `{spec.tersoff.potential}`: a0 = {c.a0_A:.5f} A, C11 = {c.C11_GPa:.2f}, C12 = "
             f"{c.C12_GPa:.2f}, C44 = {c.C44_GPa:.2f} GPa (relaxed; C44^0 = {c.C44_0_GPa:.2f}), sample density "
             f"{result.density_kg_m3:.1f} kg/m^3. Isotropic averages of this single crystal (the polycrystal's "
             "bounds) and the speeds they imply:", "", *_bounds_rows(bounds), ""]
    chk = result.lammps_check
    if chk:
        lines += [f"Batched Tersoff (JAX) against LAMMPS `pair_style tersoff` on {chk.samples} random samples "
                  f"(strain up to {chk.strain:g}, thermal displacements {chk.displacement_A:g} A): largest relative "
                  f"differences energy {chk.max_relative_energy:.1e}, forces {chk.max_relative_forces:.1e}, virial "
                  f"{chk.max_relative_virial:.1e}.", ""]
    return lines


def _tension_report(spec, result: TensionResult, jobs: list[TensionRun]) -> str:
    t, s = spec.tension, spec.samples
    e, nu, bounds, rc = result.youngs_modulus, result.poisson, result.bounds, result.relaxation_comparison
    lines = [f"# Polycrystal tension ({spec.name})", "",
             f"Cubes split into 6 tetrahedra, each with a 64-atom Tersoff sample in a uniformly random orientation; "
             f"periodic along x, free sides, stretched along x to {t.max_strain:g} in steps of {t.strain_step:g} "
             + ("(dynamic: deformation steps at " f"{t.strain_rate_per_ns:g}/ns with the vertices remapped, then damped "
                f"velocity-Verlet relaxation until the force residual is below {t.residual_tol:g})"
                if t.method == "dynamic" else f"(static: modified Newton to residual {t.residual_tol:g})")
             + f". Samples relaxed by {s.relaxation} to a largest atomic force of {s.force_tol_eV_A:g} eV/A. E = slope of "
             "the volume-averaged sigma_xx against strain; nu = (1 - dV/V0/d strain) / 2 (seed 003, Figs. 3-4).", "",
             *_crystal_lines(result, spec, bounds),
             "## Result", "",
             "| quantity | this run | reference (seed 003) | error |", "|---|---|---|---|",
             f"| E (GPa) | {e.mean:.2f} +- {e.std:.2f} | 160 | {100 * (e.mean - 160) / 160:+.2f} % |",
             f"| nu | {nu.mean:.4f} +- {nu.std:.4f} | 0.22 | {nu.mean - 0.22:+.4f} |", "",
             f"E lies {'inside' if result.inside_bounds else 'OUTSIDE'} the isotropic Reuss-Voigt interval of the "
             f"potential ({bounds.reuss.E_GPa:.2f} - {bounds.voigt.E_GPa:.2f} GPa). "
             "The reference is measured polycrystalline silicon; the model can only give what its potential's single "
             "crystal bounds, and with one grain per element (constant strain in each) it sits near the Voigt (uniform "
             "strain) side. A finite set of orientations has its own bounds (columns 'realised'): they differ from the "
             "isotropic ones by the sampling scatter of the orientations.", "",
             "## Runs", "",
             "| elements | edge (nm) | seed | E (GPa) | nu | realised Reuss - Voigt E (GPa) | macro steps | sample "
             "evaluations | dt (ps) | wall (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for j in jobs:
        b = j.bounds_realised
        lines.append(f"| {j.elements} | {j.edge_nm:g} | {j.seed} | {j.youngs_modulus_GPa:.2f} | "
                     f"{j.poisson_ratio:.4f} | {b['reuss'].E_GPa:.2f} - {b['voigt'].E_GPa:.2f} | "
                     f"{j.macro_steps} | {j.evaluations} | {j.timestep_ps:.4f} | {j.wall_s:.1f} |")
    lines += ["", "| elements | edge (nm) | E (GPa) mean +- std | nu mean +- std | wall per run (s) | s per macro step |",
              "|---|---|---|---|---|---|"]
    for x in result.experiments:
        sp, ex, px = x.s_per_macro_step, x.youngs_modulus_GPa, x.poisson_ratio
        lines.append(f"| {x.elements} | {x.edge_nm:g} | {ex.mean:.2f} +- {ex.std:.2f} | {px.mean:.4f} +- "
                     f"{px.std:.4f} | {x.wall_s.mean:.1f} | " + (f"{sp.mean:.3f} |" if sp else "- |"))
    lines += ["", "## Steady state of the samples (eq. 8): minimisation against damped MD", "",
              f"{rc.elements} elements strained by {rc.strain_rms:g} rms in random directions: preconditioned "
              f"Newton minimisation {rc.minimize_evaluations} force evaluations ({rc.minimize_s:.2f} s), damped "
              f"MD (1 fs, gamma 20/ps) {rc.md_steps} steps ({rc.md_s:.2f} s); the stresses differ by at most "
              f"{rc.max_stress_difference_GPa:.1e} GPa (largest stress {rc.max_stress_GPa:.2f} GPa).", "",
              "![stress-strain](stress_strain.png)", "", "![volume-strain](volume_strain.png)", "",
              "![mesh](mesh.png)", "",
              f"Wall time {result.wall_s:.1f} s on this machine. opalflow {__version__}."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- waves
WAVE_AXIS = {"plate": 2, "rod": 2, "shear": 0}          # velocity component the piston drives
WAVE_KEY = {"plate": "wave_speed_plate_m_s", "rod": "wave_speed_rod_m_s", "shear": "wave_speed_shear_m_s"}


def wave_job(spec: WavesWorkflow, samples: Samples, crystal: Crystal, bounds: Bounds, name: str,
             say) -> tuple[WaveRun, Polycrystal]:
    """A piston on z = 0 drives the column; the front is where the section-averaged velocity reaches half the
    piston's.

    plate: periodic in x and y (a laterally infinite plate: uniaxial strain, P wave), piston along z;
    rod: free sides, piston along z (E wave for wavelengths long against the width);
    shear: periodic in x and y, piston along x (plane shear wave).  The piston's velocity is held
    (a step), so the half-amplitude point travels at the long-wave speed; arrival times at each
    vertex layer in the fit range give the speed (least squares, with its standard error).
    """
    w = spec.waves
    t0 = time.perf_counter()
    lateral = name != "rod"
    mesh = block(tuple(w.cubes), w.cube_nm, (lateral, lateral, False))
    pc = Polycrystal(mesh, samples, random_rotations(mesh.elements, w.seed), crystal.constants,
                     spec.samples.relaxation, spec.samples.force_tol_eV_A)
    dt = pc.stable_timestep(w.timestep_safety)
    length = w.cubes[2] * w.cube_nm
    slowest = bounds.reuss.of(name) / M_PER_S * 0.95
    steps = int(math.ceil(w.travel * length / slowest / dt))
    layer = np.rint(mesh.vertices[:, 2] / w.cube_nm).astype(int)
    counts = np.bincount(layer)
    axis = WAVE_AXIS[name]
    v0 = w.piston_m_s / M_PER_S
    fixed = np.zeros_like(pc.x, dtype=bool)
    fixed[layer == 0, axis] = True
    prescribed = np.where(fixed, v0, 0.0)
    pc.v[fixed] = v0
    history = [np.zeros(len(counts))]
    meter = Progress(steps, 0, f"  {name} wave: ", say=say, unit="macro step")
    for step in range(1, steps + 1):
        pc.verlet(dt, 0.0, fixed, prescribed)
        history.append(np.bincount(layer, pc.v[:, axis], minlength=len(counts)) / counts)
        meter.update(step)
    profile = np.array(history) / v0                 # (steps + 1, layers): section velocity / piston velocity
    times = np.arange(steps + 1) * dt
    stations = np.arange(len(counts)) * w.cube_nm
    arrival = np.full(len(counts), np.nan)
    for k in range(len(counts)):
        above = np.nonzero(profile[:, k] >= 0.5)[0]
        if len(above) and above[0] > 0:
            i = above[0]
            f0, f1 = profile[i - 1, k], profile[i, k]
            arrival[k] = times[i - 1] + (0.5 - f0) / (f1 - f0) * dt
    lo, hi = w.fit_range
    use = (stations >= lo * length) & (stations <= hi * length) & np.isfinite(arrival)
    if use.sum() < 3:
        raise RuntimeError(f"{name} wave: the front reached {int(np.isfinite(arrival).sum())} stations; too few to fit")
    coef, cov = np.polyfit(arrival[use], stations[use], 1, cov=True)
    speed = coef[0] * M_PER_S
    wall = time.perf_counter() - t0
    return WaveRun(name, mesh.elements, list(w.cubes), w.cube_nm, length, "periodic" if lateral else "free",
                   w.piston_m_s, dt, steps, pc.evaluations, speed, float(np.sqrt(cov[0, 0])) * M_PER_S, int(use.sum()),
                   wall, wall / steps, times.tolist(), stations.tolist(), arrival.tolist(), profile.tolist()), pc


def run_waves(spec: WavesWorkflow, out: Path, say=print, resume: bool = False) -> WavesResult:
    t0 = time.perf_counter()
    params, crystal, samples, bounds = setup(spec, out)
    w = spec.waves
    say(f"polycrystal waves with {spec.tersoff.potential}: {', '.join(w.experiments)} in a {w.cubes[0]}x{w.cubes[1]}x"
        f"{w.cubes[2]} column of cubes ({6 * int(np.prod(w.cubes))} elements), edge {w.cube_nm:g} nm")
    check = _lammps_check(spec, params, samples, out)
    tension = TensionWorkflow(name="moduli", kind="polycrystal_tension", tersoff=spec.tersoff,
                              samples=dataclasses.replace(spec.samples, seeds=[w.seed], lammps_check=0))
    tension.tension = dataclasses.replace(tension.tension, method="static", cubes=[4], cube_nm=[w.cube_nm])

    def measure(job: Job) -> Measured:
        say("E and nu of the same potential: static tension of 384 elements")
        run, _ = tension_job(tension, samples, crystal, 4, w.cube_nm, w.seed, say, "static tension")
        return Measured(**dataclasses.asdict(speeds(run.youngs_modulus_GPa, run.poisson_ratio, samples.density_kg_m3)),
                        youngs_modulus_GPa=run.youngs_modulus_GPa, poisson_ratio=run.poisson_ratio,
                        elements=run.elements, seed=w.seed, wall_s=run.wall_s)

    measured, = run_experiments([experiment_job(tension, "static_tension")], out, resume, measure, Measured, say)
    states = {}

    def wave(job: Job) -> WaveRun:
        name = job.spec.waves.experiments[0]
        run, states[name] = wave_job(spec, samples, crystal, bounds, name, say)
        say(f"{name} wave: {run.speed_m_s:.0f} +- {run.speed_stderr_m_s:.0f} m/s ({run.macro_steps} macro steps, "
            f"{run.wall_s:.1f} s)")
        return run

    todo = [experiment_job(spec, f"wave_{name}", waves=dataclasses.replace(w, experiments=[name]),
                           samples=dataclasses.replace(spec.samples, lammps_check=0)) for name in w.experiments]
    jobs = run_experiments(todo, out, resume, wave, WaveRun, say)
    result = _waves_result(spec, jobs, bounds, measured, check, crystal, samples)

    def files(stage):
        _plot_fronts(stage("wavefront.png"), jobs)
        _plot_profiles(stage("profiles.png"), jobs)
        for name, pc in states.items():
            write_vtu(stage(f"wave_{name}.vtu"), pc, pc.v * M_PER_S)
        if states:
            name, pc = next(iter(states.items()))
            plot_mesh(stage("mesh.png"), pc, f"{name} wave: {pc.mesh.elements} elements at the end of the run")
        stage(RESULTS).write_bytes(_waves_h5(jobs))
        result.wall_s = time.perf_counter() - t0

    return finish(out, result, lambda: _waves_report(spec, result, jobs), files=files)


def _waves_result(spec, jobs: list[WaveRun], bounds: Bounds, measured: Measured, check, crystal,
                  samples) -> WavesResult:
    out = WavesResult(bounds=bounds, measured_moduli=measured, single_crystal=crystal,
                      density_kg_m3=samples.density_kg_m3, lammps_check=check, potential=spec.tersoff.potential,
                      spec=spec.to_dict())
    parts = []
    curves = ("times_ps", "profile", "arrival_ps", "stations_nm")
    for j in jobs:
        ref, pred = REFERENCE[WAVE_KEY[j.experiment]], measured.of(j.experiment)
        setattr(out, WAVE_KEY[j.experiment], j.speed_m_s)
        out.experiments[j.experiment] = WaveExperiment(
            **{k: v for k, v in dataclasses.asdict(j).items() if k not in curves},
            error_vs_reference=(j.speed_m_s - ref) / ref, error_vs_measured_moduli=(j.speed_m_s - pred) / pred)
        parts.append(f"{j.experiment} {j.speed_m_s:.0f} m/s ({100 * (j.speed_m_s - ref) / ref:+.1f} % of {ref:.0f})")
    out.headline = "; ".join(parts)
    return out


def _plot_fronts(path: Path, jobs: list[WaveRun]) -> None:
    fig, ax = new_figure(figsize=(6.5, 4.5))
    for j, colour in zip(jobs, ("C0", "C1", "C2")):
        arr, st = np.array(j.arrival_ps, dtype=float), np.array(j.stations_nm)
        ok = np.isfinite(arr)
        ax.plot(arr[ok], st[ok], "o", ms=3, color=colour, label=f"{j.experiment}: {j.speed_m_s:.0f} m/s")
        ref = REFERENCE[WAVE_KEY[j.experiment]]
        t = np.linspace(0, np.nanmax(arr), 10)
        ax.plot(t, ref * t * 1e-3, "--", color=colour, lw=1, label=f"{j.experiment} reference {ref:.0f} m/s")
    ax.set_xlabel("time (ps)")
    ax.set_ylabel("wavefront position z (nm)")
    ax.set_title("Wavefront (half the piston velocity) against time")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def _plot_profiles(path: Path, jobs: list[WaveRun]) -> None:
    fig, axes = new_figure(1, len(jobs), figsize=(4.2 * len(jobs), 3.8), squeeze=False)
    for ax, j in zip(axes[0], jobs):
        prof, times, st = np.array(j.profile), np.array(j.times_ps), np.array(j.stations_nm)
        for frac in (0.33, 0.66, 1.0):
            i = int(frac * (len(times) - 1))
            ax.plot(st, prof[i], label=f"t = {times[i]:.1f} ps")
            ref = REFERENCE[WAVE_KEY[j.experiment]] * times[i] * 1e-3
            ax.axvline(ref, color=ax.lines[-1].get_color(), ls=":", lw=1)
        ax.set_xlabel("z (nm)")
        ax.set_ylabel("section velocity / piston velocity")
        ax.set_title(f"{j.experiment} ({j.lateral} sides); dotted: reference front")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    save_figure(fig, path)


def _waves_h5(jobs: list[WaveRun]) -> bytes:
    def write(h):
        for j in jobs:
            g = h.create_group(f"wave_{j.experiment}")
            for key, unit in (("times_ps", "ps"), ("stations_nm", "nm"), ("arrival_ps", "ps"), ("speed_m_s", "m/s"),
                              ("speed_stderr_m_s", "m/s"), ("timestep_ps", "ps")):
                d = g.create_dataset(key, data=np.asarray(getattr(j, key), dtype=float))
                d.attrs["units"] = unit
            d = g.create_dataset("profile", data=np.array(j.profile))
            d.attrs["units"] = "1 (section-averaged velocity / piston velocity)"
            d.attrs["columns"] = [f"z = {z:g} nm" for z in j.stations_nm]
    return h5_bytes(write)


def _waves_report(spec, result: WavesResult, jobs: list[WaveRun]) -> str:
    w = spec.waves
    m, b = result.measured_moduli, result.bounds
    lines = [f"# Polycrystal waves ({spec.name})", "",
             f"A column of {w.cubes[0]} x {w.cubes[1]} x {w.cubes[2]} cubes of {w.cube_nm:g} nm "
             f"({6 * int(np.prod(w.cubes))} tetrahedra, 64-atom samples, orientation seed {w.seed}); a piston on z = 0 moves "
             f"at {w.piston_m_s:g} m/s from t = 0 (held). Velocity Verlet on the vertices, no damping. Front = where the "
             "section-averaged velocity reaches half the piston's; speed = least-squares slope of station position "
             f"against arrival time over {w.fit_range[0]:g}-{w.fit_range[1]:g} of the length.", "",
             *_crystal_lines(result, spec, b),
             f"E and nu measured on the same potential (static tension, {m.elements} elements, seed {m.seed}): "
             f"E = {m.youngs_modulus_GPa:.2f} GPa, nu = {m.poisson_ratio:.4f}; the speeds they imply are the "
             "'from measured E, nu' column.", "",
             "| wave | sides | speed (m/s) | reference (seed 003) | error | from measured E, nu | error | Reuss - Voigt "
             "| macro steps | wall (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for j in jobs:
        ref, pred, v = REFERENCE[WAVE_KEY[j.experiment]], m.of(j.experiment), j.speed_m_s
        lines.append(f"| {j.experiment} | {j.lateral} | {v:.0f} +- {j.speed_stderr_m_s:.0f} | {ref:.0f} | "
                     f"{100 * (v - ref) / ref:+.2f} % | {pred:.0f} | {100 * (v - pred) / pred:+.2f} % | "
                     f"{b.reuss.of(j.experiment):.0f} - {b.voigt.of(j.experiment):.0f} | {j.macro_steps} | {j.wall_s:.1f} |")
    lines += ["", "The references are measured polycrystalline silicon; the speeds the potential can give are bounded by "
              "its Reuss and Voigt averages.", "", "![wavefront](wavefront.png)", "", "![profiles](profiles.png)", "",
              "![mesh](mesh.png)", "", f"Wall time {result.wall_s:.1f} s on this machine. opalflow {__version__}."]
    return "\n".join(lines) + "\n"
