"""Benchmark of the polycrystal: cost of the batched samples and of a macro step against element count.

    python bench/bench_polycrystal.py [--cubes 2 4 6 8]

For each block of n^3 cubes (6 n^3 tetrahedra, 64 atoms each): seconds per batched force/stress
evaluation of all samples (JAX, after compilation), seconds per macro step of the dynamic tension
(velocity Verlet, samples relaxed by Newton: evaluations per step counted), and the same per
element and per atom.  Writes bench/results/polycrystal.json and .md with the machine and the JAX
device (a GPU when JAX has one).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cubes", type=int, nargs="+", default=[2, 4, 6, 8])
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args()
    import jax

    from opalflow.tersoff.parameters import load_parameters
    from opalflow.tersoff.polycrystal.crystal import single_crystal
    from opalflow.tersoff.polycrystal.dynamics import Polycrystal
    from opalflow.tersoff.polycrystal.mesh import block
    from opalflow.tersoff.polycrystal.samples import Samples, random_rotations

    params = load_parameters("Si_zhuravlev2021.tersoff", "Si")
    crystal = single_crystal(params, "Si_zhuravlev2021.tersoff")
    samples = Samples(params.values(), params.cutoff(), crystal.a0_A)
    rows = []
    for n in args.cubes:
        mesh = block((n, n, n), 10.0, (True, False, False))
        pc = Polycrystal(mesh, samples, random_rotations(mesh.elements, 1), crystal.constants)
        samples.evaluate(pc.atoms, pc.cells)                      # compile for this shape
        t = time.perf_counter()
        for _ in range(5):
            samples.evaluate(pc.atoms, pc.cells)
        per_eval = (time.perf_counter() - t) / 5
        dt = pc.stable_timestep(0.5)
        pc.forces()
        rate = 0.05e-3                                             # strain per ps, the workflow's 0.05 / ns
        evals0, t = pc.evaluations, time.perf_counter()
        for _ in range(args.steps):
            ratio = (pc.box[0] + mesh.box[0] * rate * dt) / pc.box[0]
            pc.box[0] *= ratio
            pc.x[:, 0] *= ratio
            pc.verlet(dt, math.pi * 9.0 / (n * 10.0))
        per_step = (time.perf_counter() - t) / args.steps
        rows.append({"cubes": n, "elements": mesh.elements, "atoms": mesh.elements * samples.n,
                     "s_per_evaluation": per_eval, "s_per_macro_step": per_step,
                     "evaluations_per_step": (pc.evaluations - evals0) / args.steps,
                     "us_per_atom_evaluation": per_eval / (mesh.elements * samples.n) * 1e6})
        print(json.dumps(rows[-1]))
    el = np.array([r["elements"] for r in rows], float)
    st = np.array([r["s_per_macro_step"] for r in rows])
    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "jax_devices": [str(d) for d in jax.devices()]},
              "rows": rows, "macro_step_cost_exponent": float(np.polyfit(np.log(el), np.log(st), 1)[0]) if len(rows) > 1 else None}
    out = HERE / "results"
    out.mkdir(exist_ok=True)
    (out / "polycrystal.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = ["| elements | atoms | s per batched evaluation | us per atom | s per macro step | evaluations per step |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['elements']} | {r['atoms']} | {r['s_per_evaluation']:.4f} | {r['us_per_atom_evaluation']:.2f} | "
              f"{r['s_per_macro_step']:.4f} | {r['evaluations_per_step']:.2f} |" for r in rows]
    lines += ["", f"Macro-step cost ~ elements^{result['macro_step_cost_exponent']:.2f}; JAX devices: "
              f"{', '.join(result['machine']['jax_devices'])}; {result['machine']['cpus']} CPUs."]
    (out / "polycrystal.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
