"""Benchmark of the static solver designs (opalflow/bpm/static.py) on the same samples.

    python bench/bench_static.py [--diameters 60 40 30 20] [--solvers direct amg block-amg cg cg-jax] [--workflow quickstart]
    /usr/bin/time -v python -m opalflow run opal_fcc --out DIR --set compression.method=static \
        --set compression.drop_loose=true 2> TIME
    python bench/bench_static.py --record DIR:TIME      # the paper's sample, the whole command

For each particle diameter the workflow's sample is built once (in a child process) and pickled; each
solver then solves it in a fresh child process, so that its peak resident memory (``ru_maxrss`` of that
child: the loaded sample, the solver's set-up and the solve) is its own.  Recorded per row: particles,
bonds, dofs, E, iterations, set-up and solve time, solve time per iteration per bond, peak memory.  The
cost exponent of each design is the slope of log(set-up + solve time) against log(particles).  Results:
bench/results/static_<workflow>.json; the rows of diameters and solvers not measured in a call are kept
(each row has the date it was measured).  ``--record DIR:TIME`` keeps a whole command's run (its
summary's E, iterations and ``timings_s``, and the wall time and peak memory of ``/usr/bin/time -v``) in
bench/results/static_<workflow>_command.json.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def build(workflow: str, diameter: float, path: Path) -> None:
    from opalflow.bpm.deck import loaded_sample
    from opalflow.bpm.loading import LOADINGS
    from opalflow.bpm.scene import scene_of
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    spec = load_spec(WORKFLOWS / f"{workflow}.toml", [f"packing.diameter_nm={diameter}"])
    t = time.perf_counter()
    s = scene_of(spec).structure(spec)          # (from the structure cache where built before)
    deck = loaded_sample(spec, s)
    data = deck.structure
    with open(path, "wb") as f:
        pickle.dump({"structure": data, "coefficients": deck.coefficients,
                     "supports": LOADINGS[spec.compression.loading].supports(deck),
                     "build_s": time.perf_counter() - t}, f)


def solve(path: Path, solver: str) -> dict:
    from opalflow.bpm.static import solve_compression
    from opalflow.bpm.stiffness import stiffness_network

    with open(path, "rb") as f:
        d = pickle.load(f)
    s = d["structure"]
    net = stiffness_network(s, d["coefficients"])
    r = solve_compression(net, s.positions, d["supports"], solver=solver, drop_loose=True,
                          say=lambda m: print(m, file=sys.stderr, flush=True))
    solve_s = r.seconds - r.setup_seconds
    return {"n_particles": s.n_particles, "n_bonds": s.n_bonds, "dofs": 6 * s.n_particles,
            "youngs_modulus_GPa": r.modulus_MPa / 1e3, "iterations": r.iterations, "relative_residual": r.residual,
            "setup_s": round(r.setup_seconds, 3), "solve_s": round(solve_s, 3), "total_s": round(r.seconds, 3),
            "solve_ns_per_iteration_per_bond": round(1e9 * solve_s / max(r.iterations, 1) / s.n_bonds, 2),
            "build_s": round(d["build_s"], 2)}


def child(args: list[str]) -> tuple[dict, float]:
    """Run this script with ``args`` in a child process: its JSON answer and its peak memory (GiB)."""
    proc = subprocess.Popen([sys.executable, __file__, *args], stdout=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    out = proc.stdout.read()
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"child {args} failed")
    return (json.loads(out) if out.strip() else {}), usage.ru_maxrss / 2**20


def record(folder: str, timing: str) -> int:
    """bench/results/static_<workflow>_command.json from a run folder and its ``/usr/bin/time -v`` output."""
    s = json.loads((Path(folder) / "summary.json").read_text())
    run = json.loads((Path(folder) / "run.json").read_text())
    got = {}
    for line in Path(timing).read_text().splitlines():
        key, _, value = line.strip().partition(": ")
        if key.startswith("Command being timed"):
            got["command"] = value.strip('"')
        elif key.startswith("Elapsed (wall clock)"):
            got["wall_s"] = sum(float(v) * 60**k for k, v in enumerate(reversed(value.split(":"))))
        elif key.startswith("Maximum resident set size"):
            got["peak_memory_GiB"] = round(int(value) / 2**20, 2)
    out = HERE / "results" / f"static_{s['workflow']}_command.json"
    out.write_text(json.dumps({**got, "workflow": s["workflow"], "n_particles": s["n_particles"],
                               "n_bonds": s["n_bonds"], "youngs_modulus_GPa": s["youngs_modulus_GPa"],
                               "solver": s["solver"], "iterations": s["iterations"],
                               "relative_residual": s["relative_residual"], "timings_s": s["timings_s"],
                               "recorded_wall_s": s["wall_s"], "provenance": run.get("provenance"),
                               "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                           "load_1min": os.getloadavg()[0]},
                               "measured": time.strftime("%Y-%m-%d")}, indent=2) + "\n")
    print(f"{got} -> {out}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workflow", default="quickstart")
    ap.add_argument("--diameters", type=float, nargs="+", default=[60.0, 40.0, 30.0, 20.0])
    ap.add_argument("--solvers", nargs="+", default=["direct", "amg", "block-amg", "cg", "cg-jax"])
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--record", help="DIR:TIME: a finished static run and its /usr/bin/time -v output")
    a = ap.parse_args()
    if a.record:
        return record(*a.record.split(":"))
    if a.child:
        if a.child[0] == "build":
            build(a.child[1], float(a.child[2]), Path(a.child[3]))
        else:
            print(json.dumps(solve(Path(a.child[1]), a.child[2])))
        return 0
    out = HERE / "results" / f"static_{a.workflow}.json"
    # rows of diameters or solvers not measured this time are kept (each row says when it was measured)
    rows = [r for r in (json.loads(out.read_text())["rows"] if out.exists() else [])
            if r["diameter_nm"] not in a.diameters or r["solver"] not in a.solvers]
    with tempfile.TemporaryDirectory() as tmp:
        for d in a.diameters:
            sample = Path(tmp) / f"d{d:g}.pkl"
            _, build_gib = child(["--child", "build", a.workflow, str(d), str(sample)])
            for solver in a.solvers:
                row, peak = child(["--child", "solve", str(sample), solver])
                row.update({"diameter_nm": d, "solver": solver, "peak_memory_GiB": round(peak, 3),
                            "build_peak_memory_GiB": round(build_gib, 3), "measured": time.strftime("%Y-%m-%d")})
                rows.append(row)
                print(f"d = {d:g} nm, {row['n_particles']} particles, {row['n_bonds']} bonds, {solver}: "
                      f"E = {row['youngs_modulus_GPa']:.5g} GPa, {row['iterations']} iterations, set-up "
                      f"{row['setup_s']:.2f} s, solve {row['solve_s']:.2f} s "
                      f"({row['solve_ns_per_iteration_per_bond']:.1f} ns/iteration/bond), peak {peak:.2f} GiB",
                      flush=True)
    rows.sort(key=lambda r: (-r["diameter_nm"], r["solver"]))
    exponents = {}
    for solver in a.solvers:
        sel = [r for r in rows if r["solver"] == solver]
        if len(sel) >= 2:
            x = np.log([r["n_particles"] for r in sel])
            y = np.log([r["total_s"] for r in sel])
            exponents[solver] = {"time_vs_particles": float(np.polyfit(x, y, 1)[0]),
                                 "iterations_vs_particles": float(np.polyfit(x, np.log([r["iterations"] for r in sel]),
                                                                             1)[0])}
    result = {"workflow": a.workflow, "rows": rows, "cost_exponents": exponents,
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                          "processor": platform.machine()}}
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"cost exponents: {exponents} -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
