"""The static solver against what a LAMMPS user does instead: damped relaxation to rest, side by side.

    python bench/bench_peer.py [--diameters 60 30] [--damping 0.5 1 2 4] [--repeats 3] [--np 1]

For each particle diameter of the quickstart sample:

1. ``python -m opalflow run quickstart --set packing.diameter_nm=D compression.method=static`` once (cold:
   it builds the structure, which the structure cache then keeps): the static E, and data.lmp;
2. the peer deck (opalflow/bpm/relaxation.py: the run's own deck, bonds unbreakable and unsmoothed, the
   top layer displaced and held, fix viscous + fix viscous/sphere) run by ``lmp`` for each drag
   (``--damping`` x the critical drag of the lowest axial mode) for ``--calibration-steps`` x 60 / d steps:
   the first step from which E stays within 1 % and within 0.1 % of the static E (tuned knowing the
   answer, as a user who had it would); the drag that gets there in the fewest steps is kept (at the
   smaller diameters only the drags within 2x of the best at the first diameter are tried);
3. ``--repeats`` alternating pairs, each the whole command: ``lmp -in in.relax.lmp`` with the kept drag
   and exactly the steps it needs to 0.1 % against ``python -m opalflow run ... compression.method=static`` (structure from the cache, as LAMMPS
   reads its data file); LAMMPS's loop time (its log) against opalflow's set-up + solve (summary.json).

Medians and ratios with the machine and its load -> bench/results/peer_static.json and .md.  Runs of
LAMMPS under ``mpiexec -n NP`` with ``--np``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results"
PY = sys.executable


def opalflow_static(diameter: float, out: Path) -> dict:
    """The whole static command; its summary and wall time as the user waits for it."""
    cmd = [PY, "-m", "opalflow", "run", "quickstart", "--out", str(out), "--set", f"packing.diameter_nm={diameter:g}",
           "--set", "compression.method=static"]
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t
    s = json.loads((out / "summary.json").read_text())
    return {"command_s": wall, "wall_s_recorded": s["wall_s"], "setup_solve_s": s["static_s"],
            "setup_s": s["setup_s"], "solve_s": s["solve_s"], "solver": s["solver"], "E_MPa": 1e3 * s["youngs_modulus_GPa"],
            "n_particles": s["n_particles"], "n_bonds": s["n_bonds"], "build_s": s["build_s"]}


def lammps_relax(folder: Path, np_: int) -> dict:
    """``lmp -in in.relax.lmp`` in ``folder``: whole wall, loop time, steps, the E samples."""
    lmp = shutil.which("lmp", path=str(Path(PY).parent)) or "lmp"
    cmd = [lmp, "-in", "in.relax.lmp", "-log", "log.lammps", "-screen", "none"]
    if np_ > 1:
        cmd = [shutil.which("mpiexec", path=str(Path(PY).parent)) or "mpiexec", "-n", str(np_)] + cmd
    for f in ("relax.txt", "log.lammps"):
        (folder / f).unlink(missing_ok=True)
    t = time.perf_counter()
    subprocess.run(cmd, cwd=folder, check=True)
    wall = time.perf_counter() - t
    log = (folder / "log.lammps").read_text()
    loops = [(float(a), int(b)) for a, b in re.findall(r"Loop time of ([\d.eE+-]+) on \d+ procs for (\d+) steps", log)]
    E = np.loadtxt(folder / "relax.txt", ndmin=2)
    return {"command_s": wall, "loop_s": loops[-1][0], "steps": loops[-1][1], "samples": E}


def steps_within(samples: np.ndarray, target: float, tol: float) -> int | None:
    """The first sampled step from which E stays within ``tol`` of ``target`` to the end of the samples."""
    err = np.abs(samples[:, 1] / target - 1)
    outside = np.flatnonzero(err > tol)
    if len(outside) == len(err):
        return None
    first = outside[-1] + 1 if len(outside) else 0
    return int(samples[first, 0]) if first < len(err) else None


def paper_law(rows: list[dict], diameter: float = 15.0, bonds: int = 17_480_942) -> dict | None:
    """LAMMPS's relaxation of the paper's sample (opal_fcc: d = 15 nm, 17.5 M bonds) extrapolated from the
    measured rows: steps to 0.1 % ~ d^-q (the lowest mode's period over a time step that shrinks with d;
    fitted), seconds per bond-step the mean measured one."""
    done = [r for r in rows if r.get("steps_to_0.1%")]
    if len(done) < 2:
        return None
    q = -float(np.polyfit(np.log([r["diameter_nm"] for r in done]), np.log([r["steps_to_0.1%"] for r in done]), 1)[0])
    ref = min(done, key=lambda r: r["diameter_nm"])
    steps = ref["steps_to_0.1%"] * (ref["diameter_nm"] / diameter) ** q
    per_bond_step = float(np.mean([r["lammps_loop_s"] / (r["steps_to_0.1%"] * r["n_bonds"]) for r in done]))
    return {"diameter_nm": diameter, "n_bonds": bonds, "steps_exponent_q": q, "steps_to_0.1%": steps,
            "s_per_bond_step": per_bond_step, "lammps_loop_s": steps * bonds * per_bond_step}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diameters", type=float, nargs="+", default=[60.0, 30.0])
    ap.add_argument("--damping", type=float, nargs="+", default=[0.1, 0.25, 0.5, 1.0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--np", type=int, default=1)
    ap.add_argument("--calibration-steps", type=int, default=6000, help="at d = 60 nm (x 60 / d)")
    ap.add_argument("--tag", default="", help="suffix of the result files")
    a = ap.parse_args()
    from opalflow.bpm.deck import compression_deck
    from opalflow.bpm.relaxation import relaxation_deck
    from opalflow.bpm.scene import scene_of
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    rows, best_damping = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for d in a.diameters:
            work = Path(tmp) / f"d{d:g}"
            cold = opalflow_static(d, work / "static_cold")
            E = cold["E_MPa"]
            print(f"d = {d:g} nm: {cold['n_particles']} particles, static E = {E:.6g} MPa ({cold['solver']}, set-up + "
                  f"solve {cold['setup_solve_s']:.2f} s; cold command {cold['command_s']:.1f} s)", flush=True)
            spec = load_spec(WORKFLOWS / "quickstart.toml", [f"packing.diameter_nm={d:g}"])
            deck = compression_deck(spec, scene_of(spec).structure(spec))
            every = max(10, int(round(50 * 60.0 / d)))

            def relax_folder(g: float, steps: int) -> Path:
                f = work / f"relax_{g:g}_{steps}"
                f.mkdir(parents=True, exist_ok=True)
                shutil.copy(work / "static_cold" / "data.lmp", f / "data.lmp")
                (f / "in.relax.lmp").write_text(relaxation_deck(deck, steps=steps, damping=g, every=every))
                return f

            budget = int(a.calibration_steps * 60.0 / d)

            dampings = a.damping if best_damping is None else [g for g in a.damping
                                                               if best_damping / 2 <= g <= best_damping * 2]
            scan = {}
            for g in dampings:
                r = lammps_relax(relax_folder(g, budget), a.np)
                s1, s01 = steps_within(r["samples"], E, 1e-2), steps_within(r["samples"], E, 1e-3)
                per_step = r["loop_s"] / max(r["steps"], 1)
                scan[g] = {"damping": g, "steps_run": r["steps"], "steps_to_0.1%": s01, "steps_to_1%": s1,
                           "loop_s": r["loop_s"], "loop_s_to_1%": per_step * (s1 or 0),
                           "loop_s_to_0.1%": per_step * (s01 or 0), "E_last_MPa": float(r["samples"][-1, 1]),
                           "E_samples_MPa": r["samples"].tolist()}
                print(f"  damping {g:g}: stays within 0.1 % from step {s01}, within 1 % from {s1} (of {r['steps']}; "
                      f"{r['loop_s']:.1f} s loop)", flush=True)
            done = [v for v in scan.values() if v["steps_to_0.1%"]]
            if not done:
                print(f"  no drag stayed within 0.1 % in {budget} steps", flush=True)
                rows.append({"diameter_nm": d, "static": cold, "scan": list(scan.values())})
                continue
            kept = min(done, key=lambda v: v["steps_to_0.1%"])
            if best_damping is None:
                best_damping = kept["damping"]
            folder = relax_folder(kept["damping"], kept["steps_to_0.1%"])
            pairs = []
            for k in range(a.repeats):
                lam = lammps_relax(folder, a.np)
                ours = opalflow_static(d, work / f"static_{k}")
                lam.pop("samples")
                pairs.append({"lammps": lam, "opalflow": ours})
                print(f"  pair {k + 1}: LAMMPS loop {lam['loop_s']:.2f} s (command {lam['command_s']:.2f} s), opalflow "
                      f"set-up + solve {ours['setup_solve_s']:.3f} s (command {ours['command_s']:.2f} s)", flush=True)
            med = lambda xs: float(np.median(xs))  # noqa: E731
            loop = med([p["lammps"]["loop_s"] for p in pairs])
            lam_cmd = med([p["lammps"]["command_s"] for p in pairs])
            ours_solve = med([p["opalflow"]["setup_solve_s"] for p in pairs])
            ours_cmd = med([p["opalflow"]["command_s"] for p in pairs])
            row = {"diameter_nm": d, "n_particles": cold["n_particles"], "n_bonds": cold["n_bonds"],
                   "dofs": 6 * cold["n_particles"], "static_E_MPa": E, "solver": pairs[-1]["opalflow"]["solver"],
                   "lammps_np": a.np, "damping_kept": kept["damping"], "steps_to_0.1%": kept["steps_to_0.1%"],
                   "steps_to_1%": kept["steps_to_1%"], "timestep_ns": deck.dt_ns,
                   "lammps_loop_s": loop, "lammps_loop_to_1%_s": kept["loop_s_to_1%"], "lammps_command_s": lam_cmd,
                   "opalflow_setup_solve_s": ours_solve, "opalflow_command_s": ours_cmd,
                   "opalflow_command_cold_s": cold["command_s"], "build_s": cold["build_s"],
                   "ratio_loop_over_setup_solve": loop / ours_solve, "ratio_command": lam_cmd / ours_cmd,
                   "scan": list(scan.values()), "pairs": pairs}
            rows.append(row)
            print(f"  d = {d:g} nm: LAMMPS loop / opalflow set-up + solve = {row['ratio_loop_over_setup_solve']:.1f}x; "
                  f"whole commands {row['ratio_command']:.1f}x", flush=True)
    machine = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
               "load_1min_end": os.getloadavg()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}
    name = f"peer_static{a.tag}"
    path = OUT / f"{name}.json"
    if path.exists():       # rows of other diameters measured before are kept (each row has its machine)
        kept_rows = [r for r in json.loads(path.read_text())["rows"] if r["diameter_nm"] not in a.diameters]
        rows = sorted(kept_rows + rows, key=lambda r: -r["diameter_nm"])
    for r in rows:
        r.setdefault("machine", machine)
    result = {"what": __doc__.splitlines()[0], "rows": rows, "paper_scale": paper_law(rows)}
    (OUT / f"{name}.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"# {result['what']}", "", "LAMMPS on `lammps_np` MPI rank(s); medians of the alternating pairs; each row's "
             "machine, load and date are in the .json.", "",
             "| d (nm) | particles | dofs | solver | LAMMPS steps to 0.1 % (1 %) | LAMMPS loop (s) | opalflow set-up + "
             "solve (s) | ratio | LAMMPS command (s) | opalflow command (s) | ratio |", "|" + "---|" * 11]
    for r in rows:
        if "ratio_command" not in r:
            continue
        lines.append(f"| {r['diameter_nm']:g} | {r['n_particles']} | {r['dofs']} | {r['solver']} | {r['steps_to_0.1%']} "
                     f"({r['steps_to_1%']}) | {r['lammps_loop_s']:.2f} | {r['opalflow_setup_solve_s']:.3f} | "
                     f"{r['ratio_loop_over_setup_solve']:.1f}x | {r['lammps_command_s']:.2f} | {r['opalflow_command_s']:.2f} | "
                     f"{r['ratio_command']:.1f}x |")
    law = result["paper_scale"]
    if law:
        lines += ["", f"The paper's sample (d = {law['diameter_nm']:g} nm, {law['n_bonds']} bonds), extrapolated: steps to 0.1 % "
                  f"~ d^-{law['steps_exponent_q']:.2f} -> {law['steps_to_0.1%']:.0f} steps at "
                  f"{1e9 * law['s_per_bond_step']:.0f} ns per bond-step = {law['lammps_loop_s'] / 3600:.1f} h of LAMMPS loop "
                  "on one core."]
    (OUT / f"{name}.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT / name}.json and .md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
