"""Aerogel strength (issue 55): the quasi-static method checked against LAMMPS's dynamics on the same slabs, the
strength study's cost, the curve to densification.

    python bench/bench_aerogel_strength.py validate   # 2 000-sphere slabs, 3 densities x 3 seeds x trees / loops
    python bench/bench_aerogel_strength.py nonlinear  # the nonlinear method, and LAMMPS without contacts, on them
    python bench/bench_aerogel_strength.py extend     # LAMMPS twice as far where its run ended before a collapse
    python bench/bench_aerogel_strength.py report     # the validation table (.json, .md) from the runs that finished
    python bench/bench_aerogel_strength.py study      # workflows/aerogel_strength.toml: n and m, its wall time
    python bench/bench_aerogel_strength.py study --workflow aerogel_strength_linear    # the linear method's
    python bench/bench_aerogel_strength.py densify    # one slab to 35 % strain by LAMMPS's dynamics, with contacts

``validate`` runs each slab three ways: LAMMPS (``bpm/rotational``, wall at 0.1 m/s, bonds breaking at full load:
``bonds.smooth = false``), the quasi-static method (event-driven breaking of the linear network, the same rule) and
the static solver (E); one slab again at half the wall speed (is the dynamic run quasi-static?) and with LAMMPS's
``smooth yes`` (the fade-out 1 - B^4: how much it lowers the strength).  Rows go to
bench/results/aerogel_strength_validation.json; ``study`` writes bench/results/WORKFLOW.json; ``densify``
bench/results/aerogel_densification.json.  Two runs at a time (one LAMMPS process each) on this 2-core machine.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np

from opalflow.bpm.spec import CompressionSpec

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
ROOT = HERE.parent
FRACTIONS = (0.03, 0.06, 0.12)
SEEDS = (1, 2, 3)
SERIES = ("none", "restructuring")
BRITTLE = ["bonds.smooth=false"]          # a bond breaks at full load (the quasi-static method's rule)
#: the quasi-static runs go this far (they stop once the stress has fallen to half its peak)
QS_STRAIN_MAX = 0.5
#: compression.stop_fraction's default: the quasi-static runs stop, and the strength of a LAMMPS curve is read,
#: where the stress has fallen below this fraction of its peak
STOP_FRACTION = CompressionSpec.stop_fraction


def machine() -> dict:
    return {"machine": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "date": time.strftime("%Y-%m-%d %H:%M")}


def run(out: Path, sets: list[str], workflow: str = "aerogel_compression") -> dict:
    """One ``python -m opalflow run`` into ``out`` (kept when finished: a second call reads it back)."""
    if not (out / "summary.json").exists() or json.loads((out / "summary.json").read_text()).get("state") != "finished":
        cmd = [sys.executable, "-m", "opalflow", "run", workflow, "--out", str(out)]
        for s in sets:
            cmd += ["--set", s]
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out.with_name(out.name + ".log"), "w") as log:         # (progress lines: not on this screen)
            subprocess.run(cmd, check=True, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    return json.loads((out / "summary.json").read_text())


def at_peak(out: Path, summary: dict) -> dict:
    """Strength, strain at the peak, bonds broken up to the peak (from the curve) and the first tangent."""
    with h5py.File(out / "results.h5", "r") as h:
        if summary["method"] == "quasistatic":
            e, s = h["quasistatic/strain"][()], h["quasistatic/stress_MPa"][()]
            if not len(s):                                  # stopped before any bond broke: no strength
                return {"strength_kPa": math.nan, "strain_at_peak": math.nan, "broken_at_peak": 0,
                        "first_break_kPa": math.nan, "strain_at_first_break": math.nan,
                        "E_kPa": summary["youngs_modulus_GPa"] * 1e6, "tangent_kPa": None,
                        "wall_s": summary["wall_s"], "broken_bonds": 0}
            broken = np.cumsum(h["quasistatic/bonds_per_event"][()])
            k = int(np.argmax(s))
            at = int(broken[k - 1]) if k > 0 else 0          # events before the peak's (the peak: before its event)
            tangent, over_run = None, {}
            first = (float(s[0]), float(e[0]))                # the first event's stress and strain
        elif summary["method"] == "dynamic":
            e, s = h["curve/strain"][()], h["curve/stress_MPa"][()]
            b = h["curve/broken_bonds"][()]
            # the strength: the peak before the first collapse, where the stress, bonds broken, falls below
            # STOP_FRACTION of its peak so far (the quasi-static methods' stop rule: the same peak on both sides);
            # the largest stress of the run beside it (it depends on how far the run went)
            fell = np.flatnonzero((s < STOP_FRACTION * np.maximum.accumulate(s)) & (b > 0))
            k = int(np.argmax(s[:fell[0] if len(fell) else len(s)]))
            largest = int(np.argmax(s))
            over_run = {"largest_kPa": float(s[largest]) * 1e3, "strain_at_largest": float(e[largest]),
                        "strain_end": float(e[-1]),
                        "collapsed": bool(len(fell)), "peak_inside_run": bool(len(fell)) or bool(e[k] < 0.98 * e[-1])}
            at = int(b[k])
            m = (e >= 0.005) & (e <= 0.02)
            tangent = float(np.polyfit(e[m], s[m], 1)[0] * 1e3) if m.sum() > 2 else None
            # the first break: the highest stress before the first bond broke (none broke: the peak)
            pre = np.flatnonzero(b == 0)
            j = int(pre[np.argmax(s[pre])]) if len(pre) else k
            first = (float(s[j]), float(e[j]))
        else:
            return {"E_kPa": summary["youngs_modulus_GPa"] * 1e6}
    return {"strength_kPa": float(s[k]) * 1e3, "strain_at_peak": float(e[k]), "broken_at_peak": at,
            "first_break_kPa": first[0] * 1e3, "strain_at_first_break": first[1],
            "E_kPa": summary["youngs_modulus_GPa"] * 1e6, "tangent_kPa": tangent, "wall_s": summary["wall_s"],
            "broken_bonds": summary.get("broken_bonds"), **over_run}


def slab(root: Path, series: str, phi: float, seed: int) -> tuple[Path, list[str]]:
    sets = [f"aggregate.loops={series}", f"aggregate.solid_fraction={phi}", f"aggregate.seed={seed}"]
    return root / f"{series}_phi{phi}_s{seed}", sets


def validate(a) -> dict:
    root = Path(a.runs) / "validate"
    cases = [(series, phi, seed) for series in a.series for phi in a.fractions for seed in a.seeds]

    def one(case):
        series, phi, seed = case
        base, sets = slab(root, series, phi, seed)
        row = {"series": series, "solid_fraction": phi, "seed": seed}
        # the quasi-static run first (seconds): the dynamic one then goes to 1.25 x its strain at the peak, not
        # further (a LAMMPS run costs in proportion to its strain; a tree at 0.03 breaks its first bond at ~0.2)
        for method in ("quasistatic", "static", "dynamic"):
            extra = [f"compression.method={method}", f"compression.strain_max={QS_STRAIN_MAX}"]
            if method == "dynamic":
                reach = min(QS_STRAIN_MAX, round(1.25 * row["quasistatic"]["strain_at_peak"] + 0.01, 3))
                extra = [f"compression.strain_max={reach}", "compression.snapshot_strains=[]"]
            out = base.with_name(f"{base.name}_{method}")
            summary = run(out, [*sets, *BRITTLE, *extra])
            row[method] = at_peak(out, summary)
            row["particles"], row["bonds"] = summary["n_particles"], summary["n_bonds"]
            row["density_kg_m3"] = summary["density_kg_m3"]
        row["dynamic_strain_max"] = reach
        row["dynamic"]["peak_inside_run"] = row["dynamic"]["strain_at_peak"] < 0.98 * reach
        d, q = row["dynamic"], row["quasistatic"]
        row["strength_error"] = q["strength_kPa"] / d["strength_kPa"] - 1
        row["strain_at_peak_error"] = q["strain_at_peak"] / d["strain_at_peak"] - 1
        print(json.dumps({k: row[k] for k in ("series", "solid_fraction", "seed", "strength_error")}), flush=True)
        return row

    def extra(name, sets, rows):
        series, phi, seed = a.series[0], FRACTIONS[0], SEEDS[0]
        reach = next(r["dynamic_strain_max"] for r in rows if (r["series"], r["solid_fraction"], r["seed"])
                     == (series, phi, seed))
        base, slab_sets = slab(root, series, phi, seed)
        out = base.with_name(f"{base.name}_{name}")
        summary = run(out, [*slab_sets, *sets, f"compression.strain_max={reach}", "compression.snapshot_strains=[]"])
        return {"series": series, "solid_fraction": phi, "seed": seed, "case": name, **at_peak(out, summary)}

    t = time.perf_counter()
    with ThreadPoolExecutor(a.workers) as pool:
        rows = list(pool.map(one, cases))
        checks = [] if a.no_checks else list(pool.map(lambda c: extra(*c, rows), [
            ("half_speed", [*BRITTLE, "compression.plate_speed_m_s=0.05"]), ("smooth", ["bonds.smooth=true"])]))
    errors = [abs(r["strength_error"]) for r in rows]
    out = {**machine(), "wall_s": time.perf_counter() - t, "rows": rows, "checks": checks,
           "strength_error_max": max(errors), "strength_error_mean": float(np.mean(errors)),
           "within_10_percent": sum(e <= 0.10 for e in errors), "cases": len(rows)}
    (RESULTS / "aerogel_strength_validation.json").write_text(json.dumps(out, indent=1) + "\n")
    return out


def densify(a) -> dict:
    """One restructured slab (2 000 spheres, solid fraction 0.12, seed 1) compressed by LAMMPS to 35 % strain with
    its Hertz-Mindlin contacts, bonds breaking at full load: the curve through the peak, the plateau and the
    contacts' stiffening; docs/figures/aerogel_densification.png."""
    from opalflow.store import new_figure, save_figure

    out = Path(a.runs) / "densify"
    sets = ["aggregate.loops=restructuring", "aggregate.solid_fraction=0.12", "aggregate.seed=1", *BRITTLE,
            "compression.strain_max=0.35", "compression.snapshot_strains=[0.1, 0.3]",
            "compression.output_every_strain=0.002", "compression.restart_every_strain=0.05"]
    t = time.perf_counter()
    summary = run(out, sets)
    with h5py.File(out / "results.h5", "r") as h:
        e, s, broken = h["curve/strain"][()], h["curve/stress_MPa"][()] * 1e3, h["curve/broken_bonds"][()]
    k = int(np.argmax(s))
    post = e > e[k]
    plateau = (e >= 0.15) & (e <= 0.3)
    tail = e >= 0.3
    row = {**machine(), "sets": sets, "wall_s": summary["wall_s"], "bench_s": time.perf_counter() - t,
           "particles": summary["n_particles"], "bonds": summary["n_bonds"], "E_kPa": summary["youngs_modulus_GPa"] * 1e6,
           "peak_kPa": float(s[k]), "strain_at_peak": float(e[k]),
           "plateau_kPa_0.15_0.3": float(np.mean(s[plateau])) if plateau.any() else None,
           "stress_kPa_0.3_0.35": float(np.mean(s[tail])) if tail.any() else None,
           "min_after_peak_kPa": float(s[post].min()) if post.any() else None,
           "broken_bonds_at_peak": int(broken[k]), "broken_bonds_end": int(broken[-1]), "strain_end": float(e[-1])}
    fig, ax = new_figure(figsize=(6.4, 4.2))
    ax.plot(e, s, "-", color="C0", lw=1, label="stress (LAMMPS, bpm/rotational + Hertz-Mindlin contacts)")
    ax.plot([e[k]], [s[k]], "o", color="C3", label=f"peak {s[k]:.3g} kPa at strain {e[k]:.3f}")
    ax.set_xlabel("strain")
    ax.set_ylabel("stress (kPa)")
    ax2 = ax.twinx()
    ax2.plot(e, broken, ":", color="C2", lw=1)
    ax2.set_ylabel("bonds broken", color="C2")
    ax.set_title(f"restructured DLCA slab, solid fraction 0.12, {summary['n_particles']} spheres, wall 0.1 m/s",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, ROOT / "docs" / "figures" / "aerogel_densification.png")
    (RESULTS / "aerogel_densification.json").write_text(json.dumps(row, indent=1) + "\n")
    return row


def nonlinear(a) -> dict:
    """The nonlinear quasi-static method (``compression.geometry = "nonlinear"``) on the validation slabs with its
    Hertz-Mindlin contacts (the LAMMPS runs' own), and without contacts beside LAMMPS without contacts
    (``contacts.enabled = false``) on one seed per density and the tree at 0.03 seed 2 (the bond law's check: the
    same bonds, nothing else; ``report`` puts both in the table)."""
    root = Path(a.runs) / "validate"
    cases = [(series, phi, seed) for series in a.series for phi in FRACTIONS for seed in SEEDS] + [("none", 0.03, 2)]
    bare = [("restructuring", 0.03, 1), ("restructuring", 0.06, 3), ("restructuring", 0.12, 3), ("none", 0.03, 2)]

    def contactless(case):
        base, sets = slab(root, *case)
        qs = finished(base.with_name(f"{base.name}_nonlinear"))
        reach = min(QS_STRAIN_MAX, round(1.25 * (qs["strain_at_peak"] or 0.3) + 0.01, 3))
        out = base.with_name(f"{base.name}_dynamic_nocontact")
        return run(out, [*sets, *BRITTLE, "contacts.enabled=false", f"compression.strain_max={reach}",
                         "compression.snapshot_strains=[]"])

    def one(case, contacts=True):
        base, sets = slab(root, *case)
        out = base.with_name(f"{base.name}_nonlinear" + ("_contacts" if contacts else ""))
        summary = run(out, [*sets, *BRITTLE, "compression.method=quasistatic", "compression.geometry=nonlinear",
                            f"compression.strain_max={QS_STRAIN_MAX}", f"contacts.enabled={str(contacts).lower()}"])
        print(json.dumps({"case": case, "contacts": contacts, "strength_kPa": (summary["strength_MPa"] or 0) * 1e3,
                          "stopped": summary["quasistatic"]["stopped"], "wall_s": summary["wall_s"]}), flush=True)
        return summary

    t = time.perf_counter()
    with ThreadPoolExecutor(a.workers) as pool:
        got = list(pool.map(one, cases))
        got += list(pool.map(lambda c: one(c, False), bare))
        got += list(pool.map(contactless, bare))
    return {"runs": len(got), "wall_s": time.perf_counter() - t}


def extend(a) -> dict:
    """LAMMPS again, twice as far (to QS_STRAIN_MAX at most), on the validation slabs whose dynamic run ended
    before a collapse (its strength then a lower bound): RUNS/validate/NAME_dynamic_long, which ``report`` reads in
    its place."""
    root = Path(a.runs) / "validate"
    todo = []
    for case in [(series, phi, seed) for series in SERIES for phi in FRACTIONS for seed in SEEDS]:
        base, sets = slab(root, *case)
        short = base.with_name(f"{base.name}_dynamic")
        if summary := finished(short):
            d = at_peak(short, summary)
            if not d["collapsed"]:
                reach = min(QS_STRAIN_MAX, round(2 * d["strain_end"], 3))
                todo.append((base.with_name(f"{base.name}_dynamic_long"),
                             [*sets, *BRITTLE, f"compression.strain_max={reach}", "compression.snapshot_strains=[]"]))
    t = time.perf_counter()
    with ThreadPoolExecutor(a.workers) as pool:
        got = list(pool.map(lambda job: run(*job), todo))
    return {"runs": len(got), "wall_s": time.perf_counter() - t}


def study(a) -> dict:
    """workflows/WORKFLOW.toml (``--workflow``: aerogel_strength, the nonlinear method; aerogel_strength_linear, the
    linear one on 20 000-sphere slabs) run into RUNS/WORKFLOW (kept: a rerun reads it), its summary and report
    copied to bench/results/WORKFLOW.json and .md with the machine and the wall time of the run that computed its
    jobs."""
    out = Path(a.runs) / a.workflow
    summary = run(out, [], workflow=a.workflow)
    row = {**machine(), "load": a.load, **summary, "job_costs": job_costs(out)}
    (RESULTS / f"{a.workflow}.json").write_text(json.dumps(row, indent=1) + "\n")
    (RESULTS / f"{a.workflow}.md").write_text((out / "report.md").read_text())
    return {k: summary[k] for k in ("modulus_exponent", "modulus_exponent_ci95", "strength_exponent",
                                    "strength_exponent_ci95", "wall_s")}


def job_costs(out: Path) -> list[dict]:
    """Each finished job's size, wall time, events and peak memory (what ``plan`` prices the method's jobs by)."""
    from opalflow.runs.jobs import job_record

    rows = []
    for p in sorted(out.glob("jobs/*/summary.json")):
        s, rec = json.loads(p.read_text()), job_record(p.parent)
        rows.append({"label": rec.label or p.parent.name, "n_bonds": s["n_bonds"], "wall_s": s["wall_s"],
                     "events": s.get("quasistatic", {}).get("events", 0), "peak_MiB": rec.peak_rss_MiB})
    return rows


def finished(out: Path) -> dict | None:
    p = out / "summary.json"
    summary = json.loads(p.read_text()) if p.exists() else None
    return summary if summary and summary.get("state") == "finished" else None


def report(a) -> dict:
    """The validation table from the run folders that finished (all of ``validate``'s or, stopped early, those
    done): bench/results/aerogel_strength_validation.json (``partial``: true where some are missing) and .md."""
    root = Path(a.runs) / "validate"
    # what is not here (``validate --no-checks``; the runs without contacts, ``nonlinear`` stopped before them) is
    # taken from the last table with its date
    stored = RESULTS / "aerogel_strength_validation.json"
    last = json.loads(stored.read_text()) if stored.exists() else {"checks": [], "rows": []}
    rows = []
    for series in SERIES:
        for phi in FRACTIONS:
            for seed in SEEDS:
                base, _ = slab(root, series, phi, seed)
                runs = {m: base.with_name(f"{base.name}_{m}") for m in ("quasistatic", "static", "dynamic")}
                if finished(base.with_name(f"{base.name}_dynamic_long")):         # ``extend``'s
                    runs["dynamic"] = base.with_name(f"{base.name}_dynamic_long")
                got = {m: finished(out) for m, out in runs.items()}
                if not all(got.values()):
                    continue
                row = {"series": series, "solid_fraction": phi, "seed": seed, "particles": got["static"]["n_particles"],
                       "bonds": got["static"]["n_bonds"], "density_kg_m3": got["static"]["density_kg_m3"],
                       **{m: at_peak(runs[m], got[m]) for m in runs}}
                row["strength_error"] = row["quasistatic"]["strength_kPa"] / row["dynamic"]["strength_kPa"] - 1
                bare = base.with_name(f"{base.name}_dynamic_nocontact")
                if finished(bare):
                    row["dynamic_nocontact"] = at_peak(bare, finished(bare))
                for key, tail in (("nonlinear", "_nonlinear_contacts"), ("nonlinear_nocontact", "_nonlinear")):
                    nl = base.with_name(base.name + tail)
                    if summary := finished(nl):
                        row[key] = at_peak(nl, summary)
                        q = summary["quasistatic"]
                        row[key]["stopped"] = q["stopped"]
                        row[key]["out_of_balance"] = [q.get("out_of_balance_states", 0),
                                                      q.get("out_of_balance_max", 0.0)]
                if "nonlinear" in row:
                    row["nonlinear_error"] = row["nonlinear"]["strength_kPa"] / row["dynamic"]["strength_kPa"] - 1
                    row["first_break_error"] = (row["nonlinear"]["first_break_kPa"]
                                                / row["dynamic"]["first_break_kPa"] - 1)
                if "dynamic_nocontact" in row and "nonlinear_nocontact" in row:
                    row["nonlinear_error_nocontact"] = (row["nonlinear_nocontact"]["strength_kPa"]
                                                        / row["dynamic_nocontact"]["strength_kPa"] - 1)
                else:
                    row.pop("dynamic_nocontact", None)
                    row.pop("nonlinear_nocontact", None)
                    before = [r for r in last["rows"] if "nonlinear_error_nocontact" in r
                              and (r["series"], r["solid_fraction"], r["seed"]) == (series, phi, seed)]
                    if before:
                        row.update({k: before[0][k] for k in ("dynamic_nocontact", "nonlinear_nocontact",
                                                              "nonlinear_error_nocontact")},
                                   nocontact_measured=before[0].get("nocontact_measured", last.get("date")))
                rows.append(row)
    checks = []
    for name in ("half_speed", "smooth"):
        base, _ = slab(root, a.series[0], FRACTIONS[0], SEEDS[0])
        out = base.with_name(f"{base.name}_{name}")
        if finished(out):
            checks.append({"series": a.series[0], "solid_fraction": FRACTIONS[0], "seed": SEEDS[0], "case": name,
                           **at_peak(out, finished(out))})
        else:
            checks += [{"measured": last.get("date"), **c} for c in last["checks"] if c["case"] == name]
    errors = [abs(r["strength_error"]) for r in rows]
    nl_errors = [abs(r["nonlinear_error"]) for r in rows if "nonlinear_error" in r]
    first_errors = [abs(r["first_break_error"]) for r in rows if "first_break_error" in r]
    stopped = sum(math.isnan(e) for e in nl_errors)              # the nonlinear runs that stopped before a break
    nl_errors = [e for e in nl_errors if not math.isnan(e)]
    first_errors = [e for e in first_errors if not math.isnan(e)]
    v = {**machine(), "rows": rows, "checks": checks, "partial": len(rows) < len(a.series) * 9 or len(checks) < 2,
         "strength_error_max": max(errors), "strength_error_mean": float(np.mean(errors)),
         "within_10_percent": sum(e <= 0.10 for e in errors), "cases": len(rows),
         "nonlinear_error_max": max(nl_errors, default=None),
         "nonlinear_within_10_percent": sum(e <= 0.10 for e in nl_errors), "nonlinear_cases": len(nl_errors),
         # the rows whose LAMMPS run collapsed (elsewhere its strength is a bound: the run ended first)
         "lammps_collapsed": sum(r["dynamic"].get("collapsed", True) for r in rows),
         "nonlinear_within_10_percent_where_lammps_collapsed": sum(
             abs(r.get("nonlinear_error", math.nan)) <= 0.10 for r in rows if r["dynamic"].get("collapsed", True)),
         "first_break_error_max": max(first_errors, default=None),
         "first_break_within_10_percent": sum(e <= 0.10 for e in first_errors), "nonlinear_stopped_before_a_break": stopped}
    (RESULTS / "aerogel_strength_validation.json").write_text(json.dumps(v, indent=1) + "\n")
    lines = ["| slab | spheres | E static / LAMMPS 0.5-2 % (kPa) | LAMMPS: strength (kPa), strain, bonds broken "
             "before | linear quasi-static: strength (error) | nonlinear + contacts: strength (error), strain | "
             "LAMMPS's first break (kPa), strain | nonlinear's first break (error) | without contacts: LAMMPS, "
             "nonlinear (error) | cost LAMMPS / linear / nonlinear (s) |", "|" + "---|" * 10]

    def kpa(x):
        return f"{x:.3g}"

    for r in v["rows"]:
        d, q, n = r["dynamic"], r["quasistatic"], r.get("nonlinear")
        bare = (f"{kpa(r['dynamic_nocontact']['strength_kPa'])}, {kpa(r['nonlinear_nocontact']['strength_kPa'])} "
                f"({r['nonlinear_error_nocontact']:+.1%})" + (f" (run {r['nocontact_measured']}, not repeated)"
                                                               if "nocontact_measured" in r else "")
                if "nonlinear_error_nocontact" in r else "-")
        lines.append(
            f"| {r['series']} {r['solid_fraction']} s{r['seed']} | {r['particles']} | {kpa(r['static']['E_kPa'])} / "
            f"{kpa(d['tangent_kPa'])} | {kpa(d['strength_kPa'])}, {d['strain_at_peak']:.3f}, {d['broken_at_peak']}"
            + (f" (largest of the run {kpa(d['largest_kPa'])} at {d['strain_at_largest']:.3f})"
               if d.get("largest_kPa", d["strength_kPa"]) > 1.01 * d["strength_kPa"] else "")
            + ("" if d.get("collapsed", True) else f" (no collapse by the run's end at {d['strain_end']:.3f})")
            + " | "
            f"{kpa(q['strength_kPa'])} ({r['strength_error']:+.1%}) | "
            + (f"{kpa(n['strength_kPa'])} ({r['nonlinear_error']:+.1%}), {n['strain_at_peak']:.3f}"
               + (f"; {n['out_of_balance'][0]} state{'s' * (n['out_of_balance'][0] > 1)} out of balance "
                  f"(max {n['out_of_balance'][1]:.1g})"
                  if n.get("out_of_balance", [0])[0] else "") + " | "
               if n and not math.isnan(n["strength_kPa"]) else f"stopped: {n['stopped']} | " if n else "- | ")
            + f"{kpa(d['first_break_kPa'])}, {d['strain_at_first_break']:.3f} | "
            + (f"{kpa(n['first_break_kPa'])} ({r['first_break_error']:+.1%}) | "
               if n and not math.isnan(n["strength_kPa"]) else "- | ")
            + f"{bare} | {d['wall_s']:.0f} / {q['wall_s']:.1f} / " + (f"{n['wall_s']:.0f} |" if n else "- |"))
    for c in v["checks"]:
        lines.append(f"\nCheck `{c['case']}` ({c['series']}, {c['solid_fraction']}, seed {c['seed']}): strength "
                     f"{c['strength_kPa']:.4g} kPa at strain {c['strain_at_peak']:.4f}, {c['wall_s']:.0f} s"
                     + (f" (run {c['measured']}, not repeated)." if "measured" in c else "."))
    text = "\n".join(lines) + "\n"
    (RESULTS / "aerogel_strength_validation.md").write_text(text)
    print(text)
    return {"rows": len(v["rows"])}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("part", choices=["validate", "nonlinear", "extend", "study", "densify", "report"])
    p.add_argument("--runs", default="runs/bench_aerogel_strength", help="folder of the runs (kept: rerun reads them)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--no-checks", action="store_true",
                   help="validate: leave out the half-speed and smooth LAMMPS runs (~30 min; report keeps the last)")
    p.add_argument("--fractions", nargs="+", type=float, default=FRACTIONS, help="validate: solid fractions")
    p.add_argument("--seeds", nargs="+", type=int, default=SEEDS, help="validate: seeds")
    p.add_argument("--workflow", default="aerogel_strength", choices=["aerogel_strength", "aerogel_strength_linear"],
                   help="study: the workflow")
    p.add_argument("--load", default="", help="what else ran on the machine meanwhile (recorded with the study)")
    p.add_argument("--series", nargs="+", default=["restructuring"], choices=SERIES,
                   help="loop models (a tree at 0.03 breaks near 25 %% strain: 10-20 min of LAMMPS a slab)")
    a = p.parse_args(argv)
    out = {"validate": validate, "nonlinear": nonlinear, "extend": extend, "study": study, "densify": densify,
           "report": report}[a.part](a)
    print(json.dumps({k: v for k, v in out.items() if not isinstance(v, list)}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
