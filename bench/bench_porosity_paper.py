"""The paper's porosity study at the paper's resolution (d = 15 nm, issue 56 item 2), job by job.

    python -m opalflow run porosity_strength --out DIR --set study.paper_scale=true [--set 'study.seeds=[1]']
        --set executor.workers=1 --set executor.cpus_per_rank=2     # one job at a time: the densest need ~18 GiB
    python bench/bench_porosity_paper.py DIR                        # -> bench/results/porosity_quasistatic_d15.json

The study resumes job by job (a rerun keeps the finished jobs and continues a stopped one from its saved
events), so it may run over several sittings; this records what its folder holds: each finished job's porosity,
density, E, strength, events, bonds broken, particles and bonds, its last session's wall time and the peak
memory of its process, and the study's fits once the study has written them (all its jobs finished).
"""
from __future__ import annotations

import datetime
import json
import os
import sys
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


if __name__ == "__main__":
    result = record(Path(sys.argv[1]))
    OUT.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{result['jobs_finished']} jobs finished -> {OUT}")
