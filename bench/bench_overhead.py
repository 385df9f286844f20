"""What opalflow's dynamic run costs over LAMMPS alone on the same deck, side by side.

    python bench/bench_overhead.py [--workflow quickstart] [--repeats 3]

The deck is built once (``python -m opalflow build``).  Then, alternating, ``--repeats`` rounds of

- opalflow: ``python -m opalflow run WORKFLOW`` (the whole command: structure from the cache, as the built
  deck's user has it, deck, LAMMPS in-process with progress and restart files, the analysis);
- LAMMPS alone: ``bash run.sh`` in a fresh copy of the built folder, then ``python -m opalflow analyze`` (the
  same results from the same deck).

Recorded: each command's wall time, the medians and opalflow / (run.sh + analyze) - 1; the run's own
recorded wall time (summary.json ``wall_s``) beside the command's.  -> bench/results/overhead_dynamic.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def timed(cmd: list[str], cwd: Path | None = None) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, capture_output=True)
    return time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workflow", default="quickstart")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    py = [sys.executable, "-m", "opalflow"]
    rounds = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run(py + ["build", a.workflow, "--out", str(tmp / "built")], check=True, capture_output=True)
        for k in range(a.repeats):
            ours_folder = tmp / f"opalflow_{k}"
            ours = timed(py + ["run", a.workflow, "--out", str(ours_folder)])
            recorded = json.loads((ours_folder / "summary.json").read_text())["wall_s"]
            folder = tmp / f"lammps_{k}"
            shutil.copytree(tmp / "built", folder)
            run_sh = timed(["bash", "run.sh"], cwd=folder)
            analyze = timed(py + ["analyze", str(folder)])
            rounds.append({"opalflow_command_s": ours, "opalflow_recorded_wall_s": recorded, "run_sh_s": run_sh,
                           "analyze_s": analyze, "lammps_plus_analyze_s": run_sh + analyze})
            print(f"round {k + 1}: opalflow {ours:.1f} s (recorded {recorded:.1f} s); bash run.sh {run_sh:.1f} s + "
                  f"analyze {analyze:.1f} s = {run_sh + analyze:.1f} s", flush=True)
    med = {key: float(np.median([r[key] for r in rounds])) for key in rounds[0]}
    overhead = med["opalflow_command_s"] / med["lammps_plus_analyze_s"] - 1
    per_round = [r["opalflow_command_s"] / r["lammps_plus_analyze_s"] - 1 for r in rounds]
    machine = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
               "load_1min_end": os.getloadavg()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}
    out = ROOT / "bench" / "results" / "overhead_dynamic.json"
    out.write_text(json.dumps({"workflow": a.workflow, "machine": machine, "rounds": rounds, "medians": med,
                               "overhead": overhead, "overhead_per_round": per_round}, indent=1) + "\n")
    print(f"median: opalflow {med['opalflow_command_s']:.1f} s against run.sh + analyze "
          f"{med['lammps_plus_analyze_s']:.1f} s: overhead {100 * overhead:+.1f} % "
          f"(rounds {', '.join(f'{100 * x:+.1f}' for x in per_round)} %) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
