"""The aerogel studies (Roy and Hossain, seed 002) as sweeps of ``aerogel`` compression jobs.

``aerogel_models``: contact vs parallel bonds x linear vs Hertz-Mindlin contacts on the same aggregates
(one per seed): E and strength with their spread, the stress-strain curves on one plot, the static E of
the parallel-bond network beside the dynamic one, and a quasi-static check (the first combination and
seed again at half the wall speed).

``aerogel_density``: at each solid fraction x seed a static job (E: one linear solve of the slab, glued
like the dynamic run) and a dynamic job (strength; none with ``study.method = "static"``, which makes
larger samples affordable); fits E ~ rho^m and sigma ~ rho^n with 95 % intervals beside Ma et al. (2000)
and silica-aerogel experiments (data/reference/aerogel_literature.toml).
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.analysis.fits import Fit, fit_power_law
from opalflow.bpm.methods import METHODS
from opalflow.bpm.stiffness import EnergyParts
from opalflow.resources import DATA, resource
from opalflow.store import RESULTS, new_figure, save_figure
from opalflow.studies.spec import StudyWorkflow
from opalflow.studies.sweep import Job, fmt_value, job_spec, label_number

COMBINATIONS = (("parallel", "hertz"), ("parallel", "linear"), ("contact", "hertz"), ("contact", "linear"))


@dataclass
class DensityScaling:
    """The literature's density exponents (data/reference/aerogel_literature.toml's ``[density_scaling]``, with
    their sources): E ~ rho^m of DLCA beam networks and of experiments, sigma ~ rho^n of brittle open-cell foams
    and of experiments (the strength exponents absent from a study written before them)."""

    m_dlca_beams: float
    m_dlca_beams_source: str
    m_experiment_low: float
    m_experiment_high: float
    m_experiment_source: str
    n_foam_brittle: float | None = None
    n_foam_source: str = ""
    n_experiment: float | None = None
    n_experiment_source: str = ""


def density_scaling() -> DensityScaling:
    """The literature's density exponents (data/reference/aerogel_literature.toml)."""
    raw = tomllib.loads(resource(DATA / "reference", "aerogel_literature.toml").read_text())
    return DensityScaling(**raw["density_scaling"])


def _curve(out: Path, job: Job) -> tuple[np.ndarray, np.ndarray] | None:
    """Strain and stress of a finished dynamic or quasi-static job (its results.h5; the quasi-static one's
    saw-tooth: each event's stress before and after it, from the origin)."""
    import h5py

    path = job.folder(out) / RESULTS
    if not path.exists():
        return None
    with h5py.File(path, "r") as h:
        if "quasistatic" in h:
            e, before, after = (h[f"quasistatic/{k}"][()] for k in ("strain", "stress_MPa", "stress_after_MPa"))
            return np.r_[0.0, np.repeat(e, 2)], np.r_[0.0, np.column_stack([before, after]).ravel()]
        return h["curve/strain"][()], h["curve/stress_MPa"][()]


def _mean_std(values: list[float]) -> tuple[float, float]:
    v = np.array([x for x in values if x is not None], float)
    return (float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0) if len(v) else (float("nan"), 0.0)


@dataclass
class ModelRow:
    """One bond model x contact law over the seeds: E and strength as mean and standard deviation (kPa)."""

    bonds: str
    contacts: str
    runs: int
    E_kPa: float
    E_std_kPa: float
    strength_kPa: float
    strength_std_kPa: float
    broken_bonds: float
    wall_s: float


@dataclass
class RateCheck:
    """The first combination and seed again at half the wall speed."""

    speed_m_s: float
    E_change: float
    strength_change: float
    quasi_static: bool


@dataclass
class Models:
    rows: list[ModelRow]
    static_E_kPa: float
    static_E_std_kPa: float
    rate_check: RateCheck | None
    headline: str


def aerogel_models_jobs(spec: StudyWorkflow) -> list[Job]:
    """Each bond model x contact law x seed, the static parallel-bond solve per seed and one half-speed twin
    (the rate check)."""
    st = spec.study
    base = job_spec(spec)
    jobs = [Job(f"{bond}_{contact}_s{s}", job_spec(
                spec, {"bonds.model": bond, "contacts.model": contact, "aggregate.seed": s}))
            for bond, contact in COMBINATIONS for s in st.seeds]
    jobs += [Job(f"static_s{s}", job_spec(spec, {"bonds.model": "parallel", "compression.method": "static",
                                                 "aggregate.seed": s})) for s in st.seeds]
    half = base.compression.plate_speed_m_s / 2
    return jobs + [Job("half_speed", job_spec(spec, {
        "bonds.model": "parallel", "contacts.model": "hertz", "aggregate.seed": st.seeds[0],
        "compression.plate_speed_m_s": float(label_number(half))}))]


def aerogel_models_analyse(spec: StudyWorkflow, jobs: list[Job], res: dict) -> Models | None:
    """E and strength of each model over the seeds, the static E of the parallel-bond network, the rate check."""
    st = spec.study
    rows = []
    for bond, contact in COMBINATIONS:
        runs = [res[f"{bond}_{contact}_s{s}"] for s in st.seeds if f"{bond}_{contact}_s{s}" in res]
        E = _mean_std([r.youngs_modulus_GPa * 1e6 for r in runs])
        S = _mean_std([r.strength_MPa * 1e3 for r in runs])
        rows.append(ModelRow(bond, contact, len(runs), E[0], E[1], S[0], S[1],
                             _mean_std([r.broken_bonds for r in runs])[0], float(sum(r.wall_s for r in runs))))
    static = _mean_std([res[f"static_s{s}"].youngs_modulus_GPa * 1e6 for s in st.seeds if f"static_s{s}" in res])
    first, rate = f"parallel_hertz_s{st.seeds[0]}", None
    if first in res and "half_speed" in res:
        e1, e2 = res[first].youngs_modulus_GPa, res["half_speed"].youngs_modulus_GPa
        s1, s2 = res[first].strength_MPa, res["half_speed"].strength_MPa
        rate = RateCheck(job_spec(spec).compression.plate_speed_m_s, e2 / e1 - 1, s2 / s1 - 1, abs(e2 / e1 - 1) < 0.02)
    ph = rows[0]
    return Models(rows, static[0], static[1], rate,
                  f"parallel+hertz E = {ph.E_kPa:.4g} +- {ph.E_std_kPa:.2g} kPa (static {static[0]:.4g}), "
                  f"contact+hertz E = {rows[2].E_kPa:.3g} kPa; half speed changes E by {rate.E_change:+.2%}"
                  if rate else "incomplete")


def aerogel_models_render(spec: StudyWorkflow, models: Models, out: Path) -> list[str]:
    st = spec.study
    jobs = {j.label: j for j in aerogel_models_jobs(spec)}
    _plot_models({(b, c): [x for s in st.seeds if (x := _curve(out, jobs[f"{b}_{c}_s{s}"]))]
                  for b, c in COMBINATIONS}, out / "models.png")
    lines = [f"The same {len(st.seeds)} aggregates (seeds {', '.join(map(str, st.seeds))}) with each bond and "
             "contact model; E (fit of the linear part) and strength (peak stress) as mean +- standard deviation "
             "over the seeds.", "",
             "| bonds | contacts | runs | E (kPa) | strength (kPa) | broken bonds | wall (s) |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r.bonds} | {r.contacts} | {r.runs} | {r.E_kPa:.4g} +- {r.E_std_kPa:.2g} | "
              f"{r.strength_kPa:.4g} +- {r.strength_std_kPa:.2g} | {r.broken_bonds:.0f} | {r.wall_s:.0f} |"
              for r in models.rows]
    lines += ["", f"Static solver (parallel bonds, same glued slab, linear): E = {models.static_E_kPa:.4g} +- "
              f"{models.static_E_std_kPa:.2g} kPa. Contact bonds have no static stiffness: they carry no moment, so a "
              "tree-like network of them is a mechanism held only by its loops and by contacts that form as it folds."]
    rate = models.rate_check
    if rate:
        lines += ["", f"Quasi-static check (parallel + Hertz, seed {st.seeds[0]}): half the wall speed "
                  f"({rate.speed_m_s / 2:g} m/s) changes E by {rate.E_change:+.2%} and the strength by "
                  f"{rate.strength_change:+.2%} ({'quasi-static' if rate.quasi_static else 'NOT quasi-static'}: "
                  "criterion |dE| < 2 %)."]
    return lines + ["", "![stress-strain curves of the four models](models.png)"]


def _plot_models(curves: dict, path: Path) -> None:
    """All four models in kPa, and the contact-bond ones again in Pa (a thousand times softer)."""
    fig, axes = new_figure(1, 2, figsize=(11, 4.2))
    for k, ((bond, contact), runs) in enumerate(curves.items()):
        for n, (strain, stress) in enumerate(runs):
            style = dict(color=f"C{k}", lw=1, alpha=0.8, ls="-" if contact == "hertz" else "--",
                         label=f"{bond} bond, {contact} contact" if n == 0 else None)
            axes[0].plot(strain * 100, stress * 1e3, **style)
            if bond == "contact":
                axes[1].plot(strain * 100, stress * 1e6, **style)
    axes[0].set_ylabel("stress (kPa)")
    axes[0].set_title("bond x contact model (one line per seed)")
    axes[1].set_ylabel("stress (Pa)")
    axes[1].set_title("contact bonds only (a mechanism: no moments)")
    for ax in axes:
        ax.set_xlabel("strain (%)")
        ax.legend(fontsize=8)
    save_figure(fig, path)


@dataclass
class StrengthRun:
    """The strength job of one slab (``study.method`` dynamic or quasistatic): its E, its strength, the strain and
    the energy (the area under the curve) to the peak, the bonds broken before the peak and the bonds broken in the
    run by each check of the breaking rule (quasi-static)."""

    method: str
    E_kPa: float
    strength_kPa: float | None
    strain_at_peak: float | None
    energy_to_peak_kJ_m3: float | None
    broken_at_peak: int | None
    broken_by_check: dict[str, int]
    wall_s: float


@dataclass
class DensityRun:
    """One solid fraction x seed of one loop model: the static E (and its energy by mode), and the strength run
    where the study's method gives one."""

    loop_model: str
    target_solid_fraction: float
    seed: int
    solid_fraction: float
    density_kg_m3: float
    E_kPa: float
    mean_coordination: float | None
    loops_per_10k: float | None
    energy_split: EnergyParts | None
    loaded: StrengthRun | None
    wall_s: float

    @property
    def strength_kPa(self) -> float | None:
        return self.loaded.strength_kPa if self.loaded else None


@dataclass
class DensityStrength:
    """The strength of one loop model at one solid fraction over its seeds: geometric means, the seeds' scatter
    (max / min) and where that scatter comes from.  Below the peak a slab is linear where no bond broke before
    it, so sigma = E eps_peak and var(ln sigma) = var(ln E) + var(ln eps) + 2 cov: ``share_E`` and ``share_strain``
    are the two variances over var(ln sigma), ``corr_E_strain`` their correlation (the stiff slabs break early
    where it is negative)."""

    target_solid_fraction: float
    runs: int
    #: runs at this solid fraction in which no bond broke up to compression.strain_max (no strength)
    unbroken: int
    density_kg_m3: float
    strength_kPa: float
    strength_max_min: float
    E_kPa: float
    strength_per_E: float
    strain_at_peak: float
    energy_to_peak_kJ_m3: float
    broken_at_peak: float
    share_E: float
    share_strain: float
    corr_E_strain: float
    broken_by_check: dict[str, int]


@dataclass
class DensitySeries:
    """A loop model's runs, its fits (E ~ rho^m; sigma ~ rho^n where three runs have a strength), the largest E
    scatter between seeds, the network's coordination and loops, the bonds' energy by mode, the strength per
    solid fraction (with a strength method)."""

    runs: list[DensityRun]
    fits: dict[str, Fit]
    scatter_max_min: float
    mean_coordination: float
    loops_per_10k: float
    energy_split: EnergyParts | None          # the runs' mean (None: no run has one)
    strength: list[DensityStrength]


@dataclass
class Density:
    """The density study: every run, the first loop model's fits (and its exponents with their 95 % intervals as
    the summary's ``modulus_exponent``, ``strength_exponent``), each loop model's series, the literature."""

    runs: list[DensityRun]
    fits: dict[str, Fit]
    models: dict[str, DensitySeries]
    literature: DensityScaling
    modulus_exponent: float
    modulus_exponent_ci95: tuple[float, float]
    strength_exponent: float | None = None
    strength_exponent_ci95: tuple[float, float] | None = None
    headline: str = ""


def _density_fits(runs: list[DensityRun]) -> dict[str, Fit]:
    """E ~ rho^m (and sigma ~ rho^n where three runs have a strength) of one series."""
    fits = {"E": fit_power_law([r.density_kg_m3 for r in runs], [r.E_kPa for r in runs])}
    broke = [r for r in runs if r.strength_kPa]
    if len(broke) >= 3:
        fits["strength"] = fit_power_law([r.density_kg_m3 for r in broke], [r.strength_kPa for r in broke])
    return fits


def _scatter(runs: list[DensityRun]) -> float:
    """The largest max / min of E between seeds at one solid fraction."""
    worst = 1.0
    for f in {r.target_solid_fraction for r in runs}:
        e = [r.E_kPa for r in runs if r.target_solid_fraction == f and r.E_kPa > 0]
        if len(e) >= 2:
            worst = max(worst, max(e) / min(e))
    return worst


def _strength_at(f: float, runs: list[DensityRun]) -> DensityStrength | None:
    """:class:`DensityStrength` of the runs at target solid fraction ``f`` that have a strength."""
    rs = [r for r in runs if r.target_solid_fraction == f and r.strength_kPa and r.loaded.E_kPa > 0]
    if not rs:
        return None
    sig, E, eps = (np.log(v) for v in ([r.strength_kPa for r in rs], [r.loaded.E_kPa for r in rs],
                                                    [r.loaded.strain_at_peak for r in rs]))
    var = float(np.var(sig)) if len(rs) > 1 else 0.0
    checks = {c: sum(r.loaded.broken_by_check.get(c, 0) for r in rs) for c in rs[0].loaded.broken_by_check}
    energy = [r.loaded.energy_to_peak_kJ_m3 for r in rs if r.loaded.energy_to_peak_kJ_m3 is not None]
    broken = [r.loaded.broken_at_peak for r in rs if r.loaded.broken_at_peak is not None]
    unbroken = sum(1 for r in runs if r.target_solid_fraction == f and r.loaded and not r.strength_kPa)
    return DensityStrength(
        f, len(rs), unbroken, float(np.exp(np.mean(np.log([r.density_kg_m3 for r in rs])))), float(np.exp(sig.mean())),
        float(np.exp(sig.max() - sig.min())), float(np.exp(E.mean())), float(np.exp((sig - E).mean())),
        float(np.exp(eps.mean())), float(np.exp(np.mean(np.log(energy)))) if energy else float("nan"),
        float(np.mean(broken)) if broken else float("nan"),
        float(np.var(E)) / var if var else float("nan"), float(np.var(eps)) / var if var else float("nan"),
        float(np.corrcoef(E, eps)[0, 1]) if len(rs) > 2 and np.std(E) and np.std(eps) else float("nan"), checks)


def has_static_jobs(st) -> bool:
    """Whether the density study solves each slab statically beside its loaded run (E from there): for a method
    that is not linear or gives no strength; a linear strength method's first solve is the static one."""
    return not METHODS[st.method].linear or not METHODS[st.method].strength


def aerogel_density_jobs(spec: StudyWorkflow) -> list[Job]:
    """Each loop model x solid fraction x seed (``at``: model, solid fraction, seed, the slab's name): a static solve
    (``NAME_static``: E, energy by mode), a quasi-static run (``NAME``: E by the same first solve, and the strength;
    no static job: the slab is aggregated once) or a dynamic run (``NAME``: strength) with a static solve beside it
    (E without a fit)."""
    st = spec.study
    many = len(st.loop_models) > 1
    jobs = []
    for model in st.loop_models:
        prefix = f"{model}_" if many else ""
        for f in st.solid_fractions:
            for s in st.seeds:
                common = {"aggregate.solid_fraction": float(label_number(f)), "aggregate.seed": s,
                          "aggregate.loops": model}      # (one model too: the series is what its label says)
                name = f"{prefix}phi{label_number(f)}_s{s}"
                at = (model, f, s, name)
                if has_static_jobs(st):
                    jobs.append(Job(f"{name}_static", job_spec(spec, {**common, "compression.method": "static"}),
                                    at=at))
                if METHODS[st.method].strength:
                    jobs.append(Job(name, job_spec(spec, common), at=at))
    return jobs


def _density_series(runs: list[DensityRun]) -> DensitySeries:
    fits = _density_fits(runs)
    have = [r.energy_split for r in runs if r.energy_split is not None]
    split = EnergyParts(*(float(np.mean([getattr(e, f.name) for e in have]))
                          for f in dataclasses.fields(EnergyParts))) if have else None
    strength = [x for f in sorted({r.target_solid_fraction for r in runs}) if (x := _strength_at(f, runs))]
    return DensitySeries(runs, fits, _scatter(runs), float(np.mean([r.mean_coordination or 0 for r in runs])),
                         float(np.mean([r.loops_per_10k or 0 for r in runs])), split, strength)


def _strength_run(result) -> StrengthRun:
    """A strength job's result as :class:`StrengthRun`."""
    by_check = getattr(result, "broken_bonds_by_check", None) or {}
    checks = {check: sum(bins.values()) for check, bins in by_check.items()}
    broke = result.strength_MPa is not None and math.isfinite(result.strength_MPa)     # (nan: no bond broke)
    return StrengthRun(result.method, result.youngs_modulus_GPa * 1e6, result.strength_MPa * 1e3 if broke else None,
                       result.strain_at_peak if broke else None, result.energy_to_peak_kJ_m3 if broke else None,
                       getattr(result, "broken_bonds_at_peak", None) if broke else None, checks, result.wall_s)


def aerogel_density_analyse(spec: StudyWorkflow, jobs: list[Job], res: dict) -> Density | None:
    """E ~ rho^m and sigma ~ rho^n with 95 % intervals for each loop model with two densities or more."""
    series: dict[str, list[DensityRun]] = {m: [] for m in spec.study.loop_models}
    for model, f, s, name in dict.fromkeys(j.at for j in jobs):
        loaded = res.get(name)                                  # the strength run
        static = res.get(f"{name}_static") or loaded            # E: the static solve, else the quasi-static one
        if static is not None:
            series[model].append(DensityRun(
                model, f, s, static.solid_fraction, static.density_kg_m3, static.youngs_modulus_GPa * 1e6,
                static.mean_coordination, static.loops_per_10k, static.energy_split,
                _strength_run(loaded) if loaded else None,
                static.wall_s + (loaded.wall_s if loaded and loaded is not static else 0.0)))
    models = {m: _density_series(runs) for m, runs in series.items() if len({r.density_kg_m3 for r in runs}) >= 2}
    if not models:
        return None
    ref = density_scaling()
    first = models[next(iter(models))]
    m, n = first.fits["E"], first.fits.get("strength")
    study = Density([r for m in models.values() for r in m.runs], first.fits, models, ref, m.exponent,
                    m.exponent_ci, n.exponent if n else None, n.exponent_ci if n else None)
    n_txt = f", n = {n.exponent:.2f} [{n.exponent_ci[0]:.2f}, {n.exponent_ci[1]:.2f}]" if n else ""
    study.headline = ("E ~ rho^m with " + "; ".join(f"{_m_text(m.fits['E'])} ({name})" for name, m in models.items())
                      + n_txt + f"; Ma et al. m = {ref.m_dlca_beams}, experiments {ref.m_experiment_low}-"
                      f"{ref.m_experiment_high}")
    return study


def _m_text(f: Fit) -> str:
    return f"m = {f.exponent:.2f} [{f.exponent_ci[0]:.2f}, {f.exponent_ci[1]:.2f}]"


def aerogel_density_render(spec: StudyWorkflow, study: Density, out: Path) -> list[str]:
    st, ref = spec.study, study.literature
    method = next((r.loaded.method for r in study.runs if r.loaded), None)
    static_jobs = has_static_jobs(st)
    e_from = ("E from the static solver (the slab glued between its bottom layer and the wall, as the loaded run)"
              if static_jobs else f"E from the {st.method} run's first load step (its secant; the static solver's E "
              "where the run is linear)")
    _plot_density(study.models, out / "density.png", "static" if static_jobs else "first load step")
    lines = [f"Solid fractions {', '.join(map(str, st.solid_fractions))} x seeds {', '.join(map(str, st.seeds))} x "
             f"loop models {', '.join(st.loop_models)}: {e_from}" + (f", strength from the {method} run" if method
                                                                      else "")
             + "; density = the slab's after the cut.", "",
             "| loop model | law | exponent | 95 % interval | prefactor | R^2 | E max/min between seeds | "
             "coordination | loops per 10 000 | energy: bending / twisting / shear / stretching | reference |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for model, m in study.models.items():
        for law, f in m.fits.items():
            e = m.energy_split
            lines.append(
                f"| {model} | {'E = a rho^m' if law == 'E' else 'sigma = a rho^n'} (kPa) | {f.exponent:.3f} | "
                f"[{f.exponent_ci[0]:.3f}, {f.exponent_ci[1]:.3f}] | {f.prefactor:.4g} | {f.r2:.4f} | "
                f"{m.scatter_max_min:.1f} | {m.mean_coordination:.2f} | {m.loops_per_10k:.0f} | "
                + (" / ".join(f"{100 * getattr(e, k):.0f} %" for k in ("bending", "twisting", "shear", "stretching")) if e
                   else "-")
                + (f" | m = {ref.m_dlca_beams} ({ref.m_dlca_beams_source}); {ref.m_experiment_low}-"
                   f"{ref.m_experiment_high} ({ref.m_experiment_source}) |" if law == "E" else
                   f" | {_n_reference(ref)} |"))
    if method:
        lines += ["", f"Strength per solid fraction ({method}; geometric means over the seeds; share of "
                  "var(ln sigma) from ln E and ln(strain at peak), their correlation: DensityStrength in "
                  "opalflow/studies/aerogel.py):", "",
                  "| loop model | target solid fraction | runs broken / unbroken | density (kg/m^3) | strength (kPa) | "
                  "strength max/min | E (kPa) | strength / E | strain at peak | energy to peak (kJ/m^3) | bonds broken "
                  "before the peak | share of ln E / ln strain | corr | bonds broken by |", "|" + "---|" * 14]
        lines += [f"| {model} | {x.target_solid_fraction:g} | {x.runs} / {x.unbroken} | {x.density_kg_m3:.1f} | "
                  f"{x.strength_kPa:.4g} | {x.strength_max_min:.1f} | {x.E_kPa:.4g} | {x.strength_per_E:.4f} | "
                  f"{x.strain_at_peak:.3f} | "
                  f"{x.energy_to_peak_kJ_m3:.3g} | {x.broken_at_peak:.1f} | {x.share_E:.2f} / {x.share_strain:.2f} | "
                  f"{x.corr_E_strain:.2f} | {', '.join(f'{k} {v}' for k, v in x.broken_by_check.items()) or '-'} |"
                  for model, m in study.models.items() for x in m.strength]
        _plot_curves(spec, study, out, out / "curves.png")
    lines += ["", "| loop model | target solid fraction | seed | solid fraction | density (kg/m^3) | E static (kPa) | "
              "E loaded (kPa) | strength (kPa) | strain at peak | wall (s) |", "|" + "---|" * 10]
    lines += [f"| {r.loop_model} | {r.target_solid_fraction:g} | {r.seed} | {r.solid_fraction:.4f} | "
              f"{r.density_kg_m3:.1f} | {r.E_kPa:.4g} | {fmt_value(r.loaded and r.loaded.E_kPa, '.4g')} | "
              f"{fmt_value(r.strength_kPa, '.4g')} | {fmt_value(r.loaded and r.loaded.strain_at_peak, '.4f')} | "
              f"{r.wall_s:.0f} |" for r in study.runs]
    return lines + ["", "![E and strength against density](density.png)"] + (
        ["", "![stress-strain curves, one per solid fraction](curves.png)"] if method else [])


def _n_reference(ref: DensityScaling) -> str:
    """The literature's strength exponents (data/reference/aerogel_literature.toml), where it has them."""
    if ref.n_experiment is None:
        return "-"
    return (f"n = {ref.n_experiment} ({ref.n_experiment_source}); brittle open cells n = "
            f"{ref.n_foam_brittle} ({ref.n_foam_source})")


def _plot_curves(spec: StudyWorkflow, study: Density, out: Path, path: Path) -> None:
    """The first loop model's stress-strain curves, one per solid fraction: the seed of median strength."""
    jobs = {j.at: j for j in aerogel_density_jobs(spec) if not j.label.endswith("_static")}
    model = next(iter(study.models))
    fig, ax = new_figure(figsize=(6.4, 4.4))
    for k, f in enumerate(sorted({r.target_solid_fraction for r in study.models[model].runs})):
        rs = sorted((r for r in study.models[model].runs if r.target_solid_fraction == f and r.strength_kPa),
                    key=lambda r: r.strength_kPa)
        job = next((j for at, j in jobs.items() if rs and at[:3] == (model, f, rs[len(rs) // 2].seed)), None)
        curve = _curve(out, job) if job else None
        if curve is not None:
            ax.plot(curve[0], curve[1] * 1e3, "-", color=f"C{k}", lw=1,
                    label=f"solid fraction {f:g}, seed {rs[len(rs) // 2].seed}")
    ax.set_xlabel("strain")
    ax.set_ylabel("stress (kPa)")
    ax.set_title(f"{model}: the seed of median strength at each solid fraction", fontsize=9)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def _plot_density(models: dict[str, DensitySeries], path: Path, e_from: str = "static") -> None:
    """E (and strength) against density, one colour per loop model, each with its power-law fit; ``e_from``: where
    E comes from (the legend's)."""
    fig, ax = new_figure(figsize=(6.8, 4.6))
    for k, (model, m) in enumerate(models.items()):
        runs, fits = m.runs, m.fits
        rho = np.array([r.density_kg_m3 for r in runs])
        grid = np.geomspace(rho.min(), rho.max(), 50)
        f = fits["E"]
        ax.loglog(rho, [r.E_kPa for r in runs], "o", color=f"C{k}", ms=4, label=f"E ({e_from}), {model}")
        ax.loglog(grid, f.prefactor * grid ** f.exponent, "-", color=f"C{k}", label=f"{model}: {_m_text(f)}")
        if "strength" in fits:
            broke = [r for r in runs if r.strength_kPa]
            f = fits["strength"]
            ax.loglog([r.density_kg_m3 for r in broke], [r.strength_kPa for r in broke], "s", color=f"C{k}",
                      mfc="none", label=f"strength ({broke[0].loaded.method}), {model}")
            ax.loglog(grid, f.prefactor * grid ** f.exponent, "--", color=f"C{k}",
                      label=f"n = {f.exponent:.2f} [{f.exponent_ci[0]:.2f}, {f.exponent_ci[1]:.2f}]")
    ax.set_xlabel("density (kg/m^3)")
    ax.set_ylabel("kPa")
    ax.legend(fontsize=7)
    save_figure(fig, path)
