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
  fastest setting at each size; and the jobs of the paper-scale porosity studies,
  ``bench/results/porosity_paper_d*.json``, each its own size, those that ran alone and in one session),
  interpolated in bonds on log-log axes (extrapolated beyond by the end segments), plus the build; where none
  was measured, its first solve (a lower bound);
- geometrically nonlinear quasi-static run (``compression.geometry = "nonlinear"``): the mean wall time per bond
  of the jobs of the aerogel strength study (``bench/results/aerogel_strength.json``, ``job_costs``: 2 000-sphere
  slabs) times the job's bonds, plus the build; their spread (13-638 s) is each slab's own breaks, so the longest
  job (the SLURM time) is priced by the slowest of them per bond;
- peak memory: m0 + m1 * bonds per job (resident set of the job's process and its LAMMPS; for
  ``block-amg`` the solver's own law).

It prints a line per job, the totals (core-hours, the longest job) and the SLURM resources the array
would ask for (memory and time with a margin), and with ``--measured DIR`` the measured figures of a
finished run or study beside the predicted ones.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from opalflow import registry
from opalflow.resources import ROOT
from opalflow.runs.jobs import Job, job_record
from opalflow.runs.result import read_summary
from opalflow.spec import SpecError
from opalflow.store import RECORD

LAWS = ROOT / "bench" / "results" / "cost_laws.json"
SOLVERS = ROOT / "bench" / "results" / "static_quickstart.json"
QUASISTATIC = ROOT / "bench" / "results" / "quasistatic_scale.json"
#: the paper-scale porosity studies' records (bench/bench_porosity_paper.py), one a particle diameter, and their
#: resolution table (``--resolution``)
STUDY_RECORDS = "porosity_paper_d*.json"
RESOLUTION = ROOT / "bench" / "results" / "porosity_resolution.json"
NONLINEAR = ROOT / "bench" / "results" / "aerogel_strength.json"
#: SLURM asks for this much more than predicted (memory and time)
MARGIN = 1.5


@dataclass
class MemoryLaw:
    """Peak memory = m0 + m1 * bonds (MiB)."""

    m0_MiB: float
    m1_MiB: float

    def at(self, bonds: float) -> float:
        return self.m0_MiB + self.m1_MiB * bonds


@dataclass
class SolverLaw(MemoryLaw):
    """A static solver: solve seconds = c * bonds^p, its memory as :class:`MemoryLaw`."""

    c: float = 0.0
    p: float = 0.0


@dataclass
class StaticRest:
    """The static solve's outputs: rest_s0 + rest_s_per_bond * bonds seconds."""

    rest_s0: float
    rest_s_per_bond: float


@dataclass
class DynamicLaw:
    """A LAMMPS run: seconds per bond and step (bpm/rotational; bpm/spring ``spring_factor`` times cheaper), the
    start and the analysis, and the MPI efficiency."""

    s_per_bond_step: float
    lammps_start_s: float
    rest_s: float
    spring_factor: float
    mpi_efficiency: float


@dataclass
class MeasuredRun:
    """A whole quasi-static run measured (bench/results/quasistatic_scale.json), the fastest at its size."""

    bonds: int
    wall_s: float
    events: int
    diameter_nm: float
    peak_MiB: float | None
    #: the cores the run had (the measuring machine's: a quasi-static run threads its solves over all of them)
    cores: int = 1


@dataclass
class CostLaws:
    """The cost laws of this kind of machine (bench/bench_cost.py, bench/bench_static.py, the quasi-static runs)."""

    date: str
    machine: dict
    static: StaticRest
    static_memory: MemoryLaw
    dynamic: DynamicLaw
    dynamic_memory: MemoryLaw
    solvers: dict[str, SolverLaw] = field(default_factory=dict)
    #: "breaking rule, event tolerance" -> the measured runs, by size
    quasistatic: dict[str, list[MeasuredRun]] = field(default_factory=dict)
    #: the nonlinear method's jobs measured (the aerogel strength study's)
    nonlinear: list[MeasuredRun] = field(default_factory=list)


@dataclass
class CostFacts:
    """What a job is priced by (a kind's ``cost`` hook): its method, size and what the method adds, and the
    seconds its structure took to build here."""

    method: str
    n_particles: int
    n_bonds: int
    build_s: float = 0.0
    bond_model: str = "parallel"
    steps: int | None = None               # a dynamic run's time steps
    solver: str | None = None              # a solve's solver
    breaking: str | None = None            # a quasi-static run's rule and event tolerance
    event_tolerance: float | None = None
    geometry: str | None = None            # a quasi-static run's: "linear" or "nonlinear"


@dataclass
class Prediction:
    wall_s: float
    core_s: float
    peak_MiB: float
    priced_by: str | None = None           # "measured runs": a quasi-static job priced by whole runs
    events: int | None = None
    wall_max_s: float | None = None        # where jobs alike differ (the nonlinear method's): the slowest measured


@dataclass
class Measured:
    """What a finished job of ``--measured DIR`` took (None: not known)."""

    wall_s: float | None
    peak_MiB: float | None


@dataclass
class PlanRow:
    label: str
    built: bool                            # its structure built (else interpolated between the built ones)
    facts: CostFacts
    prediction: Prediction
    measured: Measured | None = None


@dataclass
class Plan:
    workflow: str
    kind: str
    jobs: list[PlanRow]
    core_hours: float
    longest_job_s: float
    peak_MiB: float
    slurm: dict
    machine: dict
    laws_measured: str
    #: a paper-scale porosity study: the coarsest resolution measured to give the paper's resolution's exponents
    #: (:func:`cheapest_resolution`), a line of text; "" otherwise
    resolution: str = ""


def cheapest_resolution(spec) -> str:
    """For a porosity study at paper scale: what the resolution table (:data:`RESOLUTION`, bench/bench_porosity_paper.py
    --resolution) says of the coarsest particle diameter whose fits of eqs. 22 and 23 (b_E and m) fall inside the
    finest's 95 % intervals, and what a job costs there; "" for any other workflow or where none is measured."""
    st = getattr(spec, "study", None)
    if st is None or st.type != "porosity" or not st.paper_scale or not RESOLUTION.exists():
        return ""
    table = json.loads(RESOLUTION.read_text())
    ref = table["reference_diameter_nm"]
    tried = "; ".join(f"{r['diameter_nm']:g} nm: {r['jobs']} jobs{'' if r['inside'] else ', outside'}"
                      for r in table["rows"][1:])
    if table["cheapest_diameter_nm"] is None:
        return (f"resolution ({RESOLUTION.name}): no coarser particle diameter measured ({tried}) gives the "
                f"d = {ref:g} nm study's b_E and m within their 95 % intervals")
    return (f"resolution ({RESOLUTION.name}): d = {table['cheapest_diameter_nm']:g} nm is the coarsest measured "
            f"({tried}) whose b_E and m fall within the d = {ref:g} nm study's 95 % intervals, at "
            f"{table['cheapest_cost_ratio']:.2g} of a d = {ref:g} nm job's wall time: --set "
            f"study.diameter_nm={table['cheapest_diameter_nm']:g}")


def laws() -> CostLaws:
    """The cost laws (bench/bench_cost.py) with the static solvers' laws (bench/bench_static.py): per solver,
    solve seconds = c * bonds^p and solver memory = m0 + m1 * bonds, fitted to the measured rows."""
    import numpy as np

    for path, bench in ((LAWS, "bench_cost.py"), (SOLVERS, "bench_static.py")):
        if not path.exists():
            raise SpecError("plan", str(path), f"no cost laws measured yet: run python bench/{bench}")
    raw = json.loads(LAWS.read_text())
    law = CostLaws(raw.get("date", ""), raw.get("machine", {}), StaticRest(**raw["static"]),
                   MemoryLaw(**raw["static_memory"]), DynamicLaw(**raw["dynamic"]), MemoryLaw(**raw["dynamic_memory"]))
    rows = json.loads(SOLVERS.read_text())["rows"]
    for solver in sorted({r["solver"] for r in rows}):
        mine = [r for r in rows if r["solver"] == solver]
        b = np.array([r["n_bonds"] for r in mine], float)
        p, logc = np.polyfit(np.log(b), np.log([r["total_s"] for r in mine]), 1)
        m1, m0 = np.polyfit(b, [1024 * r["peak_memory_GiB"] for r in mine], 1)
        law.solvers[solver] = SolverLaw(float(m0), float(m1), float(np.exp(logc)), float(p))
    law.quasistatic, law.nonlinear = quasistatic_runs(), nonlinear_runs()
    return law


def quasistatic_runs() -> dict[str, list[MeasuredRun]]:
    """"breaking rule, event tolerance" -> the fastest complete quasi-static run at each size, from
    bench/results/quasistatic_scale.json and the paper-scale studies' jobs (:func:`study_jobs`; none: {})."""
    best: dict[tuple, MeasuredRun] = {}
    scale = json.loads(QUASISTATIC.read_text()) if QUASISTATIC.exists() else {"rows": []}
    cores = int(scale.get("machine", {}).get("cpus", 1))
    for r in scale["rows"]:
        if not r.get("complete") or not r.get("wall_s"):
            continue
        key = (f"{r.get('breaking', 'lammps')}, {r['tolerance']:g}", r["n_bonds"])
        if key not in best or r["wall_s"] < best[key].wall_s:
            best[key] = MeasuredRun(r["n_bonds"], r["wall_s"], r["events"], r["diameter_nm"],
                                    1024 * r["peak_memory_GiB"] if r.get("peak_memory_GiB") else None, cores)
    for setting, run in study_jobs():
        if (setting, run.bonds) not in best or run.wall_s < best[setting, run.bonds].wall_s:
            best[setting, run.bonds] = run
    runs: dict[str, list[MeasuredRun]] = {}
    for (setting, _), row in sorted(best.items(), key=lambda kv: kv[0][1]):
        runs.setdefault(setting, []).append(row)
    return runs


def study_jobs() -> list[tuple[str, MeasuredRun]]:
    """("breaking rule, event tolerance", the job) of every job the paper-scale porosity studies recorded
    (:data:`STUDY_RECORDS`) that ran in one session with the machine to itself (a job resumed, or noted to have
    shared the machine, is left out; a job stopped for a while counts its wall less that while; a peak that was
    not the job's own, ``peak_rss_of`` says whose, is not taken)."""
    out = []
    for path in sorted((ROOT / "bench" / "results").glob(STUDY_RECORDS)):
        rec = json.loads(path.read_text())
        setting = f"{rec['breaking']}, {rec['event_tolerance']:g}"
        for j in rec["jobs"]:
            if not j["last_session_resumed"] and not j.get("note"):
                out.append((setting, MeasuredRun(j["bonds"], j["last_session_wall_s"] - j.get("paused_s", 0.0),
                                                 j["events"], rec["diameter_nm"],
                                                 None if j.get("peak_rss_of") else 1024 * j["peak_rss_GiB"],
                                                 int(rec.get("machine", {}).get("cpus", 1)))))
    return out


def nonlinear_runs() -> list[MeasuredRun]:
    """The nonlinear method's jobs measured: bench/results/aerogel_strength.json's ``job_costs`` (none: [])."""
    rows = json.loads(NONLINEAR.read_text()).get("job_costs", []) if NONLINEAR.exists() else []
    return [MeasuredRun(r["n_bonds"], r["wall_s"], r["events"], 0.0, r.get("peak_MiB")) for r in rows]


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


def predict(facts: CostFacts, law: CostLaws, ranks: int = 1) -> Prediction:
    """Wall seconds, core-seconds and peak memory (MiB) of one job with these facts: the build as timed by
    the plan, plus the solve (static: the solver's law) or the time steps (dynamic), plus the outputs."""
    bonds = max(facts.n_bonds, 1)
    if facts.method not in ("static", "quasistatic"):
        dyn = law.dynamic
        per_bond = dyn.s_per_bond_step / (dyn.spring_factor if facts.bond_model == "spring" else 1.0)
        lammps = facts.steps * bonds * per_bond / (ranks * dyn.mpi_efficiency if ranks > 1 else 1.0)
        wall = facts.build_s + dyn.lammps_start_s + lammps + dyn.rest_s
        return Prediction(wall, wall * ranks, law.dynamic_memory.at(bonds))
    if facts.geometry == "nonlinear" and law.nonlinear:    # the strength study's jobs, per bond
        import numpy as np

        per_bond = [r.wall_s / r.bonds for r in law.nonlinear]
        wall = facts.build_s + float(np.mean(per_bond)) * bonds
        memory = [r.peak_MiB for r in law.nonlinear if r.peak_MiB]
        return Prediction(wall, wall * ranks, max(memory) if memory else _solve_memory(facts, law, bonds),
                          "nonlinear runs", round(float(np.mean([r.events for r in law.nonlinear]))),
                          facts.build_s + max(per_bond) * bonds)
    runs = None if facts.geometry == "nonlinear" else law.quasistatic.get(f"{facts.breaking}, "
                                                                          f"{facts.event_tolerance or 0:g}")
    if facts.method == "quasistatic" and runs:          # whole runs measured with its rule and tolerance
        sizes = [r.bonds for r in runs]
        wall = facts.build_s + _loglog(bonds, sizes, [r.wall_s for r in runs])
        with_memory = [r for r in runs if r.peak_MiB]
        mem = (_loglog(bonds, [r.bonds for r in with_memory], [r.peak_MiB for r in with_memory]) if with_memory
               else _solve_memory(facts, law, bonds))
        # core-seconds: the job as measured, on the cores its runs had (or its ranks, where more)
        return Prediction(wall, wall * max(ranks, max(r.cores for r in runs)), mem, "measured runs",
                          max(1, round(_loglog(bonds, sizes, [r.events for r in runs]))))
    sv, st = law.solvers[facts.solver], law.static          # a solve (quasi-static: its first, a lower bound)
    wall = facts.build_s + sv.c * bonds ** sv.p + st.rest_s0 + st.rest_s_per_bond * bonds
    return Prediction(wall, wall * ranks, _solve_memory(facts, law, bonds))


def _solve_memory(facts: CostFacts, law: CostLaws, bonds: int) -> float:
    """A solve's peak memory: the static method's law, with AMG's own per bond or the solver's."""
    if facts.solver == "amg":
        return law.static_memory.at(bonds)
    return law.static_memory.m0_MiB + law.solvers[facts.solver].at(bonds)


def _sample(n: int, k: int) -> list[int]:
    if k <= 0 or k >= n:
        return list(range(n))
    return sorted({round(i * (n - 1) / (k - 1)) for i in range(k)}) if k > 1 else [0]


def _between(costs: dict[int, CostFacts], i: int) -> CostFacts:
    """The facts of job ``i``: its own where it was built, else interpolated in the job's index between the
    built jobs on either side (a study's jobs run along its parameter), the nearest one beyond the ends."""
    if i in costs:
        return costs[i]
    lo = max((k for k in costs if k < i), default=None)
    hi = min((k for k in costs if k > i), default=None)
    if lo is None or hi is None:
        return costs[lo if hi is None else hi]
    w = (i - lo) / (hi - lo)
    out = dataclasses.replace(costs[lo])
    for f in dataclasses.fields(out):
        a, b = getattr(costs[lo], f.name), getattr(costs[hi], f.name)
        if isinstance(a, (int, float)) and not isinstance(a, bool) and isinstance(b, (int, float)):
            setattr(out, f.name, type(a)(a + w * (b - a)) if isinstance(a, float) else round(a + w * (b - a)))
    if out.method == "static" and costs[lo].solver != costs[hi].solver:
        out.solver = costs[lo if w < 0.5 else hi].solver
    return out


def measured(folder: Path, label: str, single: bool) -> Measured | None:
    job = folder if single else next(iter(sorted(folder.glob(f"jobs/{label}-*"))), None)
    if job is None:
        return None
    s = read_summary(job)
    if not s or s.get("state") == "built":
        return None
    rec = job_record(job)
    number = lambda x: x if isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0 else None  # noqa: E731
    return Measured(number(s.get("wall_s")), number(rec.peak_rss_MiB if rec is not None else None))


def plan(spec, *, ranks: int = 1, sample: int = 3, against: Path | None = None, say=print) -> Plan:
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
    for j in jobs:
        if not registry.get(j.spec.kind).cost:
            raise SpecError("kind", j.spec.kind, "has no cost model yet (plan prices bonded-particle runs)")
    costs = {}
    for i in _sample(len(jobs), sample):
        say(f"plan: building {jobs[i].label} ({i + 1}/{len(jobs)}) for its size")
        costs[i] = registry.resolve(registry.get(jobs[i].spec.kind).cost)(jobs[i].spec)
    rows = []
    for i, j in enumerate(jobs):
        facts = _between(costs, i)
        rows.append(PlanRow(j.label, i in costs, facts, predict(facts, law, ranks),
                            None if against is None else measured(Path(against), j.label,
                                                                  single="executor" not in kind.options)))
    longest = max(r.prediction.wall_max_s or r.prediction.wall_s for r in rows)
    peak = max(r.prediction.peak_MiB for r in rows)
    slurm = {"ntasks": ranks, "mem": f"{math.ceil(MARGIN * peak / 1024)}G",
             "time_min": max(1, math.ceil(MARGIN * longest / 60)), "array": f"0-{len(rows) - 1}"}
    return Plan(spec.name, spec.kind, rows, sum(r.prediction.core_s for r in rows) / 3600, longest, peak, slurm,
                law.machine, law.date, cheapest_resolution(spec))


def plan_lines(p: Plan) -> list[str]:
    lines = [f"plan {p.workflow} ({p.kind}, {len(p.jobs)} job(s); cost laws of {LAWS.name}, measured "
             f"{p.laws_measured} on {p.machine.get('cpus', '?')} cores)",
             f"  {'job':<22} {'method':<11} {'particles':>10} {'bonds':>11} {'steps':>8} {'wall (s)':>10} "
             f"{'core-s':>10} {'memory':>10}" + ("   measured wall / memory" if any(r.measured for r in p.jobs) else "")]
    for r in p.jobs:
        f, pr, m = r.facts, r.prediction, r.measured
        meas = ""
        if m:
            err = f" ({100 * (pr.wall_s / m.wall_s - 1):+.0f} %)" if m.wall_s else ""
            mem = f"{m.peak_MiB:.0f} MiB ({100 * (pr.peak_MiB / m.peak_MiB - 1):+.0f} %)" if m.peak_MiB else "-"
            meas = f"   {m.wall_s:.1f} s{err} / {mem}" if m.wall_s else "   -"
        lines.append(f"  {r.label:<22} {f.method:<11} {f.n_particles:>10} {f.n_bonds:>11} "
                     f"{f.steps if f.steps is not None else '-':>8} {pr.wall_s:>10.1f} {pr.core_s:>10.1f} "
                     f"{pr.peak_MiB / 1024:>8.2f} GiB{'' if r.built else ' ~'}{meas}")
    s = p.slurm
    lines += [f"total: {p.core_hours:.3g} core-hours; longest job {p.longest_job_s:.0f} s "
              f"({p.longest_job_s / 3600:.2f} h); peak memory {p.peak_MiB / 1024:.2f} GiB per job "
              "(~: job interpolated between built ones)",
              f"SLURM (x{MARGIN} margin): --array={s['array']} --ntasks={s['ntasks']} --mem={s['mem']} "
              f"--time={s['time_min']}  ([executor] type = \"slurm\", mem_gb, time_min)"]
    quasistatic = [r for r in p.jobs if r.facts.method == "quasistatic"]
    if any(r.prediction.priced_by == "nonlinear runs" for r in quasistatic):
        spread = [r.wall_s for r in nonlinear_runs()]
        lines.append(f"nonlinear quasi-static jobs are priced by the mean per bond of the {len(spread)} jobs of the "
                     f"aerogel strength study ({NONLINEAR.name}: {min(spread):.0f}-{max(spread):.0f} s a job, each "
                     "slab's own breaks), the longest job (SLURM's time) by the slowest")
    if any(r.prediction.priced_by == "measured runs" for r in quasistatic):
        events = [r.prediction.events for r in quasistatic if r.prediction.events]
        cores = max(round(r.prediction.core_s / r.prediction.wall_s) for r in quasistatic
                    if r.prediction.priced_by == "measured runs")
        lines.append("quasistatic jobs are priced by the whole runs measured with their breaking rule and event "
                     f"tolerance ({QUASISTATIC.name}: the standard sample's; {STUDY_RECORDS}: the paper-scale "
                     f"porosity studies' jobs; their events, {min(events)}-{max(events)} here: a study's pores or "
                     f"coatings change how many events a run takes), on the {cores} cores a job they ran on: the "
                     "core-hours count them")
    if any(not r.prediction.priced_by for r in quasistatic):
        lines.append("quasistatic jobs are priced as their first solve, a lower bound: each broken bond costs a "
                     "re-solve and their number is not known before the run")
    if p.resolution:
        lines.append(p.resolution)
    return lines
