"""``python -m opalflow plan WORKFLOW``: what a run or a study will cost before it is submitted.

The jobs are the ones the workflow would run (a study's from its type's ``jobs`` hook,
:data:`opalflow.studies.spec.STUDY_TYPES`); each is priced by its kind's ``cost`` facts
(particles, bonds, time steps: the structure is built, nothing is written) and by the cost laws measured on
this kind of machine (``bench/bench_cost.py`` -> ``bench/results/cost_laws.json``):

- every job: the structure and deck build, timed here while the plan builds the job's structure;
- static solve: c * bonds^p of its solver (``auto``'s choice: opalflow.bpm.static.auto_solver), fitted to
  ``bench/results/static_quickstart.json`` (d = 60-20 nm), plus the outputs (a + b * bonds);
- dynamic run: steps * bonds * t_bond (bpm/rotational; bpm/spring ``spring_factor`` times cheaper per
  bond), divided by the MPI ranks at the measured efficiency, plus the analysis;
- quasi-static run: the wall time and peak memory of the whole runs measured with the job's breaking rule
  and event tolerance (``bench/results/quasistatic_scale.json``: the standard sample at d = 60-15 nm, the
  fastest setting at each size), interpolated in bonds on log-log axes (extrapolated beyond by the end
  segments), plus the build; where none was measured, its first solve (a lower bound);
- peak memory: m0 + m1 * bonds per job (resident set of the job's process and its LAMMPS; for
  ``block-amg`` the solver's own law).

It prints a line per job, the totals (core-hours, the longest job) and the SLURM resources the array
would ask for (memory and time with a margin), and with ``--measured DIR`` the measured figures of a
finished run or study beside the predicted ones.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from opalflow import registry
from opalflow.resources import ROOT
from opalflow.runs.jobs import Job, job_record
from opalflow.runs.record import read_summary
from opalflow.spec import SpecError
from opalflow.store import RECORD

LAWS = ROOT / "bench" / "results" / "cost_laws.json"
SOLVERS = ROOT / "bench" / "results" / "static_quickstart.json"
QUASISTATIC = ROOT / "bench" / "results" / "quasistatic_scale.json"
#: SLURM asks for this much more than predicted (memory and time)
MARGIN = 1.5


def laws() -> dict:
    """The cost laws (bench/bench_cost.py) with the static solvers' laws (bench/bench_static.py): per solver,
    solve seconds = c * bonds^p and solver memory = m0 + m1 * bonds, fitted to the measured rows."""
    import numpy as np

    for path, bench in ((LAWS, "bench_cost.py"), (SOLVERS, "bench_static.py")):
        if not path.exists():
            raise SpecError("plan", str(path), f"no cost laws measured yet: run python bench/{bench}")
    law = json.loads(LAWS.read_text())
    rows = json.loads(SOLVERS.read_text())["rows"]
    law["solvers"] = {}
    for solver in sorted({r["solver"] for r in rows}):
        mine = [r for r in rows if r["solver"] == solver]
        b = np.array([r["n_bonds"] for r in mine], float)
        p, logc = np.polyfit(np.log(b), np.log([r["total_s"] for r in mine]), 1)
        m1, m0 = np.polyfit(b, [1024 * r["peak_memory_GiB"] for r in mine], 1)
        law["solvers"][solver] = {"c": float(np.exp(logc)), "p": float(p), "m0_MiB": float(m0), "m1_MiB": float(m1)}
    law["quasistatic"] = quasistatic_runs()
    return law


def quasistatic_runs() -> dict[str, list[dict]]:
    """"breaking rule, event tolerance" -> the fastest complete quasi-static run at each size (bonds, wall_s,
    peak_MiB, events, diameter_nm), from bench/results/quasistatic_scale.json (none: {})."""
    if not QUASISTATIC.exists():
        return {}
    best: dict[tuple, dict] = {}
    for r in json.loads(QUASISTATIC.read_text())["rows"]:
        if not r.get("complete") or not r.get("wall_s"):
            continue
        key = (f"{r.get('breaking', 'lammps')}, {r['tolerance']:g}", r["n_bonds"])
        if key not in best or r["wall_s"] < best[key]["wall_s"]:
            best[key] = {"bonds": r["n_bonds"], "wall_s": r["wall_s"], "events": r["events"],
                         "diameter_nm": r["diameter_nm"],
                         "peak_MiB": 1024 * r["peak_memory_GiB"] if r.get("peak_memory_GiB") else None}
    runs: dict[str, list[dict]] = {}
    for (setting, _), row in sorted(best.items(), key=lambda kv: kv[0][1]):
        runs.setdefault(setting, []).append(row)
    return runs


def _loglog(x: float, xs: list[float], ys: list[float]) -> float:
    """y at x by straight lines between the points (xs, ys) on log-log axes, the end segments beyond them
    (one point: y itself)."""
    import numpy as np

    lx, ly = np.log(xs), np.log(ys)
    if len(xs) == 1:
        return float(ys[0])
    k = int(np.clip(np.searchsorted(lx, np.log(x)) - 1, 0, len(xs) - 2))
    slope = (ly[k + 1] - ly[k]) / (lx[k + 1] - lx[k])
    return float(np.exp(ly[k] + slope * (np.log(x) - lx[k])))


def jobs_of(spec) -> list[Job]:
    """The jobs ``spec`` would run: its kind's (:attr:`opalflow.registry.Kind.jobs`: a study's), else the run
    itself."""
    kind = registry.get(spec.kind)
    return registry.resolve(kind.jobs)(spec) if kind.jobs else [Job(spec.name, spec)]


def predict(facts: dict, law: dict, ranks: int = 1) -> dict:
    """Wall seconds, core-seconds and peak memory (MiB) of one job with these facts: the build as timed by
    the plan, plus the solve (static: the solver's law) or the time steps (dynamic), plus the outputs."""
    bonds = max(facts["n_bonds"], 1)
    if facts["method"] in ("static", "quasistatic"):      # quasistatic: its first solve, unless measured runs
        sv, st = law["solvers"][facts["solver"]], law["static"]
        wall = facts["build_s"] + sv["c"] * bonds ** sv["p"] + st["rest_s0"] + st["rest_s_per_bond"] * bonds
        mem = law["static_memory"]["m0_MiB"] + (law["static_memory"]["m1_MiB"] * bonds if facts["solver"] == "amg"
                                                 else sv["m0_MiB"] + sv["m1_MiB"] * bonds)
        runs = law.get("quasistatic", {}).get(f"{facts.get('breaking')}, {facts.get('event_tolerance', 0):g}")
        if facts["method"] == "quasistatic" and runs:
            sizes = [r["bonds"] for r in runs]
            wall = facts["build_s"] + _loglog(bonds, sizes, [r["wall_s"] for r in runs])
            with_memory = [r for r in runs if r["peak_MiB"]]
            if with_memory:
                mem = _loglog(bonds, [r["bonds"] for r in with_memory], [r["peak_MiB"] for r in with_memory])
            return {"wall_s": wall, "core_s": wall * ranks, "peak_MiB": mem, "priced_by": "measured runs",
                    "events": max(1, round(_loglog(bonds, sizes, [r["events"] for r in runs])))}
    else:
        dyn = law["dynamic"]
        per_bond = dyn["s_per_bond_step"] / (dyn["spring_factor"] if facts.get("bond_model") == "spring" else 1.0)
        lammps = facts["steps"] * bonds * per_bond / (ranks * dyn["mpi_efficiency"] if ranks > 1 else 1.0)
        wall = facts["build_s"] + dyn["lammps_start_s"] + lammps + dyn["rest_s"]
        mem = law["dynamic_memory"]["m0_MiB"] + law["dynamic_memory"]["m1_MiB"] * bonds
    return {"wall_s": wall, "core_s": wall * ranks, "peak_MiB": mem}


def _sample(n: int, k: int) -> list[int]:
    if k <= 0 or k >= n:
        return list(range(n))
    return sorted({round(i * (n - 1) / (k - 1)) for i in range(k)}) if k > 1 else [0]


def _between(costs: dict[int, dict], i: int) -> dict:
    """The facts of job ``i``: its own where it was built, else interpolated in the job's index between the
    built jobs on either side (a study's jobs run along its parameter), the nearest one beyond the ends."""
    if i in costs:
        return costs[i]
    lo = max((k for k in costs if k < i), default=None)
    hi = min((k for k in costs if k > i), default=None)
    if lo is None or hi is None:
        return costs[lo if hi is None else hi]
    w = (i - lo) / (hi - lo)
    out = dict(costs[lo])
    for key, a in costs[lo].items():
        b = costs[hi].get(key)
        if isinstance(a, (int, float)) and not isinstance(a, bool) and isinstance(b, (int, float)):
            out[key] = type(a)(a + w * (b - a)) if isinstance(a, float) else round(a + w * (b - a))
    if out["method"] == "static" and costs[lo].get("solver") != costs[hi].get("solver"):
        out["solver"] = costs[lo if w < 0.5 else hi]["solver"]
    return out


def measured(folder: Path, label: str, single: bool) -> dict | None:
    job = folder if single else next(iter(sorted(folder.glob(f"jobs/{label}-*"))), None)
    if job is None:
        return None
    s = read_summary(job)
    if not s or s.get("state") == "built":
        return None
    rec = job_record(job)
    wall, peak = s.get("wall_s"), rec.peak_rss_MiB if rec is not None else None
    number = lambda x: x if isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0 else None  # noqa: E731
    return {"wall_s": number(wall), "peak_MiB": number(peak)}


def plan(spec, *, ranks: int = 1, sample: int = 3, against: Path | None = None, say=print) -> dict:
    """Price the jobs of ``spec`` (``sample`` of a study's jobs are built, spread from the first to the last;
    the others are interpolated between them) and return rows and totals."""
    if isinstance(sample, bool) or not isinstance(sample, int) or sample < 0:
        raise SpecError("--sample", sample, "must be an integer >= 0 (0: build every job)")
    if against is not None and not (Path(against).is_dir() and (Path(against) / RECORD).exists()):
        raise SpecError("--measured", str(against), f"is not a run or study folder (it has no {RECORD})")
    law = laws()
    kind = registry.get(spec.kind)
    jobs = jobs_of(spec)
    if not jobs:
        raise SpecError("workflow", spec.name, "has no jobs to plan")
    costs = {}
    for j in jobs:
        k = registry.get(j.spec.kind)
        if not k.cost:
            raise SpecError("kind", j.spec.kind, "has no cost model yet (plan prices bonded-particle runs)")
    picked = _sample(len(jobs), sample)
    for i in picked:
        say(f"plan: building {jobs[i].label} ({i + 1}/{len(jobs)}) for its size")
        costs[i] = registry.resolve(registry.get(jobs[i].spec.kind).cost)(jobs[i].spec)
    rows = []
    for i, j in enumerate(jobs):
        facts = _between(costs, i)
        row = {"label": j.label, "built": i in costs, **facts, **predict(facts, law, ranks)}
        if against is not None:
            row["measured"] = measured(Path(against), j.label, single="executor" not in kind.options)
        rows.append(row)
    total_core_h = sum(r["core_s"] for r in rows) / 3600
    longest = max(r["wall_s"] for r in rows)
    peak = max(r["peak_MiB"] for r in rows)
    slurm = {"ntasks": ranks, "mem": f"{math.ceil(MARGIN * peak / 1024)}G",
             "time_min": max(1, math.ceil(MARGIN * longest / 60)), "array": f"0-{len(rows) - 1}"}
    return {"workflow": spec.name, "kind": spec.kind, "jobs": rows, "core_hours": total_core_h,
            "longest_job_s": longest, "peak_MiB": peak, "slurm": slurm, "machine": law.get("machine", {}),
            "laws_measured": law.get("date", "")}


def plan_lines(p: dict) -> list[str]:
    lines = [f"plan {p['workflow']} ({p['kind']}, {len(p['jobs'])} job(s); cost laws of {LAWS.name}, measured "
             f"{p['laws_measured']} on {p['machine'].get('cpus', '?')} cores)",
             f"  {'job':<22} {'method':<11} {'particles':>10} {'bonds':>11} {'steps':>8} {'wall (s)':>10} "
             f"{'core-s':>10} {'memory':>10}" + ("   measured wall / memory" if any("measured" in r for r in p["jobs"])
                                                 else "")]
    for r in p["jobs"]:
        m = r.get("measured")
        meas = ""
        if m:
            err = f" ({100 * (r['wall_s'] / m['wall_s'] - 1):+.0f} %)" if m.get("wall_s") else ""
            mem = (f"{m['peak_MiB']:.0f} MiB ({100 * (r['peak_MiB'] / m['peak_MiB'] - 1):+.0f} %)"
                   if m.get("peak_MiB") else "-")
            meas = f"   {m['wall_s']:.1f} s{err} / {mem}" if m.get("wall_s") else "   -"
        lines.append(f"  {r['label']:<22} {r['method']:<11} {r['n_particles']:>10} {r['n_bonds']:>11} "
                     f"{r.get('steps', '-'):>8} {r['wall_s']:>10.1f} {r['core_s']:>10.1f} "
                     f"{r['peak_MiB'] / 1024:>8.2f} GiB{'' if r['built'] else ' ~'}{meas}")
    s = p["slurm"]
    lines += [f"total: {p['core_hours']:.3g} core-hours; longest job {p['longest_job_s']:.0f} s "
              f"({p['longest_job_s'] / 3600:.2f} h); peak memory {p['peak_MiB'] / 1024:.2f} GiB per job "
              "(~: job interpolated between built ones)",
              f"SLURM (x{MARGIN} margin): --array={s['array']} --ntasks={s['ntasks']} --mem={s['mem']} "
              f"--time={s['time_min']}  ([executor] type = \"slurm\", mem_gb, time_min)"]
    if any(r["method"] == "quasistatic" and r.get("priced_by") for r in p["jobs"]):
        events = [r["events"] for r in p["jobs"] if "events" in r]
        lines.append("quasistatic jobs are priced by the whole runs measured with their breaking rule and event "
                     f"tolerance ({QUASISTATIC.name}: the standard sample's events, {min(events)}-{max(events)} "
                     "here; a study's pores or coatings change how many events a run takes)")
    if any(r["method"] == "quasistatic" and not r.get("priced_by") for r in p["jobs"]):
        lines.append("quasistatic jobs are priced as their first solve, a lower bound: each broken bond costs a "
                     "re-solve and their number is not known before the run")
    return lines
