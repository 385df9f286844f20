"""Benchmark of the Tersoff track: fit, LAMMPS property evaluation, MD stability.

    python bench/bench_tersoff.py

Runs the three shipped workflows with ``python -m opalflow run`` in child processes and
writes bench/results/tersoff.json: wall time of each, seconds per L-BFGS start and per
loss evaluation, the LAMMPS evaluation time per strain size, MD atom-steps per second
(512 atoms, one process per run), and the machine.
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

HERE = Path(__file__).resolve().parent


def run(workflow: str, out: Path) -> tuple[dict, float]:
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "opalflow", "run", workflow, "--out", str(out)],
                          capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(proc.stderr)
    return json.loads((out / "summary.json").read_text()), time.perf_counter() - t


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        props, props_wall = run("tersoff_properties", Path(tmp) / "props")
        fit, fit_wall = run("tersoff_fit", Path(tmp) / "fit")
        stab, stab_wall = run("tersoff_stability", Path(tmp) / "stab")
    starts = fit["starts"]
    spec = stab["spec"]["stability"]
    steps = spec["time_ps"] * 1000 / spec["timestep_fs"]
    runs = stab["stability"]["runs"]
    result = {
        "properties": {"wall_s": round(props_wall, 2), "lammps_s": round(props["lammps_s"], 3),
                       "seconds_per_strain": {str(r["strain"]): round(r["seconds"], 4) for r in props["strain_scan"]}},
        "fit": {"wall_s": round(fit_wall, 2), "fit_s": round(fit["fit_s"], 2), "starts": len(starts),
                "seconds_per_start": round(sum(r["seconds"] for r in starts) / len(starts), 3),
                "seconds_per_evaluation": round(sum(r["seconds"] for r in starts)
                                                / sum(r["evaluations"] for r in starts), 5),
                "loss": fit["loss"], "reference_loss": fit["reference_loss"]},
        "stability": {"wall_s": round(stab_wall, 2), "runs": len(runs), "atoms": 8 * spec["cells"] ** 3,
                      "steps": steps, "workers": spec["workers"] or os.cpu_count(),
                      "atom_steps_per_s": round(8 * spec["cells"] ** 3 * steps
                                                / (sum(r["seconds"] for r in runs) / len(runs)))},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "processor": platform.machine()},
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "tersoff.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
