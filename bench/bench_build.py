"""Benchmark of the structure build: time per stage and peak memory.

    python bench/bench_build.py [WORKFLOW ...] [--set section.key=value ...]

Runs ``python -m opalflow build`` for each workflow (default: opal_fcc, the paper's
standard sample) in a child process, so that the peak resident memory of the child
(LAMMPS included) is measured, and writes bench/results/build_<workflow>.json with
the stage timings, the sizes (particles, bonds, data-file bytes), the throughput
(particles and bonds per second) and the machine.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def bench(workflow: str, sets: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "opalflow", "build", workflow, "--out", str(out)]
        for s in sets:
            cmd += ["--set", s]
        log = Path(tmp) / "build.log"
        t = time.perf_counter()
        with open(log, "w") as f:
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)
            _, status, usage = os.wait4(proc.pid, 0)  # rusage of this child alone
        wall = time.perf_counter() - t
        if os.waitstatus_to_exitcode(status):
            raise SystemExit(log.read_text())
        peak_kb = usage.ru_maxrss
        summary = json.loads((out / "summary.json").read_text())
        data_bytes = (out / "data.lmp").stat().st_size
    timings = summary["timings_s"]
    return {
        "workflow": workflow, "sets": sets,
        "n_particles": summary["n_particles"], "n_bonds": summary["n_bonds"],
        "data_file_bytes": data_bytes,
        "timings_s": timings, "wall_s": round(wall, 2),
        "peak_memory_GiB": round(peak_kb / 2**20, 3),
        "particles_per_s": round(summary["n_particles"] / timings["total"]),
        "bonds_per_s": round(summary["n_bonds"] / timings["total"]),
        "bond_search_s_per_Mbond": round(timings["bonds"] / (summary["n_bonds"] / 1e6), 3),
        "write_s_per_Mbond": round(timings["write"] / (summary["n_bonds"] / 1e6), 3),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "processor": platform.machine()},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workflows", nargs="*", default=["opal_fcc"])
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args()
    (HERE / "results").mkdir(exist_ok=True)
    for w in args.workflows:
        result = bench(w, args.set)
        name = Path(w).stem + ("_" + "_".join(s.replace("=", "-") for s in args.set) if args.set else "")
        path = HERE / "results" / f"build_{name}.json"
        path.write_text(json.dumps(result, indent=2) + "\n")
        print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
