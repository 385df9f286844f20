"""The atomistic workflows: ``tersoff_properties``, ``tersoff_fit``, ``tersoff_stability``.

Each writes into its run folder: ``summary.json`` (the keys of :class:`opalflow.tersoff.result.TersoffResult`:
a0_A, Ec_eV, B_GPa, Cprime_GPa, C11_GPa, C12_GPa, C44_GPa, C44_0_GPa, loss, reference_loss, fit_s, stability, ...),
``report.md`` with every property's error against Table 1 of seed 003, the plots, and
the LAMMPS logs.  The potential is parsed and rewritten into the folder, so no user path
reaches a LAMMPS script.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from opalflow.lammps.engine import accelerated
from opalflow.runs.record import finish
from opalflow.store import new_figure, save_figure
from opalflow.tersoff import fit as fitting
from opalflow.tersoff import stability as stab
from opalflow.tersoff.model import DiamondModel, neighbor_radius
from opalflow.tersoff.parameters import (COLUMNS, REFERENCE_POTENTIAL, Properties, TersoffParameters, load_parameters,
                                         read_tersoff, write_tersoff)
from opalflow.tersoff.properties import MODULI_KEYS as MODULI, evaluate
from opalflow.tersoff.result import PropertyError, ScanRow, StabilitySummary, TersoffResult
from opalflow.tersoff.spec import TersoffWorkflow
from opalflow.version import __version__

LABELS = {"Ec_eV": ("E_c", "eV"), "B_GPa": ("B", "GPa"), "Cprime_GPa": ("C'", "GPa"), "C11_GPa": ("C11", "GPa"),
          "C12_GPa": ("C12", "GPa"), "C44_0_GPa": ("C44^0", "GPa"), "C44_GPa": ("C44", "GPa")}


def model_for(cutoff: float, a: float) -> DiamondModel:
    """A diamond model whose neighbour list reaches past the cutoff R + D."""
    return DiamondModel(a=a, neighbor_radius_over_a=neighbor_radius(cutoff, a))


def loss_of(spec: TersoffWorkflow, start: TersoffParameters) -> fitting.Loss:
    """The loss (eq. 13) the spec fits by: targets and weights (Table 1, weight 1 unless set), bounds (defaults
    updated by the spec), fixed parameters at the values of ``start``."""
    t = spec.tersoff
    ref = fitting.zhuravlev2021()
    fixed = {k: getattr(start, k) for k in t.fixed}
    bounds = {**fitting.DEFAULT_BOUNDS, **{k: tuple(v) for k, v in t.bounds.items()}}
    bounds = {k: v for k, v in bounds.items() if k not in fixed}
    r_max = fixed.get("R", bounds.get("R", (0, 0))[1]) + fixed.get("D", bounds.get("D", (0, 0))[1])
    return fitting.Loss(targets={**ref.targets, **t.targets}, weights={**fitting.default_weights(), **t.weights},
                        bounds=bounds, fixed=fixed, a_target=t.lattice_target_A,
                        neighbor_radius_over_a=neighbor_radius(r_max, t.lattice_target_A))


def _errors(props: Properties, ref: fitting.Table1) -> dict[str, PropertyError]:
    """Error of each property: absolute (same unit) and relative, against targets and the paper's column."""
    out = {}
    for key in LABELS:
        v, target, calc = props.of(key), ref.targets[key], ref.calculated[key]
        out[key] = PropertyError(v, target, v - target, (v - target) / abs(target), calc, v - calc)
    return out


def _property_rows(props: Properties, ref: fitting.Table1, model: dict | None = None) -> list[str]:
    head = "| property | LAMMPS | target (Table 1) | error | paper's calculated | difference |"
    rule = "|---|---|---|---|---|---|"
    if model is not None:
        head += " fit model | LAMMPS - model |"
        rule += "---|---|"
    rows = [head, rule]
    for key, (label, unit) in LABELS.items():
        v, tg, calc = props.of(key), ref.targets[key], ref.calculated[key]
        row = (f"| {label} ({unit}) | {v:.3f} | {tg:g} | {v - tg:+.3f} ({100 * (v - tg) / abs(tg):+.1f} %) | "
               f"{calc:g} | {v - calc:+.3f} |")
        if model is not None:
            row += f" {model[key]:.3f} | {v - model[key]:+.2e} |"
        rows.append(row)
    return rows


def _lammps_properties(params: TersoffParameters, spec: TersoffWorkflow, folder: Path, scan: bool):
    t = spec.tersoff
    ev = evaluate(params, folder, strain=t.strain, scan=tuple(t.strain_scan) if scan else (), cells=t.cells,
                  a_guess=t.lattice_target_A)
    props = Properties(a0_A=ev.a0_A, Ec_eV=ev.Ec_eV, **ev.values)
    exact = model_for(params.cutoff(), t.lattice_target_A).evaluate(params, a=ev.a0_A)
    return ev, props, exact


def _scan_table(ev, exact: dict) -> list[ScanRow]:
    """Strain size -> error of each modulus against the exact (AD) second derivative, and time."""
    rows = []
    for h, moduli in ev.scan.items():
        err = {k: moduli[k] - exact[k] for k in MODULI}
        rows.append(ScanRow(h, err, max(abs(e) for e in err.values()), ev.scan_s[h]))
    return rows


def _plot_scan(rows: list[ScanRow], path: Path) -> None:
    fig, ax = new_figure(figsize=(6, 4))
    h = [r.strain for r in rows]
    for key in MODULI:
        ax.loglog(h, [max(abs(r.errors_GPa[key]), 1e-12) for r in rows], "o-", label=LABELS[key][0])
    ax.set_xlabel("strain size e of the central difference (eq. 16)")
    ax.set_ylabel("|LAMMPS - exact| (GPa)")
    ax.set_title("Finite-difference moduli against the AD second derivative")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    save_figure(fig, path)


def _stability_summary(results: list[stab.BoundaryResult], temperature: float) -> StabilitySummary:
    at = [r for r in results if r.temperature_K == temperature]
    return StabilitySummary(all(r.passed for r in at), temperature, results)


def _stability_rows(results: list[stab.BoundaryResult]) -> list[str]:
    rows = ["| boundary | T (K) | result | NVE drift (eV/atom) | 4-fold interior | interior RMS (A) | lost | "
            "mean T (K) | time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        rows.append(f"| {r.boundary} | {r.temperature_K:g} | {'pass' if r.passed else 'FAIL: ' + r.reason} | "
                    f"{r.drift_eV_per_atom:.2e} | {r.fourfold_interior:.3f} | {r.rms_interior_A:.3f} | "
                    f"{r.atoms_lost} | {r.mean_temperature_K:.0f} | {r.seconds:.1f} |")
    return rows


def _stability(params: TersoffParameters, folder: Path, spec: TersoffWorkflow, temperatures_K: tuple,
               say) -> list[stab.BoundaryResult]:
    """The MD stability check of ``params`` at ``temperatures_K`` with the spec's [stability] settings."""
    s = spec.stability
    return stab.check(params, folder, temperatures_K=temperatures_K, say=say, boundaries=tuple(s.boundaries),
                      workers=s.workers, cells=s.cells, time_ps=s.time_ps, timestep_fs=s.timestep_fs, seed=s.seed,
                      criteria=stab.Criteria(s.max_drift_eV, s.min_fourfold, s.max_rms_A))


def _finish(out: Path, spec: TersoffWorkflow, result: TersoffResult, report: list[str], t0: float) -> TersoffResult:
    result.wall_s = time.perf_counter() - t0
    result.spec = spec.to_dict()
    report.append("")
    report.append(f"Wall time {result.wall_s:.1f} s on this machine. opalflow {__version__}.")
    return finish(out, result.summary(), "\n".join(report), result=TersoffResult)


def run_properties(spec: TersoffWorkflow, out: Path, say=print, suffix: str | None = None) -> TersoffResult:
    with accelerated(suffix):
        return _run_properties(spec, out, say)


def _run_properties(spec: TersoffWorkflow, out: Path, say=print) -> TersoffResult:
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    params = load_parameters(spec.tersoff.potential, spec.tersoff.element)
    ref = fitting.zhuravlev2021()
    say(f"properties of {spec.tersoff.potential} ({params.element}) by LAMMPS, strain scan "
        f"{len(spec.tersoff.strain_scan)} sizes")
    ev, props, exact = _lammps_properties(params, spec, out, scan=True)
    loss = loss_of(spec, params)
    rows = _scan_table(ev, exact)
    _plot_scan(rows, out / "strain_scan.png")
    result = TersoffResult(
        mode="properties", **dataclasses.asdict(props), loss=loss(params),
        reference_loss=loss(read_tersoff(REFERENCE_POTENTIAL)),
        strain=ev.strain, spread_GPa=ev.spread, model=exact,
        lammps_minus_model={k: props.of(k) - exact[k] for k in LABELS},
        reference=_errors(props, ref), strain_scan=rows, lammps_s=ev.seconds,
        headline=(f"a0 = {props.a0_A:.5f} A, Ec = {props.Ec_eV:.4f} eV, B = {props.B_GPa:.2f}, "
                  f"C' = {props.Cprime_GPa:.2f}, C11 = {props.C11_GPa:.2f}, C12 = {props.C12_GPa:.2f}, "
                  f"C44^0 = {props.C44_0_GPa:.2f}, C44 = {props.C44_GPa:.2f} GPa"))
    report = [f"# Tersoff properties: {spec.tersoff.potential}", "",
              f"LAMMPS `pair_style tersoff`, `units metal`, {spec.tersoff.cells}^3 conventional cells "
              f"({8 * spec.tersoff.cells ** 3} atoms); lattice constant by `fix box/relax iso 0` "
              f"+ `minimize`: a0 = {props.a0_A:.6f} A (target a* = {spec.tersoff.lattice_target_A} A). "
              f"Moduli by central second differences of the energy (seed 003, eq. 16) at strain "
              f"{ev.strain:g}; C44 with the atoms relaxed (`minimize`) in each sheared box.", "",
              *_property_rows(props, ref, exact), "",
              "Fit model = the exact (automatic-differentiation) second derivatives of the same energy at a0; "
              "the LAMMPS - model column is the finite-difference error.", "",
              f"Loss eq. 13 of this set (fit model at a*, Table 1 targets): {result.loss:.5f}; "
              f"Table 2's set: {result.reference_loss:.5f}.", "",
              "## Error against run time: strain size of the central difference", "",
              "| strain | max abs error (GPa) | " + " | ".join(LABELS[k][0] for k in MODULI) + " | time (s) |",
              "|---|---|" + "---|" * len(MODULI) + "---|"]
    for r in rows:
        report.append(f"| {r.strain:g} | {r.max_abs_error_GPa:.2e} | "
                      + " | ".join(f"{r.errors_GPa[k]:+.1e}" for k in MODULI) + f" | {r.seconds:.3f} |")
    report += ["", f"Time per strain size: 8 energies (+e and -e on the four strain paths; for C44 with the atoms relaxed); "
               f"the whole evaluation at one strain, lattice relaxation and set-up included, took "
               f"{ev.seconds - sum(ev.scan_s.values()) + ev.scan_s[ev.strain]:.3f} s of LAMMPS.",
               "", f"Spread over strains within a decade of {ev.strain:g}: "
               + ", ".join(f"{LABELS[k][0]} {v:.2g}" for k, v in ev.spread.items()) + " GPa. "
               "Round-off (1e-16 x E / e^2) dominates below the plateau, the quartic term of E above it.",
               "", "![strain scan](strain_scan.png)"]
    return _finish(out, spec, result, report, t0)


def run_stability(spec: TersoffWorkflow, out: Path, say=print, suffix: str | None = None) -> TersoffResult:
    with accelerated(suffix):
        return _run_stability(spec, out, say)


def _run_stability(spec: TersoffWorkflow, out: Path, say=print) -> TersoffResult:
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    params = load_parameters(spec.tersoff.potential, spec.tersoff.element)
    s = spec.stability
    say(f"stability of {spec.tersoff.potential}: {', '.join(s.boundaries)} at "
        f"{', '.join(f'{t:g}' for t in s.temperatures_K)} K, {s.time_ps:g} ps each")
    results = _stability(params, out, spec, tuple(s.temperatures_K), say)
    result = TersoffResult(mode="stability", stability=_stability_summary(results, s.temperatures_K[0]))
    verdicts = []
    for temp in s.temperatures_K:
        at = [r for r in results if r.temperature_K == temp]
        failed = [r.boundary for r in at if not r.passed]
        verdicts.append(f"{temp:g} K: " + ("all pass" if not failed else f"fails {', '.join(failed)}"))
    result.headline = f"stability of {spec.tersoff.potential}: " + "; ".join(verdicts)
    report = [f"# Tersoff stability: {spec.tersoff.potential}", "",
              f"{s.cells}x{s.cells}x{s.cells} conventional cells ({8 * s.cells ** 3} atoms), {s.time_ps:g} ps of NVE "
              f"at {s.timestep_fs:g} fs after relaxing the surfaces; velocities for twice the set temperature. "
              f"Pass: drift <= {s.max_drift_eV:g} eV/atom, 4-fold interior >= {s.min_fourfold:g}, "
              f"interior RMS <= {s.max_rms_A:g} A, no atom lost (opalflow/tersoff/stability.py).", "",
              *_stability_rows(results), "", result.headline + "."]
    return _finish(out, spec, result, report, t0)


def run_fit(spec: TersoffWorkflow, out: Path, say=print) -> TersoffResult:
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    t = spec.tersoff
    start = load_parameters(t.potential, t.element)
    loss = loss_of(spec, start)
    ref = fitting.zhuravlev2021()
    say(f"fit: {t.starts} L-BFGS starts (seed {t.seed}), free {', '.join(k for k in COLUMNS if k not in t.fixed)}; "
        f"fixed {', '.join(f'{k} = {getattr(start, k):g}' for k in t.fixed)}")
    results = fitting.multistart(loss, starts=t.starts, seed=t.seed, max_iter=t.max_iter, say=say)
    fit_s = time.perf_counter() - t0
    reference_loss = loss(read_tersoff(REFERENCE_POTENTIAL))
    say(f"best loss {results[0].loss:.5f} (Table 2: {reference_loss:.5f}) in {fit_s:.1f} s")
    stab_t = spec.stability.temperatures_K[0]
    chosen, checks = results[0], []
    for rank, r in enumerate(results[:t.rank_top]):
        cand = TersoffParameters.from_values(r.params, start.element)
        say(f"candidate {rank + 1} (start {r.start + 1}, loss {r.loss:.5f}): stability at {stab_t:g} K")
        res = _stability(cand, out / f"stability_candidate{rank + 1}", spec, (stab_t,), say)
        checks.append((r, res))
        if all(x.passed for x in res):
            chosen = r
            break
    best = TersoffParameters.from_values(chosen.params, start.element)
    write_tersoff(out / "fitted.tersoff", best,
                  f"fitted by opalflow {__version__} (workflow {spec.name}): loss eq. 13 = {chosen.loss:.6f}\n"
                  f"{t.starts} L-BFGS starts, seed {t.seed}; start {chosen.start + 1} chosen")
    ev, props, exact = _lammps_properties(best, spec, out / "lammps", scan=False)
    at_target = loss.model.evaluate(best)
    chosen_checks = next((res for r, res in checks if r is chosen), [])
    _plot_history(results, reference_loss, out / "loss_history.png")
    result = TersoffResult(
        mode="fit", **dataclasses.asdict(props), loss=chosen.loss, reference_loss=reference_loss,
        fit_s=fit_s, parameters=best.as_dict(),
        at_bounds=[k for k in COLUMNS if "bound)" in _bound_note(k, getattr(best, k), loss)],
        stability=_stability_summary(chosen_checks, stab_t) if chosen_checks else None,
        candidates_checked=[{"start": r.start, "loss": r.loss, "stable": all(x.passed for x in res)}
                            for r, res in checks],
        model_at_a0=exact, model_at_target=at_target,
        lammps_minus_model={k: props.of(k) - exact[k] for k in LABELS},
        reference=_errors(props, ref),
        starts=[{"start": r.start, "loss": r.loss, "iterations": r.iterations, "evaluations": r.evaluations,
                 "seconds": r.seconds, "message": r.message, "history": r.history} for r in results],
        headline=(f"fit loss {chosen.loss:.5f} (Table 2: {reference_loss:.5f}), {t.starts} starts in "
                  f"{fit_s:.1f} s; LAMMPS: Ec = {props.Ec_eV:.3f} eV, B = {props.B_GPa:.1f}, "
                  f"C11 = {props.C11_GPa:.1f}, C12 = {props.C12_GPa:.1f}, "
                  f"C44^0 = {props.C44_0_GPa:.1f}, C44 = {props.C44_GPa:.1f} GPa; "
                  + ("stable" if summary_stable(chosen_checks) else "NOT stable") + f" at {stab_t:g} K"))
    report = [f"# Tersoff fit ({spec.name})", "",
              f"Loss eq. 13 (seed 003) at a* = {t.lattice_target_A} A, weights "
              + ", ".join(f"{k} {v:g}" for k, v in loss.weights.items())
              + f". L-BFGS-B with JAX gradients from {t.starts} uniform random starts in the bounds (seed {t.seed}); "
              f"fixed {', '.join(f'{k} = {v:g}' for k, v in loss.fixed.items())}.", "",
              f"Best loss **{chosen.loss:.5f}** against Table 2's **{reference_loss:.5f}** on the same targets and "
              f"weights; fit time {fit_s:.1f} s (all starts), wall time below.", "",
              "## Parameters (fitted.tersoff)", "",
              "gamma and beta enter only as the product beta gamma (zeta is proportional to gamma), so the fit "
              "fixes their product, not each.", "",
              "| parameter | fitted | Table 2 | search box |", "|---|---|---|---|"]
    table2 = read_tersoff(REFERENCE_POTENTIAL)
    report += [f"| {k} | {getattr(best, k):.6g} | {getattr(table2, k):g} | {_bound_note(k, getattr(best, k), loss)} |"
               for k in COLUMNS]
    report += ["", "## Properties of the fitted set (LAMMPS at its a0; fit model = exact derivatives, same a0)", "",
               f"a0 = {props.a0_A:.5f} A; at a* the fit model gives "
               + ", ".join(f"{LABELS[k][0]} {at_target[k]:.3f}" for k in LABELS) + ".", "",
               *_property_rows(props, ref, exact), "",
               "## Stability of the best candidates (ranked by loss, first stable one chosen)", ""]
    for rank, (r, res) in enumerate(checks):
        report += [f"Candidate {rank + 1}: start {r.start + 1}, loss {r.loss:.5f}", "", *_stability_rows(res), ""]
    if not checks:
        report += ["No stability check (tersoff.rank_top = 0).", ""]
    report += ["## Starts", "", "| start | loss | iterations | evaluations | time (s) | stop |", "|---|---|---|---|---|---|"]
    report += [f"| {r.start + 1} | {r.loss:.5f} | {r.iterations} | {r.evaluations} | {r.seconds:.2f} | {r.message} |"
               for r in sorted(results, key=lambda r: r.start)]
    report += ["", "![loss history](loss_history.png)"]
    return _finish(out, spec, result, report, t0)


def _bound_note(name: str, value: float, loss: fitting.Loss) -> str:
    if name in loss.fixed:
        return "fixed"
    lo, hi = loss.bounds[name]
    note = " (at the lower bound)" if value <= lo + 1e-6 * (hi - lo) else (
        " (at the upper bound)" if value >= hi - 1e-6 * (hi - lo) else "")
    return f"[{lo:g}, {hi:g}]{note}"


def summary_stable(results: list[stab.BoundaryResult]) -> bool:
    return bool(results) and all(r.passed for r in results)


def _plot_history(results, reference_loss: float, path: Path) -> None:
    fig, ax = new_figure(figsize=(6, 4))
    for r in sorted(results, key=lambda r: r.start):
        ax.semilogy(np.arange(1, len(r.history) + 1), r.history, lw=1)
    ax.axhline(reference_loss, color="k", ls="--", label=f"Table 2 ({reference_loss:.4f})")
    ax.set_xlabel("L-BFGS iteration")
    ax.set_ylabel("loss eq. 13")
    ax.set_title("Loss history of each start")
    ax.legend()
    save_figure(fig, path)
