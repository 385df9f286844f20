"""Cost laws for ``python -m opalflow plan``: wall time and peak memory of static solves and dynamic runs
against their size, measured on this machine, written to bench/results/cost_laws.json (and .md).

    python bench/bench_cost.py            # about 4 minutes on 2 cores

Each case is a fresh ``python -m opalflow run`` process (its peak resident memory from wait4, its wall time
from its summary.json, which covers the structure build, the solve or the LAMMPS run and the outputs):

- static: quickstart at d = 60, 45, 35 and 30 nm -> wall = a + b * bonds^p (least squares in log space for
  b and p after a fixed start-up a), memory = m0 + m1 * bonds;
- dynamic: quickstart and opal_quick to a small strain -> LAMMPS seconds per bond-step (bpm/rotational),
  the set-up as for static, memory = m0 + m1 * bonds; quickstart with 2 MPI ranks -> parallel efficiency.
bpm/spring's cost per bond is taken as 1/25 of bpm/rotational's (shared/BRIEF.md, measured on these
machines), not measured again here.
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
           ("opal_quick", ["compression.strain_max=0.004", "compression.snapshot_strains=[]"])]


def run(workflow: str, sets: list[str], out: Path, np_: int = 1) -> dict:
    """One fresh process: its summary, run record and peak memory (MiB)."""
    cmd = [sys.executable, "-m", "opalflow", "run", workflow, "--out", str(out), "--np", str(np_)]
    for s in sets:
        cmd += ["--set", s]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
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
                                   "wall_s": s["wall_s"], "peak_MiB": r["peak_MiB"]})
            print(rows["static"][-1], flush=True)
        for name, sets in DYNAMIC:
            r = run(name, sets, tmp / f"d_{name}")
            s = r["summary"]
            rows["dynamic"].append({"workflow": name, "n_particles": s["n_particles"], "n_bonds": s["n_bonds"],
                                    "steps": s["steps"], "wall_s": s["wall_s"], "lammps_s": s["lammps_s"],
                                    "peak_MiB": r["peak_MiB"]})
            print(rows["dynamic"][-1], flush=True)
        r2 = run(DYNAMIC[0][0], DYNAMIC[0][1], tmp / "d_np2", np_=2)
        mpi = {"ranks": 2, "lammps_s": r2["summary"]["lammps_s"]}
    st = rows["static"]
    bonds = np.array([r["n_bonds"] for r in st], float)
    wall = np.array([r["wall_s"] for r in st])
    a = 0.8 * wall.min()                                  # start-up part (imports, LAMMPS packing set-up)
    p, logb = np.polyfit(np.log(bonds), np.log(np.maximum(wall - a, 1e-3)), 1)
    m1, m0 = np.polyfit(bonds, [r["peak_MiB"] for r in st], 1)
    dyn = rows["dynamic"]
    per_bond = float(np.mean([r["lammps_s"] / (r["steps"] * r["n_bonds"]) for r in dyn]))
    dm1, dm0 = np.polyfit([r["n_bonds"] for r in dyn], [r["peak_MiB"] for r in dyn], 1)
    one = dyn[0]["lammps_s"]
    laws = {
        "date": time.strftime("%Y-%m-%d"), "seconds_to_measure": round(time.time() - t0, 1),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "processor": platform.machine()},
        "static": {"a_s": float(a), "b_s": float(np.exp(logb)), "p": float(p)},
        "static_memory": {"m0_MiB": float(m0), "m1_MiB": float(m1)},
        "dynamic": {"s_per_bond_step": per_bond, "spring_factor": 25.0,
                    "mpi_efficiency": float(one / (2 * mpi["lammps_s"]))},
        "dynamic_memory": {"m0_MiB": float(dm0), "m1_MiB": float(max(dm1, 0.0))},
        "rows": rows, "mpi": mpi,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "cost_laws.json").write_text(json.dumps(laws, indent=2) + "\n")
    lines = ["# Cost laws (bench/bench_cost.py)", "", f"Measured {laws['date']} on {os.cpu_count()} cores.", "",
             f"- static: wall = {a:.2f} s + {np.exp(logb):.3g} x bonds^{p:.3f}; memory = {m0:.0f} MiB + "
             f"{1024 * m1:.3g} KiB x bonds",
             f"- dynamic: {1e6 * per_bond:.3f} us per bond-step (bpm/rotational); memory = {dm0:.0f} MiB + "
             f"{1024 * max(dm1, 0):.3g} KiB x bonds; 2 MPI ranks: efficiency {laws['dynamic']['mpi_efficiency']:.2f}",
             "", "| case | particles | bonds | steps | wall (s) | peak memory (MiB) |", "|---|---|---|---|---|---|"]
    lines += [f"| static d = {r['diameter_nm']:g} nm | {r['n_particles']} | {r['n_bonds']} | - | {r['wall_s']:.1f} | "
              f"{r['peak_MiB']:.0f} |" for r in st]
    lines += [f"| dynamic {r['workflow']} | {r['n_particles']} | {r['n_bonds']} | {r['steps']} | {r['wall_s']:.1f} | "
              f"{r['peak_MiB']:.0f} |" for r in dyn]
    (RESULTS / "cost_laws.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
