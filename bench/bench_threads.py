"""The static solve under the default environment against hand-set thread counts, side by side.

    python bench/bench_threads.py [--diameters 60 30] [--solvers auto amg] [--repeats 3]

For each diameter and solver, ``python -m opalflow run quickstart --set packing.diameter_nm=D
compression.method=static`` runs in turn (alternating, ``--repeats`` rounds) with no thread variable set
(the default: opalflow chooses, opalflow/bpm/static.py solver_threads) and with OMP_NUM_THREADS,
OPENBLAS_NUM_THREADS and MKL_NUM_THREADS all set to 1 and to the CPU count.  Recorded: the median set-up +
solve (summary.json ``static_s``) of each setting and default / best.  -> bench/results/static_threads.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def run(diameter: float, solver: str, threads: int | None, out: Path) -> float:
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    if threads:
        env.update({k: str(threads) for k in VARIABLES})
    subprocess.run([sys.executable, "-m", "opalflow", "run", "quickstart", "--out", str(out), "--set",
                    f"packing.diameter_nm={diameter:g}", "--set", "compression.method=static", "--set",
                    f"compression.solver={solver}"], env=env, check=True, capture_output=True)
    return json.loads((out / "summary.json").read_text())["static_s"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diameters", type=float, nargs="+", default=[60.0, 30.0])
    ap.add_argument("--solvers", nargs="+", default=["auto", "amg"])
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    cpus = os.cpu_count() or 1
    settings = {"default": None, "1 thread": 1, f"{cpus} threads": cpus}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in a.diameters:
            for solver in a.solvers:
                run(d, solver, None, Path(tmp) / "warm")         # the structure into the cache
                times = {k: [] for k in settings}
                for r in range(a.repeats):
                    for k, t in settings.items():
                        times[k].append(run(d, solver, t, Path(tmp) / f"{d:g}_{solver}_{r}_{k.replace(' ', '')}"))
                med = {k: float(np.median(v)) for k, v in times.items()}
                best = min(med.values())
                rows.append({"diameter_nm": d, "solver": solver, "median_setup_solve_s": med, "runs_s": times,
                             "default_over_best": med["default"] / best})
                print(f"d = {d:g} nm, {solver}: " + ", ".join(f"{k} {v:.3f} s" for k, v in med.items())
                      + f"; default / best = {med['default'] / best:.3f}", flush=True)
    machine = {"host": platform.node(), "cpus": cpus, "python": platform.python_version(),
               "load_1min_end": os.getloadavg()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}
    out = ROOT / "bench" / "results" / "static_threads.json"
    out.write_text(json.dumps({"machine": machine, "rows": rows}, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
