"""What each executor adds per job: the same 8 small static jobs (porosity study on opal_quick, 2
porosities x 4 seeds) through local, dask and slurm with 2 jobs at once, written to
bench/results/executors.json (and .md).

    bash scripts/local-slurm.sh start && python bench/bench_executors.py     # about 2 minutes on 2 cores

Overhead per job = (study wall x 2 slots - sum of the jobs' own wall_s) / jobs: process start and imports,
scheduling, polling and collecting, i.e. everything an executor costs beyond the work of its jobs.  The
jobs' Young's moduli must agree to the last digit across the executors.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SETS = ["study.base=opal_quick", "study.method=static", 'study.set=["pores.porosity_tolerance=0.1"]',
        "study.porosities=[0.3, 0.5]", "study.seeds=[1, 2, 3, 4]", "executor.workers=2", "executor.poll_s=0.5"]


def study(out: Path, executor: str) -> dict:
    cmd = [sys.executable, "-m", "opalflow", "run", "porosity", "--out", str(out), "--executor", executor]
    for s in SETS:
        cmd += ["--set", s]
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t
    jobs = {p.parent.name.rsplit("-", 1)[0]: json.loads(p.read_text()) for p in out.glob("jobs/*/summary.json")}
    work = sum(j["wall_s"] for j in jobs.values())
    return {"executor": executor, "jobs": len(jobs), "wall_s": wall, "job_wall_s_sum": work,
            "overhead_s_per_job": (2 * wall - work) / len(jobs),
            "E_GPa": {k: j["youngs_modulus_GPa"] for k, j in sorted(jobs.items())}}


def main() -> int:
    executors = ["local", "dask"] + (["slurm"] if shutil.which("sbatch") else [])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for ex in executors:
            rows.append(study(Path(tmp) / ex, ex))
            print({k: v for k, v in rows[-1].items() if k != "E_GPa"}, flush=True)
    same = all(r["E_GPa"] == rows[0]["E_GPa"] for r in rows)
    out = {"date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(), "sets": SETS, "rows": rows,
           "identical_E_across_executors": same}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "executors.json").write_text(json.dumps(out, indent=2) + "\n")
    lines = ["# Executors (bench/bench_executors.py)", "", f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores; "
             f"8 static jobs (porosity study on opal_quick), 2 at once; E identical across executors: {same}.", "",
             "| executor | jobs | study wall (s) | jobs' own wall (s) | overhead per job (s) |", "|---|---|---|---|---|"]
    lines += [f"| {r['executor']} | {r['jobs']} | {r['wall_s']:.1f} | {r['job_wall_s_sum']:.1f} | "
              f"{r['overhead_s_per_job']:.2f} |" for r in rows]
    (RESULTS / "executors.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
