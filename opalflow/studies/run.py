"""The studies of Dosta et al. (seed 000) as sweeps of compression jobs.

``kind = "study"`` workflows name a study type and a base workflow; every job is the base with a few values set
(:func:`opalflow.studies.sweep.job_spec`), run through :mod:`opalflow.studies.sweep` (parallel, cached by spec
hash).  Each study type is three steps (:data:`opalflow.studies.spec.STUDY_TYPES`): ``jobs(spec)`` -> the
:class:`opalflow.runs.jobs.Job` list, ``analyse(spec, jobs, results)`` -> its result dataclass (None where too
few jobs finished), ``render(spec, result, out)`` -> report.md's lines (and the figures they show); the Newton
calibration, whose later jobs depend on the earlier results, ``iterate(spec, out, say)`` instead of the first two.
:func:`run` writes the result as summary.json and the lines as report.md into the study folder, every result
beside the paper's number and the wall time it cost.  ``study.paper_scale = true`` swaps the coarse base for the
paper's (``study.paper_base``).
"""
from __future__ import annotations

import dataclasses
import math
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.analysis import fracture
from opalflow.analysis.fits import Fit, fit_exponential, fit_power, fit_power_law
from opalflow.bpm.facts import SampleFacts
from opalflow.bpm.methods import METHODS
from opalflow.materials import material
from opalflow.registry import resolve
from opalflow.resources import DATA, resource
from opalflow.runs.record import RunRecord, finish
from opalflow.runs.result import Result, optional, table_of
from opalflow.spec import SpecError
from opalflow.store import new_figure, save_figure
from opalflow.studies.spec import STUDY_TYPES, StudyWorkflow
from opalflow.studies.sweep import Job, failed_jobs, fmt_value, job_spec, label_number, study_set, sweep
from opalflow.version import __version__


@dataclass
class PaperCalibration:
    bond_E_GPa: float
    bond_strength_MPa: float
    experiment_E_GPa: float
    experiment_E_std_GPa: float
    experiment_strength_MPa: float
    experiment_strength_std_MPa: float


@dataclass
class PaperBulk:
    E_macro_GPa: float
    K_E: float
    strength_MPa: float


@dataclass
class PaperCoated:
    youngs_modulus_GPa: float
    strength_MPa: float
    density_kg_m3: float


@dataclass
class PaperCoating:
    E_exp_GPa: dict[str, list[float]]         # by thickness label: mean and standard deviation
    coated20: PaperCoated


@dataclass
class PaperPorosity:
    b_E: float
    m: float
    E0_GPa: float
    sigma0_MPa: float
    b_strength: float


@dataclass
class Paper:
    """The numbers of Dosta et al. the studies compare with (data/reference/dosta2022.toml: each with its section
    and table there)."""

    structure: dict
    tolerance: dict
    calibration: PaperCalibration
    bulk: PaperBulk
    coating: PaperCoating
    porosity: PaperPorosity


def paper() -> Paper:
    """Reference numbers of Dosta et al. (data/reference/dosta2022.toml)."""
    raw = tomllib.loads(resource(DATA / "reference", "dosta2022.toml").read_text())
    coating = raw.pop("coating")
    return Paper(raw.pop("structure"), raw.pop("tolerance"), PaperCalibration(**raw.pop("calibration")),
                 PaperBulk(**raw.pop("bulk")), PaperCoating(coating["E_exp_GPa"], PaperCoated(**coating["coated20"])),
                 PaperPorosity(**raw.pop("porosity")))


# ----------------------------------------------------------------------------- calibration
@dataclass
class CalibrationPoint:
    """A finite-difference point of eq. 19 beside an iterate."""

    bond_E_GPa: float
    bond_strength_MPa: float
    youngs_modulus_GPa: float
    strength_MPa: float


@dataclass
class CalibrationStep:
    """One iterate of eq. 18: the bond parameters, what they gave and their errors against the targets."""

    iteration: int
    bond_E_GPa: float
    bond_strength_MPa: float
    youngs_modulus_GPa: float
    strength_MPa: float
    error_E: float
    error_strength: float
    dem_runs: int
    fd_points: list[CalibrationPoint]
    wall_s: float


@dataclass
class Calibration:
    """The calibration's result: the last iterate, whether it met the tolerance, and every step."""

    youngs_modulus_GPa: float
    strength_MPa: float
    dem_runs: int
    bond_E_GPa: float
    bond_strength_MPa: float
    converged: bool
    history: list[CalibrationStep]
    jacobian: str
    targets: dict
    headline: str


def _calibration_start(spec: StudyWorkflow) -> np.ndarray:
    """Bond E_b and strength where the iteration starts (the study's, else the material's)."""
    base = job_spec(spec)
    silica = material(base.material, base.materials)
    return np.array([spec.study.start_E_GPa or silica.bond_youngs_modulus_GPa,
                     spec.study.start_strength_MPa or silica.bond_strength_MPa])


def _fd_points(spec: StudyWorkflow, x: np.ndarray) -> list[np.ndarray]:
    """The finite-difference points of eq. 19 beside ``x`` (decoupled: one; full: one per parameter)."""
    h = spec.study.fd_step
    return [x * (1 + h)] if spec.study.jacobian == "decoupled" else [x * np.array([1 + h, 1.0]),
                                                                     x * np.array([1.0, 1 + h])]


def _calibration_job(spec: StudyWorkflow, p) -> Job:
    name = job_spec(spec).material
    return Job(f"Eb{label_number(p[0])}_sb{label_number(p[1])}",
               job_spec(spec, {f"materials.{name}.bond_youngs_modulus_GPa": float(p[0]),
                               f"materials.{name}.bond_strength_MPa": float(p[1])}), at=tuple(map(float, p)))


def calibration_jobs(spec: StudyWorkflow) -> list[Job]:
    """The first iteration's jobs (the start and its finite-difference points); each later one is one job,
    up to ``study.max_runs`` in all."""
    x = _calibration_start(spec)
    return [_calibration_job(spec, p) for p in ([x] + _fd_points(spec, x))[:spec.study.max_runs]]


def _first_jacobian(jacobian: str, x, y, points, values) -> np.ndarray:
    """eq. 19 from the finite-difference points of the first iteration (decoupled: the diagonal from one point
    with both parameters raised; full: one point per parameter)."""
    if jacobian == "decoupled":
        return np.diag((values[1] - y) / (points[1] - x))
    return np.column_stack([(values[1] - y) / (points[1][0] - x[0]), (values[2] - y) / (points[2][1] - x[1])])


def _updated_jacobian(jacobian: str, jac: np.ndarray, x: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """eq. 19 with Delta E_b = the last step ``dx`` to ``x`` (decoupled: each diagonal term where it stays
    positive); Broyden's update of the full Jacobian."""
    if jacobian == "decoupled":
        jac = jac.copy()
        for i in range(2):
            if abs(dx[i]) > 1e-12 * abs(x[i]) and dy[i] / dx[i] > 0:
                jac[i, i] = dy[i] / dx[i]
        return jac
    return jac + np.outer(dy - jac @ dx, dx) / np.dot(dx, dx) if np.dot(dx, dx) > 0 else jac


def calibration(spec: StudyWorkflow, out: Path, say) -> Calibration:
    """Newton iteration on bond E_b and strength (eqs. 18-19) to E* and sigma*.

    Iteration 1 runs the start point and, at the same time, the finite-difference point(s) of
    eq. 19 (decoupled: E_b and sigma_b both raised by ``fd_step``, dE/dE_b and dsigma/dsigma_b read
    from the one run, as the paper does; full: one run per parameter, the 2x2 Jacobian).  Later
    iterations take the derivative from the last two iterates (eq. 19 with Delta E_b = the last
    step; Broyden's update for the full Jacobian), so each costs one DEM run.
    """
    st = spec.study
    x = _calibration_start(spec)
    target = np.array([st.target_E_GPa, st.target_strength_MPa])
    history, runs, jac, prev, converged = [], 0, None, None, False
    while runs < st.max_runs:
        points = ([x.copy()] + (_fd_points(spec, x) if jac is None else []))[:st.max_runs - runs]
        jobs = [_calibration_job(spec, p) for p in points]
        results = sweep(spec, out, jobs, say)
        if len(results) < len(jobs):
            bad = {f.label: f.error for f in failed_jobs(out, 0) if f.label in {j.label for j in jobs}}
            raise SpecError("study", spec.name, f"calibration run failed: {bad}; see {out}/jobs")
        runs += len(points)
        values = [np.array([r.youngs_modulus_GPa, r.strength_MPa]) for r in results.values()]
        y = values[0]
        err = (y - target) / target
        history.append(CalibrationStep(
            len(history) + 1, x[0], x[1], y[0], y[1], err[0], err[1], runs,
            [CalibrationPoint(p[0], p[1], v[0], v[1]) for p, v in zip(points[1:], values[1:])],
            sum(r.wall_s or 0.0 for r in results.values())))
        say(f"calibration iteration {len(history)}: E_b = {x[0]:.4g} GPa, sigma_b = {x[1]:.4g} MPa -> "
            f"E = {y[0]:.4g} GPa ({100 * err[0]:+.2f} %), strength = {y[1]:.4g} MPa ({100 * err[1]:+.2f} %), "
            f"{runs} runs")
        if np.all(np.abs(err) <= st.tolerance):
            converged = True
            break
        if jac is None:
            if len(values) < 1 + (1 if st.jacobian == "decoupled" else 2):
                break
            jac = _first_jacobian(st.jacobian, x, y, points, values)
        else:
            jac = _updated_jacobian(st.jacobian, jac, x, x - prev[0], y - prev[1])
        prev = (x.copy(), y.copy())
        x = x + np.linalg.solve(jac, target - y)          # eq. 18
        x = np.maximum(x, 0.05 * prev[0])                 # a step never makes a bond parameter vanish
    last = history[-1]
    return Calibration(
        last.youngs_modulus_GPa, last.strength_MPa, runs, last.bond_E_GPa, last.bond_strength_MPa, converged, history,
        st.jacobian, {"youngs_modulus_GPa": st.target_E_GPa, "strength_MPa": st.target_strength_MPa},
        f"{'converged' if converged else 'NOT converged'} in {runs} DEM runs: E_b = {last.bond_E_GPa:.4g} GPa, "
        f"sigma_b = {last.bond_strength_MPa:.4g} MPa -> E = {last.youngs_modulus_GPa:.4g} GPa, strength = "
        f"{last.strength_MPa:.4g} MPa")


def calibration_render(spec: StudyWorkflow, cal: Calibration, out: Path) -> list[str]:
    st = spec.study
    ref = paper().calibration
    lines = [f"Targets E* = {st.target_E_GPa} GPa, sigma* = {st.target_strength_MPa} MPa (do Rosario et al., "
             f"via Dosta et al. section 3.1), tolerance {100 * st.tolerance:g} %, {st.jacobian} derivative, "
             f"finite-difference step {100 * st.fd_step:g} %.", "",
             "| iteration | E_b (GPa) | sigma_b (MPa) | E (GPa) | error | strength (MPa) | error | DEM runs | "
             "job wall (s) |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {h.iteration} | {h.bond_E_GPa:.5g} | {h.bond_strength_MPa:.5g} | {h.youngs_modulus_GPa:.4g} | "
              f"{100 * h.error_E:+.2f} % | {h.strength_MPa:.4g} | {100 * h.error_strength:+.2f} % | {h.dem_runs} | "
              f"{h.wall_s:.0f} |" for h in cal.history]
    return lines + ["", cal.headline + ".", "",
                    f"The paper's calibration at d = 15 nm and 8.05 um^2: E_b = {ref.bond_E_GPa} GPa, "
                    f"sigma_b = {ref.bond_strength_MPa} MPa (E = 1.7 GPa, strength 41.1 MPa). "
                    f"Here E_b / paper = {cal.bond_E_GPa / ref.bond_E_GPa:.2f} and sigma_b / paper = "
                    f"{cal.bond_strength_MPa / ref.bond_strength_MPa:.2f}: the bond parameters that give the "
                    "experiment depend on the resolution (see the convergence study)."]


# ----------------------------------------------------------------------------- K_E
@dataclass
class BulkRow:
    """A pore-free sample at one diameter: its moduli (top layer, plate), K_E of each, and what broke."""

    diameter_nm: float
    E_macro_GPa: float
    K_E: float
    E_plate_GPa: float
    K_E_plate: float
    strength_MPa: float | None
    strain_at_peak: float | None
    broken_bonds: int | None
    n_particles: int
    wall_s: float


@dataclass
class Bulk:
    """K_E at the finest diameter, every diameter's row (by its label) and the titania bond moduli it implies."""

    K_E: float
    by_diameter: dict[str, BulkRow]
    titania_bond_E_GPa: dict
    headline: str


def bulk_jobs(spec: StudyWorkflow) -> list[Job]:
    """A pore-free sample at each diameter."""
    return [Job(f"bulk_d{label_number(d)}", job_spec(spec, {"pores.arrangement": "none", "packing.diameter_nm": d}),
                at=(d,)) for d in spec.study.diameters_nm]


def bulk_analyse(spec: StudyWorkflow, jobs: list[Job], results: dict) -> Bulk | None:
    """K_E = E_macro / E_b (eq. 20) from pore-free samples at each particle diameter."""
    rows = {}
    for job in jobs:
        if job.label in results:
            r, (d,) = results[job.label], job.at
            e_b = material(job.spec.material, job.spec.materials).bond_youngs_modulus_GPa
            rows[label_number(d)] = BulkRow(d, r.youngs_modulus_specimen_GPa, r.youngs_modulus_specimen_GPa / e_b,
                                            r.youngs_modulus_GPa, r.youngs_modulus_GPa / e_b, r.strength_MPa,
                                            r.strain_at_peak, r.broken_bonds, r.n_particles, r.wall_s)
    if not rows:
        return None
    ref = paper()
    finest = min(rows.values(), key=lambda row: row.diameter_nm)
    titania = {k: {"E_exp_GPa": v[0], "E_b_GPa": v[0] / finest.K_E, "E_b_paper_GPa": v[0] / ref.bulk.K_E}
               for k, v in ref.coating.E_exp_GPa.items()}
    return Bulk(finest.K_E, rows, titania, "K_E = " + ", ".join(f"{v.K_E:.3f} (d = {k} nm)" for k, v in rows.items())
                + f"; paper {ref.bulk.K_E}")


def bulk_render(spec: StudyWorkflow, bulk: Bulk, out: Path) -> list[str]:
    ref = paper().bulk
    how = ("By the static solver (compression.method = static): E_macro is the top layer's modulus at zero "
           "loading rate, the same in both columns (no plate); no strength." if not METHODS[spec.study.method].strength
           else "The plate-strain modulus beside it also holds the Hertz settling of the plate on the rough top, "
           "which dominates in a short stiff block.")
    rows = [f"| {r.diameter_nm:g} | {r.n_particles} | {r.E_macro_GPa:.3f} | {r.K_E:.3f} | {r.E_plate_GPa:.3f} | "
            f"{fmt_value(r.strength_MPa, '.1f')} | {fmt_value(r.strain_at_peak, '.4f')} | "
            f"{fmt_value(r.broken_bonds, 'd')} | {r.wall_s:.0f} |" for r in bulk.by_diameter.values()]
    lines = ["Pore-free silica (`pores.arrangement = none`), compressed like the opal; K_E = E_macro / E_b "
             "(eq. 20) with E_macro from the top particle layer's strain (the sample's own modulus). " + how, "",
             "| d (nm) | particles | E_macro (GPa) | K_E | E from plate strain (GPa) | strength (MPa) | "
             "strain at peak | broken bonds | wall (s) |",
             "|---|---|---|---|---|---|---|---|---|", *rows, "",
             *(["No bond broke in the samples marked 0: their 'strength' is the stress at the last strain, not a "
                "peak (bpm/rotational breaks bonds in tension and shear; a confined pore-free block sees little).",
                ""] if any(r.broken_bonds == 0 for r in bulk.by_diameter.values()) else []),
             f"Paper (d = 15 nm): E_macro = {ref.E_macro_GPa} GPa, K_E = {ref.K_E}, bulk strength "
             f"{ref.strength_MPa} MPa.", "",
             "Titania bond moduli E_b = E_exp / K_E with the finest K_E here (the paper's in brackets):", "",
             "| coating | E_exp (GPa) | E_b (GPa) | paper E_b (GPa) |", "|---|---|---|---|"]
    return lines + [f"| {k} nm | {v['E_exp_GPa']:g} | {v['E_b_GPa']:.2f} | {v['E_b_paper_GPa']:.2f} |"
                    for k, v in bulk.titania_bond_E_GPa.items()]


# ----------------------------------------------------------------------------- coating
@dataclass
class CoatingRow:
    """One coating run: thickness, which E_exp (low, mean, high or uncoated), the titania bond E it gave."""

    thickness_nm: float
    case: str
    E_exp_GPa: float | None
    bond_E_GPa: float | None
    youngs_modulus_GPa: float
    strength_MPa: float | None
    n_particles: int
    wall_s: float
    strength_vs_uncoated: float | None = None


@dataclass
class Coating:
    table: list[CoatingRow]
    headline: str
    strength_rises_with_thickness: bool | None = optional()     # None: no strength (a static study)


def coating_jobs(spec: StudyWorkflow) -> list[Job]:
    """The uncoated sample (thickness 0) and each coating at E_exp - std, E_exp, E_exp + std (``at``: thickness,
    case, E_exp)."""
    ref = paper()
    k_e = ref.bulk.K_E
    jobs = []
    for t in spec.study.thicknesses_nm:
        if t == 0:
            jobs.append(Job("coat0", job_spec(spec, {"coating.thickness_nm": 0.0}), at=(t, "uncoated", None)))
            continue
        key = label_number(t)
        if key not in ref.coating.E_exp_GPa:
            raise SpecError("study.thicknesses_nm", t, f"no E_exp for it; the paper gives "
                            f"{', '.join(ref.coating.E_exp_GPa)} nm")
        mean, std = ref.coating.E_exp_GPa[key]
        for case, e_exp in (("low", mean - std), ("mean", mean), ("high", mean + std)):
            jobs.append(Job(f"coat{key}_{case}", job_spec(spec, {
                "coating.thickness_nm": float(t), "materials.titania.bond_youngs_modulus_GPa": e_exp / k_e}),
                at=(t, case, e_exp)))
    return jobs


def coating_analyse(spec: StudyWorkflow, jobs: list[Job], results: dict) -> Coating | None:
    """Coatings of each thickness at E_exp - std, E_exp, E_exp + std (E_b = E_exp / K_E, K_E = 3.35)."""
    k_e = paper().bulk.K_E
    table = []
    for job in jobs:
        if job.label in results:
            (t, case, e_exp), r = job.at, results[job.label]
            table.append(CoatingRow(t, case, e_exp, None if e_exp is None else e_exp / k_e, r.youngs_modulus_GPa,
                                    r.strength_MPa, r.n_particles, r.wall_s))
    if not table:
        return None
    uncoated = next((r.strength_MPa for r in table if r.case == "uncoated"), None)
    for r in table:           # each coating's strength against the uncoated sample's (Fig. 9)
        r.strength_vs_uncoated = r.strength_MPa / uncoated if uncoated and r.strength_MPa else None
    means = [r for r in table if r.case in ("uncoated", "mean")]
    if not METHODS[spec.study.method].strength:
        return Coating(table, "E at E_exp (static): " + ", ".join(
            f"{r.thickness_nm:g} nm {r.youngs_modulus_GPa:.3g} GPa" for r in means))
    rising = all(b.strength_MPa > a.strength_MPa for a, b in zip(means, means[1:]))
    return Coating(table, "strength at E_exp: " + ", ".join(
        f"{r.thickness_nm:g} nm {r.strength_MPa:.3g} MPa{_times_uncoated(r)}" for r in means)
        + f" ({'rises' if rising else 'does NOT rise'} with thickness)", rising)


def coating_render(spec: StudyWorkflow, coating: Coating, out: Path) -> list[str]:
    ref = paper()
    paper20 = ref.coating.coated20
    _plot_coating(coating.table, out / "coating.png")
    lines = [f"E_b(titania) = E_exp / K_E with the paper's K_E = {ref.bulk.K_E}; E_exp of Colombi et al. "
             "(Table 1).", "",
             "| coating (nm) | E_exp case | E_exp (GPa) | titania E_b (GPa) | E (GPa) | strength (MPa) | vs uncoated "
             "| wall (s) |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r.thickness_nm:g} | {r.case} | {_blank(r.E_exp_GPa)} | {_blank(r.bond_E_GPa)} | "
              f"{r.youngs_modulus_GPa:.3g} | {fmt_value(r.strength_MPa, '.3g')} | "
              f"{fmt_value(r.strength_vs_uncoated, '.3f')} | {r.wall_s:.0f} |" for r in coating.table]
    return lines + ["", f"Paper (d = 15 nm, 8.05 um^2): uncoated E = 1.7 GPa, strength 41.1 MPa; 20 nm coated "
                    f"E = {paper20.youngs_modulus_GPa} GPa, strength {paper20.strength_MPa} MPa "
                    f"(density {paper20.density_kg_m3} kg/m^3); the 34 nm strength within 2.2 % of experiment.",
                    "", coating.headline + ".", "", "![coating](coating.png)"]


def _blank(v) -> str:
    return "" if v is None else f"{v:.3g}"


def _times_uncoated(r: CoatingRow) -> str:
    """The headline's " (x 8.28)": a coating's strength against the uncoated sample's (mean E_exp only)."""
    return f" (x {r.strength_vs_uncoated:.2f})" if r.case == "mean" and r.strength_vs_uncoated else ""


def _plot_coating(table: list[CoatingRow], path: Path) -> None:
    fig, axes = new_figure(1, 2, figsize=(9, 3.6))
    for ax, key, label in ((axes[0], "youngs_modulus_GPa", "E (GPa)"), (axes[1], "strength_MPa", "strength (MPa)")):
        for case, marker in (("low", "v"), ("mean", "o"), ("high", "^"), ("uncoated", "s")):
            pts = [(r.thickness_nm, getattr(r, key)) for r in table if r.case == case and getattr(r, key) is not None]
            if pts:
                ax.plot(*zip(*pts), marker, label=f"E_exp {case}" if case != "uncoated" else "uncoated")
        ax.set_xlabel("TiO2 coating (nm)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    save_figure(fig, path)


# ----------------------------------------------------------------------------- porosity
@dataclass
class PorosityRun:
    target_porosity: float
    seed: int
    porosity: float
    density_kg_m3: float
    youngs_modulus_GPa: float
    strength_MPa: float | None
    wall_s: float


@dataclass
class Porosity:
    """The runs and the fits of eqs. 22, 23 and 26 (the strength's where the jobs have one)."""

    runs: list[PorosityRun]
    fits: dict[str, Fit]
    E_better_law: str
    paper: PaperPorosity
    headline: str


def porosity_jobs(spec: StudyWorkflow) -> list[Job]:
    """Random pores at each porosity x seed (``at``: porosity, seed), the particles ``study.diameter_nm`` across where
    it is set."""
    st = spec.study
    size = {"packing.diameter_nm": st.diameter_nm} if st.diameter_nm else {}
    return [Job(f"p{label_number(p)}_s{s}", job_spec(spec, {"pores.arrangement": "random", "pores.porosity": p,
                                                          "pores.seed": s, "packing.seed": s, **size}), at=(p, s))
            for p in st.porosities for s in st.seeds]


def porosity_fits(porosity, E_GPa, strength_MPa=None) -> dict[str, Fit]:
    """Eqs. 22 and 23 (E) and 26 (strength, where given) fitted with 95 % intervals."""
    eps, e = np.asarray(porosity, float), np.asarray(E_GPa, float)
    fits = {"E_exponential": fit_exponential(eps, e), "E_power": fit_power(eps, e)}
    if strength_MPa is not None:
        fits["strength_exponential"] = fit_exponential(eps, np.asarray(strength_MPa, float))
    return fits


def porosity_analyse(spec: StudyWorkflow, jobs: list[Job], results: dict) -> Porosity | None:
    """Random pores at each porosity x seed -> fits of eqs. 22, 23, 26 with 95 % intervals (three runs at least)."""
    runs = [PorosityRun(*job.at, r.porosity, r.density_kg_m3, r.youngs_modulus_GPa, r.strength_MPa, r.wall_s)
            for job in jobs if (r := results.get(job.label)) is not None]
    if len(runs) < 3:
        return None
    fits = porosity_fits([r.porosity for r in runs], [r.youngs_modulus_GPa for r in runs],
                         # dynamic or quasi-static: a strength per job
                         [r.strength_MPa for r in runs] if METHODS[spec.study.method].strength else None)
    better = "power" if fits["E_power"].r2 > fits["E_exponential"].r2 else "exponential"
    sigma = (f", b_sigma = {fits['strength_exponential'].exponent:.2f}, sigma0 = "
             f"{fits['strength_exponential'].prefactor:.4g} MPa" if "strength_exponential" in fits else " (static)")
    return Porosity(runs, fits, better, paper().porosity,
                    f"b_E = {fits['E_exponential'].exponent:.2f}, m = {fits['E_power'].exponent:.2f}{sigma}; "
                    f"E better fitted by the {better} law")


def porosity_render(spec: StudyWorkflow, study: Porosity, out: Path) -> list[str]:
    ref, fits = study.paper, study.fits
    _plot_porosity(study.runs, fits, out / "porosity.png")
    lines = ["Random non-overlapping pores, seeds " + ", ".join(map(str, spec.study.seeds)) + " at each porosity "
             "(`pores.seed` and `packing.seed`). Porosity = the sample's measured macro-porosity.", "",
             "| law | parameter | fitted | 95 % interval | paper | prefactor | 95 % interval | paper | R^2 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, name, pname, ref_exp, ref_pre in (
            ("E_exponential", "E = E0 exp(-b eps) (22)", "b", ref.b_E, ref.E0_GPa),
            ("E_power", "E = E0 (1 - eps)^m (23)", "m", ref.m, ref.E0_GPa),
            ("strength_exponential", "sigma = sigma0 exp(-b eps) (26)", "b", ref.b_strength, ref.sigma0_MPa)):
        if key in fits:
            f = fits[key]
            lines.append(f"| {name} | {pname} | {f.exponent:.3f} | [{f.exponent_ci[0]:.3f}, {f.exponent_ci[1]:.3f}] | "
                         f"{ref_exp} | {f.prefactor:.4g} | [{f.prefactor_ci[0]:.4g}, {f.prefactor_ci[1]:.4g}] | "
                         f"{ref_pre} | {f.r2:.4f} |")
    lines += ["", f"E is fitted better by the {study.E_better_law} law (R^2 on the values); the paper found the power "
              "law (eq. 25) far better than the exponential.", "",
              "| target porosity | seed | porosity | density (kg/m^3) | E (GPa) | strength (MPa) | wall (s) |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {r.target_porosity:g} | {r.seed} | {r.porosity:.4f} | {r.density_kg_m3:.0f} | "
              f"{r.youngs_modulus_GPa:.4g} | {fmt_value(r.strength_MPa, '.4g')} | {r.wall_s:.0f} |" for r in study.runs]
    return lines + ["", "![porosity](porosity.png)"]


def _plot_porosity(runs: list[PorosityRun], fits: dict[str, Fit], path: Path) -> None:
    fig, axes = new_figure(1, 3, figsize=(13, 3.8))
    eps = np.array([r.porosity for r in runs])
    grid = np.linspace(eps.min(), eps.max(), 100)
    axes[0].plot(eps, [r.youngs_modulus_GPa for r in runs], "o", label="runs")
    for key, style in (("E_exponential", "--"), ("E_power", "-")):
        f = fits[key]
        y = f.prefactor * (np.exp(-f.exponent * grid) if f.law == "exponential" else (1 - grid) ** f.exponent)
        axes[0].plot(grid, y, style, label=f"{f.law}: {f.exponent:.2f}")
    dens = [r.density_kg_m3 for r in runs]
    axes[2].plot(dens, [r.youngs_modulus_GPa for r in runs], "o", label="E (GPa)")
    if "strength_exponential" in fits:
        f = fits["strength_exponential"]
        axes[1].plot(eps, [r.strength_MPa for r in runs], "o")
        axes[1].plot(grid, f.prefactor * np.exp(-f.exponent * grid), "--", label=f"exponential: {f.exponent:.2f}")
        ax2 = axes[2].twinx()
        ax2.plot(dens, [r.strength_MPa for r in runs], "s", color="C3")
        ax2.set_ylabel("strength (MPa)", color="C3")
    else:
        axes[1].set_title("no strength (static solves)")
    axes[0].set_ylabel("E (GPa)")
    axes[1].set_ylabel("strength (MPa)")
    for ax in axes[:2]:
        ax.set_xlabel("porosity")
        if ax.get_legend_handles_labels()[0]:      # no strength panel legend for static solves
            ax.legend(fontsize=8)
    axes[2].set_xlabel("density (kg/m^3)")
    axes[2].set_ylabel("E (GPa)")
    save_figure(fig, path)


# ----------------------------------------------------------------------------- convergence
@dataclass
class ConvergenceRun:
    seed: int
    youngs_modulus_GPa: float
    strength_MPa: float                  # nan where the job has none (a static study)
    wall_s: float
    n_particles: int
    n_bonds: int
    area_um2: float


@dataclass
class ConvergenceRow:
    """One setting (cells, diameter): the mean and spread over its seeds, the errors against the finest setting
    of each axis it belongs to (None: not on that axis; a strength error is None where there is no strength)."""

    cells: list[int]
    diameter_nm: float
    area_um2: float
    n_particles: float
    E_mean_GPa: float
    E_std_GPa: float
    strength_mean_MPa: float | None
    strength_std_MPa: float | None
    wall_s_mean: float
    seeds: int
    error_E_vs_finest_cells: float | None = optional()
    error_strength_vs_finest_cells: float | None = None
    error_E_vs_finest_diameter: float | None = optional()
    error_strength_vs_finest_diameter: float | None = None

    def error(self, what: str, axis: str) -> float | None:
        """``error_{what}_vs_finest_{axis}``: E or strength against the finest setting of the axis."""
        return getattr(self, f"error_{what}_vs_finest_{axis}")


@dataclass
class Convergence:
    rows: list[ConvergenceRow]
    cost_law: dict[str, Fit]
    paper_scale_wall_s_estimate: float | None
    headline: str


def convergence_jobs(spec: StudyWorkflow) -> list[Job]:
    """Cross-sections (cells) x seeds at the base diameter, diameters x seeds at the base cell count (``at``:
    cells, diameter, seed)."""
    st = spec.study
    base = job_spec(spec)
    d0 = base.packing.diameter_nm
    c0 = [base.pores.cells_x, base.pores.cells_y]
    settings = [("cells", tuple(c), d0) for c in st.cells] + [("diameter", tuple(c0), d) for d in st.diameters_nm]
    jobs = {}
    for axis, cells, d in settings:
        for s in st.seeds:
            label = f"c{cells[0]}x{cells[1]}_d{label_number(d)}_s{s}"
            jobs.setdefault(label, Job(label, job_spec(spec, {
                "pores.cells_x": cells[0], "pores.cells_y": cells[1], "packing.diameter_nm": d, "packing.seed": s}),
                at=(cells, d, s)))
    return list(jobs.values())


def _convergence_row(cells, d: float, runs: list[ConvergenceRun]) -> ConvergenceRow:
    e = np.array([r.youngs_modulus_GPa for r in runs])
    sg = np.array([r.strength_MPa for r in runs], float)
    has_strength = bool(np.all(np.isfinite(sg)))
    return ConvergenceRow(
        list(cells), d, runs[0].area_um2, float(np.mean([r.n_particles for r in runs])), float(e.mean()),
        float(e.std(ddof=1)) if len(e) > 1 else 0.0, float(sg.mean()) if has_strength else None,
        (float(sg.std(ddof=1)) if len(sg) > 1 else 0.0) if has_strength else None,
        float(np.mean([r.wall_s for r in runs])), len(runs))


def convergence_analyse(spec: StudyWorkflow, jobs: list[Job], results: dict) -> Convergence | None:
    """Cross-section (cells) x seeds at the base diameter, and diameters x seeds at the base cell count: each
    setting's mean against the finest of its axis (largest cross-section; smallest diameter), and the cost laws."""
    base = job_spec(spec)
    d0, c0 = base.packing.diameter_nm, [base.pores.cells_x, base.pores.cells_y]
    by_setting: dict[tuple, list[ConvergenceRun]] = {}
    for job in jobs:
        if (r := results.get(job.label)) is not None:
            cells, d, s = job.at
            by_setting.setdefault((cells, d), []).append(ConvergenceRun(
                s, r.youngs_modulus_GPa, math.nan if r.strength_MPa is None else r.strength_MPa, r.wall_s,
                r.n_particles, r.n_bonds, cells[0] * cells[1] * base.pores.spacing_nm ** 2 * math.sqrt(3) * 1e-6))
    rows = [_convergence_row(cells, d, runs) for (cells, d), runs in by_setting.items()]
    axes = {"cells": ([r for r in rows if r.diameter_nm == d0], lambda r: r.area_um2),
            "diameter": ([r for r in rows if r.cells == c0], lambda r: -r.diameter_nm)}
    if not all(members for members, _ in axes.values()):
        return None
    for axis, (members, pick) in axes.items():
        finest = max(members, key=pick)
        for r in members:
            setattr(r, f"error_E_vs_finest_{axis}", r.E_mean_GPa / finest.E_mean_GPa - 1)
            setattr(r, f"error_strength_vs_finest_{axis}", r.strength_mean_MPa / finest.strength_mean_MPa - 1
                    if r.strength_mean_MPa is not None else None)
    size_rows, diam_rows = _axis_rows(rows, d0, c0)
    cost = {}
    if len(size_rows) >= 2:
        cost["particles"] = fit_power_law([r.n_particles for r in size_rows], [r.wall_s_mean for r in size_rows])
    if len(diam_rows) >= 2:
        cost["diameter"] = fit_power_law([r.diameter_nm for r in diam_rows], [r.wall_s_mean for r in diam_rows])
    extrapolated = None
    if "diameter" in cost:
        # t = t_ref (A / A_ref) (d / d_ref)^k: time grows with the cross-section at fixed d (measured
        # exponent on particles, ~1) and as d^k at fixed area
        ref_row = diam_rows[-1]
        alpha = cost["particles"].exponent if "particles" in cost else 1.0
        structure = paper().structure
        extrapolated = (ref_row.wall_s_mean * (structure["sample_area_um2"] / ref_row.area_um2) ** alpha
                        * (structure["particle_diameter_nm"] / ref_row.diameter_nm) ** cost["diameter"].exponent)
    return Convergence(rows, cost, extrapolated,
                       (f"cost exponent for d: {cost['diameter'].exponent:.2f}" if "diameter" in cost else "")
                       + (f"; paper-scale run here ~{extrapolated / 86400:.1f} days" if extrapolated else ""))


def _axis_rows(rows: list[ConvergenceRow], d0: float, c0: list[int]) -> tuple[list, list]:
    """The cross-section axis (at the base diameter, by area) and the diameter axis (at the base cells, coarse to
    fine)."""
    return (sorted([r for r in rows if r.diameter_nm == d0], key=lambda r: r.area_um2),
            sorted([r for r in rows if r.cells == c0], key=lambda r: -r.diameter_nm))


def convergence_render(spec: StudyWorkflow, conv: Convergence, out: Path) -> list[str]:
    base = job_spec(spec)
    size_rows, diam_rows = _axis_rows(conv.rows, base.packing.diameter_nm, [base.pores.cells_x, base.pores.cells_y])
    _plot_convergence(conv.rows, out / "work_precision.png")
    lines = ["Every setting with seeds " + ", ".join(map(str, spec.study.seeds)) + "; errors against the finest "
             "setting of the same axis (largest cross-section at the base diameter; smallest diameter at the base "
             "cross-section).", "",
             "| axis | cells | d (nm) | area (um^2) | particles | E (GPa) | E spread | error E | strength (MPa) | "
             "strength spread | error strength | wall (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for axis, r in [("cells", r) for r in size_rows] + [("diameter", r) for r in diam_rows]:
        error = r.error("strength", axis)
        lines.append(f"| {axis} | {r.cells[0]}x{r.cells[1]} | {r.diameter_nm:g} | {r.area_um2:.2f} | "
                     f"{r.n_particles:.0f} | {r.E_mean_GPa:.4g} | {r.E_std_GPa:.2g} | "
                     f"{100 * r.error('E', axis):+.1f} % | "
                     f"{fmt_value(r.strength_mean_MPa, '.4g')} | {fmt_value(r.strength_std_MPa, '.2g')} | "
                     f"{fmt_value(error and 100 * error, '+.1f')} % | {r.wall_s_mean:.0f} |")
    for name, c in conv.cost_law.items():
        lines += ["", f"Cost law against {name}: wall = {c.prefactor:.3g} x {name}^{c.exponent:.2f} "
                  f"(95 % interval of the exponent [{c.exponent_ci[0]:.2f}, {c.exponent_ci[1]:.2f}])."]
    if conv.paper_scale_wall_s_estimate:
        wall = conv.paper_scale_wall_s_estimate
        lines += ["", f"Paper-scale run (d = 15 nm, 8.05 um^2) extrapolated on this machine: "
                  f"{wall:.3g} s = {wall / 86400:.2f} days on one core."]
    return lines + ["", "Paper: above 4 um^2 the cross-section changes E by < 0.12 % and strength by < 4 %.", "",
                    "![work-precision](work_precision.png)"]


def _plot_convergence(rows: list[ConvergenceRow], path: Path) -> None:
    fig, ax = new_figure(figsize=(6, 4))
    for axis, marker in (("cells", "o"), ("diameter", "s")):
        pts = [(r.wall_s_mean, abs(r.error("E", axis)) + 1e-4) for r in rows if r.error("E", axis) is not None]
        if pts:
            ax.loglog(*zip(*sorted(pts)), marker + "-", label=f"E error, {axis} axis")
    ax.set_xlabel("wall time per run (s)")
    ax.set_ylabel("|relative error| against the finest (+1e-4)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    save_figure(fig, path)


# ----------------------------------------------------------------------------- side boundaries
@dataclass
class SidesRow:
    youngs_modulus_GPa: float
    youngs_modulus_specimen_GPa: float
    strength_MPa: float | None
    strain_at_peak: float | None
    broken_bonds: int | None
    n_particles: int
    n_bonds: int
    wall_s: float


@dataclass
class Sides:
    table: dict[str, SidesRow]
    open_vs_periodic: dict
    headline: str


def sides_jobs(spec: StudyWorkflow) -> list[Job]:
    """The base with periodic and with open sides."""
    return [Job(f"sides_{how}", job_spec(spec, {"boundary.sides": how}), at=(how,)) for how in ("periodic", "open")]


def sides_analyse(spec: StudyWorkflow, jobs: list[Job], results: dict) -> Sides | None:
    """The base with periodic and with open side boundaries (Dosta et al. section 3.1.3, fracture patterns):
    E, strength and broken bonds of each."""
    table = {job.at[0]: SidesRow(r.youngs_modulus_GPa, r.youngs_modulus_specimen_GPa, r.strength_MPa, r.strain_at_peak,
                                 r.broken_bonds, r.n_particles, r.n_bonds, r.wall_s)
             for job in jobs if (r := results.get(job.label)) is not None}
    if not table:
        return None
    change = {}
    if len(table) == 2 and all(v.strength_MPa and v.youngs_modulus_GPa for v in table.values()):
        change = {k: getattr(table["open"], k) / getattr(table["periodic"], k) - 1
                  for k in ("youngs_modulus_GPa", "strength_MPa")}
    return Sides(table, change, "; ".join(f"{k}: E {v.youngs_modulus_GPa:.4g} GPa, strength "
                                          f"{fmt_value(v.strength_MPa, '.4g')} MPa" for k, v in table.items()))


def sides_render(spec: StudyWorkflow, sides: Sides, out: Path) -> list[str]:
    """The table and where the bonds break (sides.png, from each job's snapshots)."""
    runs = {}
    for job in sides_jobs(spec):
        result = sides.table.get(job.at[0])
        frames = fracture.load_frames(job.folder(out), result.strain_at_peak) if result is not None else []
        if frames:
            sample = SampleFacts.read(RunRecord.read(job.folder(out)))
            runs[f"{job.at[0]} sides"] = (frames, sample.box_nm, sample.mean_diameter_nm)
    if runs:
        fracture.plot_sides(out / "sides.png", runs)
    rows = [f"| {how} | {r.n_particles} | {r.n_bonds} | {r.youngs_modulus_GPa:.4g} | "
            f"{fmt_value(r.strength_MPa, '.4g')} | {fmt_value(r.strain_at_peak, '.4f')} | "
            f"{fmt_value(r.broken_bonds, 'd')} | {r.wall_s:.0f} |" for how, r in sides.table.items()]
    lines = ["The base sample with side boundaries (x, y) periodic, as the paper's main runs, and open: no bonds "
             "across, free side faces (section 3.1.3).", "",
             "| sides | particles | bonds | E (GPa) | strength (MPa) | strain at peak | broken bonds | wall (s) |",
             "|---|---|---|---|---|---|---|---|", *rows, ""]
    change = sides.open_vs_periodic
    if change:
        lines += [f"Open against periodic: E {100 * change['youngs_modulus_GPa']:+.1f} %, strength "
                  f"{100 * change['strength_MPa']:+.1f} % (free faces carry no lateral load: cracks start "
                  "there and the sample is weaker, as in the paper's fracture patterns).", ""]
    if runs:
        lines += ["Where the bonds break (slab through where they broke, particles coloured by broken bonds, "
                  "near the peak and after it):", "", "![sides](sides.png)"]
    return lines


# ----------------------------------------------------------------------------- a study
def jobs(spec: StudyWorkflow) -> list[Job]:
    """The jobs the study runs (its type's ``jobs`` hook: :data:`opalflow.studies.spec.STUDY_TYPES`)."""
    return resolve(STUDY_TYPES[spec.study.type].jobs)(spec)


def study_result(spec: StudyWorkflow, out: Path, say):
    """The study's result dataclass: its jobs run (cached) and analysed, or its own iteration; None where too few
    jobs finished for its analysis."""
    kind = STUDY_TYPES[spec.study.type]
    if kind.iterate:
        return resolve(kind.iterate)(spec, out, say)
    todo = jobs(spec)
    return resolve(kind.analyse)(spec, todo, sweep(spec, out, todo, say))


def run(spec: StudyWorkflow, out: Path, say=print, executor=None) -> Result:
    """Run the study's jobs (cached) through its executor (``executor`` in place of the spec's
    ``[executor]``, as ``--executor``) and write summary.json and report.md."""
    if executor is not None:
        spec = dataclasses.replace(spec, executor=executor)
    t0, started = time.perf_counter(), time.time()
    out.mkdir(parents=True, exist_ok=True)
    result = study_result(spec, out, say)
    failed = failed_jobs(out, started)
    if result is None:       # too few jobs finished for the study's analysis: the failures are the result
        summary, body = {"headline": f"no results: too few jobs finished ({len(failed)} failed)"}, []
    else:
        summary = table_of(result)
        body = resolve(STUDY_TYPES[spec.study.type].render)(spec, result, out)
    summary["failed_jobs"] = {f.label: f.error for f in failed}
    if failed:
        body += ["", "## Failed jobs (left out above; a rerun tries them again)", ""]
        for f in failed:
            body += [f"- `{f.label}`: {f.error} (folder `{f.folder}`)"]
            if f.log_tail:
                body += ["", "  ```", *[f"  {line}" for line in f.log_tail.splitlines()[-8:]], "  ```", ""]
    summary.update({"study": spec.study.type, "wall_s": time.perf_counter() - t0, "opalflow_version": __version__,
                    "executor": spec.executor.type, "spec": spec.to_dict()})
    report = [f"# Study: {spec.study.type} ({spec.name})", "",
              f"Base workflow `{spec.study.paper_base if spec.study.paper_scale else spec.study.base}`"
              + (f" with {', '.join(study_set(spec.study))}" if study_set(spec.study) else "") + "; jobs in `jobs/` (cached by "
              "spec hash: a rerun does only what is missing).", "", *body, "",
              f"Wall time of this command: {summary['wall_s']:.0f} s (jobs already finished cost nothing)."]
    return finish(out, summary, "\n".join(report))
