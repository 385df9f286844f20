"""The paper's standard sample at the paper's resolution (``opal_fcc``, d = 15 nm, 1.6 M particles, 17.5 M bonds):
the whole quasi-static and static commands, wall time and peak memory against issue 56's targets, and where the
time of a run goes.

    python bench/bench_paper_scale.py runs [--repeat 3] [--only quasistatic static] [--profile]
    python bench/bench_paper_scale.py profile RAW [--label after]     # a py-spy raw profile of one run, by phase
    python bench/bench_paper_scale.py kernels       # the solver's kernels on the paper's sample, and the bandwidth

``runs``: each command (:data:`COMMANDS`) ``--repeat`` times under ``/usr/bin/time -v``, the structure built in the
run (``OPALFLOW_CACHE=off``), one at a time on an otherwise idle machine: wall, peak memory (its rusage), the
strength or E, the run's own phase timings (summary.json), the code's commit; medians against :data:`TARGETS` (the
medians they replace kept in ``earlier_medians``); ``--profile``: one run
more of each command under ``py-spy`` (not timed: py-spy's sampling adds to its wall and hides its memory from
/usr/bin/time), its profile sorted as ``profile`` sorts one (label ``after_NAME``).
``profile``: a ``py-spy record --idle --threads -f raw`` of one run (``py-spy`` is not a dependency: ``pip install
py-spy``), the main thread's samples sorted into the phases of :data:`PHASES` (the first frame of the stack that
names one), the kernel threads' samples beside them. ``kernels``: on the paper's sample (built here, no cache), the
bond operator's product (all of K x, also on the particles in the builder's order, and the preconditioner's two
blocks), one preconditioner call, CG's vector work of an iteration (numpy's expressions, the fused passes), the AMG
hierarchy's set-up, the V-cycle and its finest level's sweeps and transfers, each the best of three on
the process's threads; and this machine's memory bandwidth (numpy's copy of 1 GiB, a numba sum over it on one and
two threads): the floor of a product is the bytes it must move (the bonds' arrays once, x read and the per-thread
sums written) over the bandwidth. Results: bench/results/paper_scale.json (``runs``, ``profiles``, ``kernels``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from bench_quasistatic import _time_output  # noqa: E402  (/usr/bin/time -v's peak memory and wall)
RESULTS = ROOT / "bench" / "results" / "paper_scale.json"

#: the paper-scale commands: the quasi-static run with the paper's rule (the setting of
#: bench/results/quasistatic_scale.json's d = 15 nm rows) and the static solve
COMMANDS = {
    "quasistatic": ["opal_fcc", "--set", "compression.method=quasistatic", "--set", "compression.drop_loose=true",
                    "--set", "bonds.smooth=false", "--set", "compression.event_tolerance=0.05", "--set",
                    "compression.resolve_rtol=3e-6", "--set", "compression.local_rtol=3e-5", "--set",
                    'bonds.breaking="musen"'],
    "static": ["opal_fcc", "--set", "compression.method=static", "--set", "compression.drop_loose=true"],
}
#: issue 56's targets: (wall s goal, must), (peak GiB goal, must)
TARGETS = {"quasistatic": {"wall_s": (240, 360), "peak_GiB": (6, 8)},
           "static": {"wall_s": (90, 90), "peak_GiB": (None, None)}}
#: where a run's main thread is, by the first frame of its stack (innermost first) that names one of these
PHASES = [("v_cycle", "V-cycle (sweeps, residuals, transfers)"),
          ("block_amg_preconditioner.<locals>.precondition", "preconditioner's bond products and rotations"),
          ("amg_preconditioner", "AMG set-up (pyamg)"),
          ("block_amg_preconditioner", "K_uu and the diagonal (set-up)"),
          ("pcg", "CG's product and vector updates"),
          ("LocalSettle", "local steps"),
          ("_breaking_indices", "breaking indices"),
          ("_checks", "breaking indices"),
          ("IterativeResolver.solve", "CG's start (residual)"),
          ("LoadedNetwork", "re-solver's set-up and re-solves' bookkeeping"),
          ("Adjacency", "adjacency"),
          ("solve_fracture", "event loop's own work"),
          ("finish", "results written (results.h5, plots, dumps, report)"),
          ("network_run", "sample, network, data.lmp, record"),
          ("structure", "structure built (packing, pores, bonds)"),
          ("run_quasistatic", "run's own work"),
          ("run_static", "run's own work"),
          ("solve_compression", "static solve")]


def machine() -> dict:
    return {"host": platform.node(), "cpus": os.cpu_count(), "load_1min": os.getloadavg()[0],
            "python": platform.python_version(), "date": time.strftime("%Y-%m-%d %H:%M")}


def one_run(name: str, folder: Path, raw: Path | None = None) -> dict:
    """The command ``name`` into ``folder`` under /usr/bin/time -v, its structure built in the run (``raw``: and
    under ``py-spy record --idle --threads``, its raw profile there)."""
    env = {**os.environ, "OPALFLOW_CACHE": "off", "PYTHONPATH": str(ROOT)}
    spy = [shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy"), "record", "-r", "10", "--idle",
           "--threads", "--nonblocking", "-f", "raw", "-o", str(raw), "--"] if raw else []
    cmd = ["/usr/bin/time", "-v", *spy, sys.executable, "-m", "opalflow", "run", *COMMANDS[name][:1], "--out",
           str(folder), *COMMANDS[name][1:]]
    got = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    if got.returncode or not (folder / "summary.json").exists():
        raise SystemExit(f"{name} failed:\n{got.stderr[-3000:]}")
    with tempfile.NamedTemporaryFile("w", suffix=".txt") as f:     # (bench_quasistatic's reader takes a file)
        f.write(got.stderr)
        f.flush()
        peak, wall = _time_output(f.name)
    s = json.loads((folder / "summary.json").read_text())
    code = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    row = {"wall_s": round(wall, 1), "peak_GiB": round(peak, 2), "youngs_modulus_GPa": s["youngs_modulus_GPa"],
           "solver_wall_s": s.get("wall_s"), "when": time.strftime("%Y-%m-%d %H:%M"), "code": code.stdout.strip()}
    q = s.get("quasistatic")
    if q:
        row.update(strength_MPa=s["strength_MPa"], events=q["events"], cg_iterations=q["cg_iterations"],
                   settled_locally=q["settled_locally"], setup_s=q["setup_s"], events_s=q["events_s"])
    return row


def runs(names: list[str], repeat: int, profiles: dict | None = None) -> dict:
    """``repeat`` runs of each command (``profiles``: the first one's profile into it, by label)."""
    out = {}
    for name in names:
        rows = []
        if profiles is not None:            # one run more, under py-spy: not among the timed ones
            with tempfile.TemporaryDirectory(prefix=f"paper_{name}_") as tmp:
                one_run(name, Path(tmp) / "run", Path(tmp) / "profile.txt")
                profiles[f"after_{name}"] = profile(Path(tmp) / "profile.txt")
        for k in range(repeat):
            with tempfile.TemporaryDirectory(prefix=f"paper_{name}_") as tmp:
                rows.append(one_run(name, Path(tmp) / "run"))
            print(name, k + 1, rows[-1], flush=True)
        med = {key: statistics.median(r[key] for r in rows) for key in ("wall_s", "peak_GiB")}
        (wall_goal, wall_must), (mem_goal, mem_must) = TARGETS[name]["wall_s"], TARGETS[name]["peak_GiB"]
        out[name] = {"command": "python -m opalflow run " + " ".join(COMMANDS[name]),
                     "runs": rows, "median_wall_s": med["wall_s"], "median_peak_GiB": med["peak_GiB"],
                     "targets": TARGETS[name],
                     "wall_goal_met": med["wall_s"] <= wall_goal, "wall_must_met": med["wall_s"] <= wall_must,
                     "peak_goal_met": mem_goal is None or med["peak_GiB"] <= mem_goal,
                     "peak_must_met": mem_must is None or med["peak_GiB"] <= mem_must}
    return out


def profile(raw: Path) -> dict:
    """A py-spy raw profile (``--idle --threads``): the main thread's samples by phase (:data:`PHASES`), shares of
    the whole; the kernel threads' busy samples beside them (each thread's own count)."""
    main, kernels, total = Counter(), Counter(), 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = stack.split(";")
        n = int(count)
        if "MainThread" in frames[0]:
            total += n
            names = [f.split(" (")[0] for f in reversed(frames[1:])]
            phase = next((label for key, label in PHASES for f in names if key in f), "other")
            main[phase] += n
        elif "opalflow_" in frames[0] and any("call" in f for f in frames):
            kernels[frames[0].split(": ")[-1]] += n
    return {"samples_main": total, "seconds_main": total / 10,
            "phases": {k: round(v / total, 3) for k, v in main.most_common()},
            "kernel_threads_busy": {k: round(v / total, 3) for k, v in kernels.items()}}


def bandwidth() -> dict:
    """GB/s of numpy's copy of 1 GiB (read + write) and of a numba sum over it on one thread and on two."""
    import threading

    import numpy as np

    from opalflow.jit import njit

    @njit(nogil=True)
    def total(a):
        s = 0.0
        for k in range(a.size):
            s += a[k]
        return s

    a = np.ones(2**27)
    b = np.empty_like(a)
    total(a[:10])
    half = a.size // 2

    def two():
        ts = [threading.Thread(target=total, args=(a[k * half:(k + 1) * half],)) for k in range(2)]
        [t.start() for t in ts]
        [t.join() for t in ts]
    return {"copy_GB_s": round(2 * a.nbytes / best(lambda: np.copyto(b, a)) / 1e9, 1),
            "read_1_thread_GB_s": round(a.nbytes / best(lambda: total(a)) / 1e9, 1),
            "read_2_threads_GB_s": round(a.nbytes / best(two) / 1e9, 1)}


def best(f, k: int = 3) -> float:
    """The shortest of ``k`` calls of ``f`` (s)."""
    ts = []
    for _ in range(k):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def kernels() -> dict:
    """The kernels of a paper-scale re-solve, timed on the paper's sample (module docstring)."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from opalflow.api import load_workflow
    from opalflow.bpm.deck import loaded_sample
    from opalflow.bpm.loading import LOADINGS
    from opalflow.bpm.quasistatic import LoadedNetwork
    from opalflow.bpm.scene import scene_of
    from opalflow.bpm.stiffness import stiffness_network
    from opalflow.linalg.direct import kernel_threads

    spec = load_workflow(COMMANDS["quasistatic"][0], COMMANDS["quasistatic"][2::2])
    built = scene_of(spec).build(spec)                       # the builder's order
    threads = kernel_threads()
    x = np.random.default_rng(1).standard_normal(6 * built.n_particles)
    plain = loaded_sample(spec, built)
    plain_net = stiffness_network(plain.structure, plain.coefficients)
    with threadpool_limits(limits=1):
        builders_order_ms = round(1e3 * best(lambda: plain_net.matvec(x, threads)), 1)
    plain = plain_net = None        # (freed before the ordered network is made)
    sample = loaded_sample(spec, built.reordered(built.cell_order(2.0 * float(np.mean(built.diameters)))))
    net = stiffness_network(sample.structure, sample.coefficients)
    alive = np.ones(len(net.L), bool)
    loaded = LoadedNetwork(net, LOADINGS[spec.compression.loading].supports(sample), sample.structure.positions,
                           alive, None, "block-amg", spec.compression.resolve_rtol)
    out = {"threads": threads, "particles": net.n_particles, "bonds": len(net.L),
           "product_all_builders_order_ms": builders_order_ms}
    with threadpool_limits(limits=1):
        for block in ("all", "ut", "t"):
            out[f"product_{block}_ms"] = round(1e3 * best(lambda: net.matvec(x, threads, alive, block)), 1)
        out["preconditioner_ms"] = round(1e3 * best(lambda: loaded.solver._precondition(x)), 1)
    moved = len(net.L) * (2 * net.i.itemsize + 8 * (3 + 5) + 1) + x.nbytes * (1 + 2 * threads)
    out["product_bytes_GB"] = round(moved / 1e9, 2)
    out["bandwidth"] = bandwidth()
    out["product_floor_ms"] = round(1e3 * moved / (out["bandwidth"]["read_2_threads_GB_s"] * 1e9), 1)
    out["product_over_floor"] = round(out["product_all_ms"] / out["product_floor_ms"], 1)
    return {**out, **_cg_vectors(x, threads), **_v_cycle(net, loaded, sample.structure.positions, threads)}


def _cg_vectors(x, threads: int) -> dict:
    """One CG iteration's vector work on vectors of the paper's sample: numpy's expressions and BLAS's dot (one
    thread, as the solves run it) against the fused passes (opalflow.linalg.krylov._Vectors)."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from opalflow.linalg.krylov import _Vectors

    rng = np.random.default_rng(3)
    xs, r, p, Ap, z = (rng.standard_normal(x.size) for _ in range(5))
    fused = _Vectors(x.size, threads)

    def plain():
        a = np.dot(r, z) / np.dot(p, Ap)
        x1, r1 = xs + a * p, r - a * Ap
        return np.dot(r1, r1), np.dot(r1, z), z + 0.5 * p, x1

    def joined():
        a = fused.dot(r, z) / fused.dot(p, Ap)
        fused.step(xs, r, p, Ap, a * 1e-12)            # (in place: kept near the start)
        fused.dot(r, z)
        fused.direction(p, z, 0.5)

    with threadpool_limits(limits=1):
        return {"cg_vectors_numpy_ms": round(1e3 * best(plain), 1), "cg_vectors_fused_ms": round(1e3 * best(joined), 1)}


def _v_cycle(net, loaded, positions, threads: int) -> dict:
    """The V-cycle of block-amg's K_uu on the paper's sample: a call, and its finest level's sweeps and transfers."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from opalflow.bpm.static import block_matrix, rigid_body_modes
    from opalflow.linalg import multigrid

    n = net.n_particles
    Kuu = block_matrix(net, loaded.free.reshape(n, 6)[:, :3], part="translation", dtype=np.float32)[0]
    Kuu.sum_duplicates()
    B = rigid_body_modes(positions).reshape(n, 6, 6)[:, :3, :].reshape(3 * n, 6).astype(np.float32)
    started = time.perf_counter()
    ml = multigrid.hierarchy(Kuu, B, threads)
    hierarchy_s = round(time.perf_counter() - started, 1)
    b = np.random.default_rng(2).standard_normal(3 * n).astype(np.float32)
    first, backward = multigrid.smoothers(ml.levels[0].A, threads)
    x = first(b)[0]
    down, up = multigrid.transfers(ml.levels[0].P, threads)
    coarse = down(b)
    cycle = multigrid.v_cycle(ml, threads)
    with threadpool_limits(limits=1):
        return {"hierarchy_s": hierarchy_s, "levels": len(ml.levels), "finest_blocks": int(Kuu.nnz // 9),
                "sweep_forward_and_residual_ms": round(1e3 * best(lambda: first(b)), 1),
                "sweep_backward_ms": round(1e3 * best(lambda: backward(x, b)), 1),
                "restriction_ms": round(1e3 * best(lambda: down(b)), 1),
                "prolongation_ms": round(1e3 * best(lambda: up(coarse)), 1),
                "v_cycle_ms": round(1e3 * best(lambda: cycle(b)), 1)}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("runs")
    r.add_argument("--repeat", type=int, default=3)
    r.add_argument("--only", nargs="+", default=list(COMMANDS), choices=list(COMMANDS))
    r.add_argument("--profile", action="store_true", help="the first run of each under py-spy (pip install py-spy)")
    pr = sub.add_parser("profile")
    pr.add_argument("raw", type=Path)
    pr.add_argument("--label", default="after")
    sub.add_parser("kernels")
    a = p.parse_args(argv)
    old = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    if a.what == "runs":
        for name in a.only:                 # the medians measured before these runs, kept
            if name in old.get("runs", {}):
                was = old["runs"][name]
                old.setdefault("earlier_medians", []).append(
                    {"command": name, "when": was["runs"][0]["when"], "code": was["runs"][0].get("code", ""),
                     "median_wall_s": was["median_wall_s"], "median_peak_GiB": was["median_peak_GiB"]})
        old.setdefault("runs", {}).update(runs(a.only, a.repeat, old.setdefault("profiles", {}) if a.profile else None))
        old["machine"] = machine()
    elif a.what == "kernels":
        old["kernels"] = kernels()
        print(json.dumps(old["kernels"], indent=1))
    else:
        old.setdefault("profiles", {})[a.label] = profile(a.raw)
        print(json.dumps(old["profiles"][a.label], indent=1))
    RESULTS.write_text(json.dumps(old, indent=1) + "\n")


if __name__ == "__main__":
    main()
