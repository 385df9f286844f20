"""Cost laws for ``python -m opalflow plan``: what a static solve or a dynamic run costs beyond the
structure build (which ``plan`` times itself, building each priced job's structure), measured on this
machine, written to bench/results/cost_laws.json (and .md).

    python bench/bench_cost.py            # about 3 minutes on 2 cores

Each case is a fresh ``python -m opalflow run`` process with one BLAS thread (as a study's job runs:
opalflow.runs.jobs.run_job), its peak resident memory from wait4, its times from summary.json:

- static: quickstart at d = 60, 45, 35 and 30 nm -> the outputs' time beyond build and solve per bond, and
  peak memory against bonds (the solve itself is priced by the solver laws of
  bench/results/static_quickstart.json, bench/bench_static.py, which cover d = 60-20 nm and both solvers);
- dynamic: quickstart to strains 0.004 and 0.012, opal_quick to 0.004 -> LAMMPS start-up and seconds per
  bond-step (bpm/rotational),
  the rest of the wall beyond build and LAMMPS, memory against bonds; quickstart with 2 MPI ranks ->
  parallel efficiency.  bpm/spring's cost per bond is 1/25 of bpm/rotational's (shared/BRIEF.md).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
STATIC = [60.0, 45.0, 35.0, 30.0]
DYNAMIC = [("quickstart", ["compression.strain_max=0.004", "compression.snapshot_strains=[]"]),
           ("quickstart", ["compression.strain_max=0.012", "compression.snapshot_strains=[]"]),
           ("opal_quick", ["compression.strain_max=0.004", "compression.snapshot_strains=[]"])]


def run(workflow: str, sets: list[str], out: Path, np_: int = 1) -> dict:
    """One fresh process: its summary, run record and peak memory (MiB)."""
    cmd = [sys.executable, "-m", "opalflow", "run", workflow, "--out", str(out), "--np", str(np_)]
    for s in sets:
        cmd += ["--set", s]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    if status:
        raise RuntimeError(f"{' '.join(cmd)} failed ({status})")
    summary = json.loads((out / "summary.json").read_text())
    record = json.loads((out / "run.json").read_text())
    return {"summary": summary, "deck": record["deck"], "peak_MiB": usage.ru_maxrss / 1024}


def main() -> int:
    t0 = time.time()
    rows = {"static": [], "dynamic": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for d in STATIC:
            r = run("quickstart", ["compression.method=static", "compression.drop_loose=true",
                                   f"packing.diameter_nm={d}"], tmp / f"s{d:g}")
            s = r["summary"]
            rows["static"].append({"diameter_nm": d, "n_particles": s["n_particles"], "n_bonds": s["n_bonds"],
                                   "solver": s["solver"], "build_s": s["build_s"], "static_s": s["static_s"],
                                   "wall_s": s["wall_s"], "peak_MiB": r["peak_MiB"]})
            print(rows["static"][-1], flush=True)
        for k, (name, sets) in enumerate(DYNAMIC):
            r = run(name, sets, tmp / f"d{k}_{name}")
            s = r["summary"]
            rows["dynamic"].append({"workflow": name, "n_particles": s["n_particles"], "n_bonds": s["n_bonds"],
                                    "steps": s["steps"], "build_s": r["deck"]["build_s"], "wall_s": s["wall_s"],
                                    "lammps_s": s["lammps_s"], "peak_MiB": r["peak_MiB"]})
            print(rows["dynamic"][-1], flush=True)
        r2 = run(DYNAMIC[0][0], DYNAMIC[0][1], tmp / "d_np2", np_=2)
        mpi = {"ranks": 2, "lammps_s": r2["summary"]["lammps_s"]}
    st = rows["static"]
    bonds = np.array([r["n_bonds"] for r in st], float)
    rest = np.array([r["wall_s"] - r["build_s"] - r["static_s"] for r in st])
    r1, r0 = np.polyfit(bonds, rest, 1)
    m1, m0 = np.polyfit(bonds, [r["peak_MiB"] for r in st], 1)
    dyn = rows["dynamic"]
    # LAMMPS seconds = start-up (init, first neighbour lists) + steps x bonds x t_bond
    per_bond, lammps0 = (float(x) for x in np.polyfit([r["steps"] * r["n_bonds"] for r in dyn],
                                                       [r["lammps_s"] for r in dyn], 1))
    drest = float(np.mean([r["wall_s"] - r["build_s"] - r["lammps_s"] for r in dyn]))
    dm1, dm0 = np.polyfit([r["n_bonds"] for r in dyn], [r["peak_MiB"] for r in dyn], 1)
    one = dyn[0]["lammps_s"]
    laws = {
        "date": time.strftime("%Y-%m-%d"), "seconds_to_measure": round(time.time() - t0, 1),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "processor": platform.machine()},
        "static": {"rest_s0": float(r0), "rest_s_per_bond": float(r1)},
        "static_memory": {"m0_MiB": float(m0), "m1_MiB": float(m1)},
        "dynamic": {"s_per_bond_step": per_bond, "lammps_start_s": lammps0, "rest_s": drest, "spring_factor": 25.0,
                    "mpi_efficiency": float(one / (2 * mpi["lammps_s"]))},
        "dynamic_memory": {"m0_MiB": float(dm0), "m1_MiB": float(max(dm1, 0.0))},
        "rows": rows, "mpi": mpi,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "cost_laws.json").write_text(json.dumps(laws, indent=2) + "\n")
    lines = ["# Cost laws (bench/bench_cost.py)", "", f"Measured {laws['date']} on {os.cpu_count()} cores.", "",
             f"- static: outputs beyond build and solve {r0:.2f} s + {1e6 * r1:.2f} s per million bonds; memory = "
             f"{m0:.0f} MiB + {1024 * m1:.3g} KiB x bonds",
             f"- dynamic: {lammps0:.2f} s LAMMPS start-up + {1e6 * per_bond:.3f} us per bond-step (bpm/rotational), "
             f"{drest:.1f} s besides build and "
             f"LAMMPS; memory = {dm0:.0f} MiB + {1024 * max(dm1, 0):.3g} KiB x bonds; 2 MPI ranks: efficiency "
             f"{laws['dynamic']['mpi_efficiency']:.2f}",
             "", "| case | particles | bonds | steps | wall (s) | peak memory (MiB) |", "|---|---|---|---|---|---|"]
    lines += [f"| static d = {r['diameter_nm']:g} nm ({r['solver']}) | {r['n_particles']} | {r['n_bonds']} | - | {r['wall_s']:.1f} | "
              f"{r['peak_MiB']:.0f} |" for r in st]
    lines += [f"| dynamic {r['workflow']} | {r['n_particles']} | {r['n_bonds']} | {r['steps']} | {r['wall_s']:.1f} | "
              f"{r['peak_MiB']:.0f} |" for r in dyn]
    (RESULTS / "cost_laws.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
