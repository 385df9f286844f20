"""The paper's porosity study at the paper's resolution (d = 15 nm, issue 56 item 2), job by job.

    python -m opalflow run porosity_strength --out DIR --set study.paper_scale=true [--set 'study.seeds=[1]']
        --set executor.workers=1 --set executor.cpus_per_rank=2     # one job at a time: the densest need ~18 GiB
    python bench/bench_porosity_paper.py DIR [--paused LABEL=SECONDS ...]
                                                    # -> bench/results/porosity_quasistatic_d15.json

The study resumes job by job (a rerun keeps the finished jobs and continues a stopped one from its saved
events), so it may run over several sittings; this records what its folder holds: each finished job's porosity,
density, E, strength, events, bonds broken, particles and bonds, its last session's wall time and the peak
memory of its process, and the study's fits once the study has written them (all its jobs finished).  The jobs
already recorded stay (a folder on another machine, a study of other seeds: ``--set 'study.seeds=[2]'``); a job
of the same label is replaced by the folder's.  ``--paused LABEL=SECONDS``: the job's process was stopped
(SIGSTOP) that long during its session (the machine lent to something else): kept as ``paused_s``, its wall
time stays as measured.
"""
from __future__ import annotations

import datetime
import json
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "porosity_quasistatic_d15.json"


def record(folder: Path) -> dict:
    jobs = []
    for job in sorted(folder.glob("jobs/*/summary.json")):
        s = json.loads(job.read_text())
        if s.get("state") != "finished":
            continue
        rec = json.loads((job.parent / "run.json").read_text())
        last = rec["sessions"][-1]
        jobs.append({"label": rec["label"], "porosity": s["porosity"], "density_kg_m3": s["density_kg_m3"],
                     "youngs_modulus_GPa": s["youngs_modulus_GPa"], "strength_MPa": s["strength_MPa"],
                     "strain_at_peak": s["strain_at_peak"], "events": last["last_step"],
                     "broken_bonds": s["broken_bonds"], "particles": s["n_particles"], "bonds": s["n_bonds"],
                     "last_session_wall_s": last["wall_s"], "last_session_resumed": bool(last["restart"]),
                     "sessions": len(rec["sessions"]), "peak_rss_GiB": rec["peak_rss_MiB"] / 1024})
    study = folder / "summary.json"
    fits = json.loads(study.read_text()).get("fits") if study.exists() else None
    return {"command": "python -m opalflow run porosity_strength --out DIR --set study.paper_scale=true --set "
                       "executor.workers=1 --set executor.cpus_per_rank=2; python bench/bench_porosity_paper.py DIR",
            "machine": {"cpus": os.cpu_count(), "date": datetime.date.today().isoformat()},
            "jobs_finished": len(jobs), "jobs": jobs, "fits": fits}


def merged(result: dict) -> dict:
    """``result`` with the jobs recorded before that its folder does not hold (their sitting's date kept)."""
    if not OUT.exists():
        return result
    before = json.loads(OUT.read_text())
    mine = {j["label"] for j in result["jobs"]}
    date = before.get("machine", {}).get("date", "")
    kept = [{**j, "date": j.get("date", date)} for j in before["jobs"] if j["label"] not in mine]
    today = result["machine"]["date"]
    jobs = sorted(kept + [{**j, "date": today} for j in result["jobs"]], key=lambda j: j["label"])
    return {**result, "jobs_finished": len(jobs), "jobs": jobs, "fits": result["fits"] or before.get("fits")}


def fits_of_recorded(jobs: list[dict]) -> dict | None:
    """Eqs. 22, 23 and 26 fitted to every recorded job (the study's own fits: opalflow.studies.run.porosity_fits, 95 %
    intervals), beside the paper's values (opalflow.studies.run.paper()): the table while the study is partly run."""
    from opalflow.runs.result import table_of
    from opalflow.studies.run import paper, porosity_fits

    if len(jobs) < 3:
        return None
    fits = porosity_fits([j["porosity"] for j in jobs], [j["youngs_modulus_GPa"] for j in jobs],
                         [j["strength_MPa"] for j in jobs])
    return {"jobs": sorted(j["label"] for j in jobs), "fits": {k: table_of(f) for k, f in fits.items()},
            "paper": table_of(paper().porosity)}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--paused", action="append", default=[], metavar="LABEL=SECONDS")
    args = ap.parse_args()
    result = record(args.folder)
    paused = {k: float(v) for k, v in (p.split("=") for p in args.paused)}
    for job in result["jobs"]:
        if job["label"] in paused:
            job["paused_s"] = paused[job["label"]]
    result = merged(result)
    result["fits_of_recorded_jobs"] = fits_of_recorded(result["jobs"])
    OUT.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{result['jobs_finished']} jobs finished -> {OUT}")
