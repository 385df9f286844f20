"""The paper's strength studies planned at its resolution (d = 15 nm) and at 20 nm, before anything runs.

    python bench/bench_plans.py [--sample 2]        # ~10 min on 2 cores: it builds the sampled jobs' structures

For the porosity and coating strength studies (``workflows/porosity_strength.toml``,
``workflows/coating_strength.toml``, quasi-static) with ``study.paper_scale = true`` (the paper's sample,
``study.paper_set``) and the same with ``packing.diameter_nm = 20`` added: ``opalflow.runs.plan.plan`` (the
structures of ``--sample`` jobs of each built, the rest interpolated; a quasi-static job priced by the whole
runs of ``bench/results/quasistatic_scale.json`` with its breaking rule and event tolerance) -> the jobs,
core-hours, the longest job and the peak memory per job, beside the measured run of the paper's uncoated
sample with the same rule (the row of ``quasistatic_scale.json`` the price of that size comes from).
Results: bench/results/plans_paper.json and .md.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE / "results" / "plans_paper"

#: (study, d): the studies of the paper's strengths (eqs. 22-26, section 3.3) at its resolution and at 20 nm
CASES = [("porosity_strength", 15.0), ("coating_strength", 15.0), ("porosity_strength", 20.0),
         ("coating_strength", 20.0)]


def case(name: str, diameter: float, sample: int) -> dict:
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS
    from opalflow.runs.plan import plan

    paper = load_spec(WORKFLOWS / f"{name}.toml", ["study.paper_scale=true"])
    sets = ["study.paper_scale=true"]
    if diameter != 15.0:
        extra = [*paper.study.paper_set, f"packing.diameter_nm={diameter:g}"]
        sets.append(f"study.paper_set={json.dumps(extra)}")
    spec = load_spec(WORKFLOWS / f"{name}.toml", sets)
    from opalflow.runs.result import table_of

    p = plan(spec, sample=sample, say=lambda m: print(m, flush=True))
    return {"study": name, "diameter_nm": diameter, "command": "python -m opalflow plan " + name + " " + " ".join(
        f"--set '{s}'" for s in sets), "jobs": len(p.jobs), "core_hours": p.core_hours,
        "longest_job_s": p.longest_job_s, "peak_GiB": p.peak_MiB / 1024,
        "particles": [min(j.facts.n_particles for j in p.jobs), max(j.facts.n_particles for j in p.jobs)],
        "events": [j.prediction.events for j in p.jobs],
        "priced_by": sorted({j.prediction.priced_by or "first solve" for j in p.jobs}),
        "slurm": p.slurm, "plan": table_of(p)}


def measured_paper_runs() -> list[dict]:
    """The whole quasi-static runs of the paper's uncoated sample (d = 15 nm) that price that size."""
    rows = json.loads((HERE / "results" / "quasistatic_scale.json").read_text())["rows"]
    return [{k: r.get(k) for k in ("breaking", "tolerance", "events", "wall_s", "peak_memory_GiB", "strength_MPa")}
            for r in rows if r["diameter_nm"] == 15.0 and r.get("complete")]


def markdown(result: dict) -> str:
    lines = [f"# {__doc__.splitlines()[0]}", "", f"Planned {result['date']} on {result['cpus']} cores "
             "(`python bench/bench_plans.py`). Core-hours on this kind of machine: a quasi-static job priced by "
             "measured runs on the cores they ran on (all of the machine's), any other on one core.", "",
             "| study | d (nm) | jobs | particles | events a job (priced) | core-hours | longest job | memory a job |",
             "|---|---|---|---|---|---|---|---|"]
    for c in result["cases"]:
        ev = [e for e in c["events"] if e]
        lines.append(f"| {c['study']} | {c['diameter_nm']:g} | {c['jobs']} | {c['particles'][0]:,}-{c['particles'][1]:,} | "
                     f"{min(ev) if ev else '-'}-{max(ev) if ev else '-'} | {c['core_hours']:.1f} | "
                     f"{c['longest_job_s'] / 60:.0f} min | {c['peak_GiB']:.1f} GiB |")
    lines += ["", "Measured whole runs of the paper's uncoated sample (bench/results/quasistatic_scale.json):", ""]
    for m in result["measured_paper_runs"]:
        lines.append(f"- rule {m['breaking'] or 'lammps'}, event tolerance {m['tolerance']:g}: {m['events']} events, "
                     f"{m['wall_s'] / 60:.1f} min, {m['peak_memory_GiB']} GiB, strength {m['strength_MPa']:.2f} MPa")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", type=int, default=2, help="jobs of each study whose structure is built")
    a = ap.parse_args()
    result = {"what": __doc__.splitlines()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
              "cpus": os.cpu_count(), "python": platform.python_version(),
              "cases": [case(name, d, a.sample) for name, d in CASES], "measured_paper_runs": measured_paper_runs()}
    OUT.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    OUT.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
