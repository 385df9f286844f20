"""Benchmark of the aerogel aggregation (opalflow/aerogel/aggregation.py) and its fractal dimension
(opalflow/aerogel/fractal.py) where the literature measures it.

    python bench/bench_aerogel.py designs      # fixed steps against free-distance jumps: cost at 0.002, D at 0.01
    python bench/bench_aerogel.py dilute       # 100 000 spheres at 0.002: D by R_g(N) of the dilute clusters
    python bench/bench_aerogel.py gel          # 30 000 spheres at 0.01: D by g(r) and S(q) of the gel
    python bench/bench_aerogel.py crossover    # the correlation length at four concentrations, its exponent
    python bench/bench_aerogel.py rlca         # RLCA (sticking 0.01) by the same methods
    python bench/bench_aerogel.py loops        # each loop model: coordination, loops, wrapping, slab E over seeds
    python bench/bench_aerogel.py cube         # the periodic cube's tensor (restructuring): E, nu, anisotropy
    python bench/bench_aerogel.py report       # bench/results/aerogel.md from bench/results/aerogel.json

Each part adds its rows to bench/results/aerogel.json (the machine and the date with them); run them on a
quiet machine (the seconds are wall time).  Spheres of 10 +- 1 nm (Gaussian), DLCA unless said.
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

from opalflow.aerogel.aggregation import aggregate, box_edge, gaussian_diameters
from opalflow.aerogel.fractal import estimates

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "aerogel.json"


def one(n: int, phi: float, seed: int, *, stepping: str = "jump", p: float = 1.0):
    d = gaussian_diameters(n, 10.0, 1.0, np.random.default_rng(seed))
    return aggregate(d, box_edge(d, phi), seed=seed, stepping=stepping, sticking_probability=p)


def fits_row(agg, seed: int) -> dict:
    """Every D of an aggregate, with its interval, range and note; the crossover mass and length."""
    fits = estimates(agg, seed)
    row = {f.method: {"D": f.D, "ci95": list(f.ci95), "range": list(f.range), "points": f.points, "note": f.note}
           for f in fits.fits()}
    row["crossover_mass"] = fits.rg[1].crossover_mass
    row["correlation_length_nm"] = fits.gr[1].xi_nm
    return row


def case(n, phi, seed, **kw) -> dict:
    t = time.perf_counter()
    agg = one(n, phi, seed, **kw)
    s = time.perf_counter() - t
    row = {"particles": n, "solid_fraction": phi, "seed": seed, "stepping": kw.get("stepping", "jump"),
           "sticking": kw.get("p", 1.0), "seconds": s, "moves": agg.moves, "jumps": agg.jumps, **fits_row(agg, seed)}
    print(json.dumps({k: (v if not isinstance(v, dict) else round(v["D"], 3)) for k, v in row.items()}), flush=True)
    return row


def designs(a) -> dict:
    one(300, 0.05, 1, stepping="fixed")
    one(300, 0.05, 1)                               # numba: compile (or load the cache) outside the timings
    cost = []
    for n in a.sizes:
        for stepping in ("fixed", "jump"):
            t = time.perf_counter()
            agg = one(n, 0.002, 1, stepping=stepping)
            cost.append({"particles": n, "solid_fraction": 0.002, "stepping": stepping, "seconds": time.perf_counter() - t,
                         "moves": agg.moves, "jumps": agg.jumps})
            print(cost[-1], flush=True)
    same = [case(a.n_compare, 0.01, seed, stepping=stepping) for seed in a.seeds for stepping in ("fixed", "jump")]
    return {"cost_0.002": cost, "compare_0.01": same}


#: the loop models compared (aggregate settings) and the sample: 20 000 spheres at solid fraction 0.05
LOOP_CASES = {"none": [], "deflection": ['aggregate.loops="deflection"'],
              "restructuring": ['aggregate.loops="restructuring"'],
              "necks 0.1": ['aggregate.loops="necks"', "aggregate.neck_gap=0.1"],
              "necks 0.3": ['aggregate.loops="necks"', "aggregate.neck_gap=0.3"]}


def load_paths(s) -> int:
    """The fewest bonds whose removal separates the slab's substrate from its top layer (the deck's: centres
    within 3/4 of a mean diameter of the top): a maximum flow of unit bond capacities."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import maximum_flow

    x, d, n = s.positions, s.diameters, s.n_particles
    bottom = s.groups["substrate"]
    top = (x[:, 2] >= np.max(x[:, 2] + d / 2) - 0.75 * d.mean()) & ~bottom
    b = s.bonds
    rows = np.concatenate([b[:, 0], b[:, 1], np.full(bottom.sum(), n), np.flatnonzero(top)])
    cols = np.concatenate([b[:, 1], b[:, 0], np.flatnonzero(bottom), np.full(top.sum(), n + 1)])
    cap = np.concatenate([np.ones(2 * len(b), np.int32), np.full(bottom.sum() + top.sum(), 1 << 30, np.int32)])
    return int(maximum_flow(csr_matrix((cap, (rows, cols)), shape=(n + 2, n + 2)), n, n + 1).flow_value)


def loops(a) -> list[dict]:
    """Each loop model on the same 5 seeds: the network's counts, whether the periodic cube wraps, the
    slab's load paths and its static E."""
    import tempfile

    from opalflow.aerogel.loops import winding_rank
    from opalflow.aerogel.scene import build_aerogel, make_aggregate, periodic_structure
    from opalflow.api import load_workflow, run

    out = []
    for name, sets in LOOP_CASES.items():
        for seed in range(1, 6):
            common = [*sets, "aggregate.particles=20000", f"aggregate.seed={seed}", "compression.method=static",
                      'compression.solver="direct"']
            spec = load_workflow("aerogel_compression", set=common)
            agg, cutoff, _ = make_aggregate(spec.aggregate, spec.bonds.cutoff_factor)
            cube = periodic_structure(agg, cutoff, "silica")
            slab_paths = load_paths(build_aerogel(spec))
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                run("aerogel_compression", Path(tmp) / "r", set=common, quiet=True)
                summ = json.loads((Path(tmp) / "r" / "summary.json").read_text())
            row = {"model": name, "seed": seed, "particles": 20000, "solid_fraction": 0.05, "seconds": time.perf_counter() - t,
                   "cube_coordination": 2 * cube.n_bonds / cube.n_particles,
                   "cube_loops_per_10k": 1e4 * (cube.n_bonds - cube.n_particles + 1) / cube.n_particles,
                   "winding_rank": winding_rank(cube.positions, cube.bonds, agg.box), "slab_load_paths": slab_paths,
                   "E_kPa": summ["youngs_modulus_GPa"] * 1e6, "energy_split": summ["energy_split"],
                   "slab_coordination": summ["mean_coordination"], "slab_particles": summ["n_particles"]}
            print(row, flush=True)
            out.append(row)
    return out


def cube(a) -> list[dict]:
    """The restructured network's periodic cube (20 000 spheres at 0.05, seeds 1-5): Hill's E and nu from
    the static tensor, the anisotropy index, beside the slab's E of the same aggregate."""
    import tempfile

    from opalflow.api import run

    out = []
    for seed in range(1, 6):
        common = ['aggregate.loops="restructuring"', "aggregate.particles=20000", f"aggregate.seed={seed}",
                  "compression.method=static", 'compression.solver="direct"']
        row = {"model": "restructuring", "seed": seed, "particles": 20000, "solid_fraction": 0.05}
        with tempfile.TemporaryDirectory() as tmp:
            try:
                run("aerogel_compression", Path(tmp) / "c", set=[*common, "sample.periodic_z=true"], quiet=True)
                c = json.loads((Path(tmp) / "c" / "summary.json").read_text())
                row.update(E_hill_kPa=c["youngs_modulus_isotropic_GPa"] * 1e6, nu_hill=c["poisson_ratio_isotropic"],
                           anisotropy_index=c["anisotropy_index"], E_xyz_kPa=[v * 1e6 for v in c["youngs_moduli_GPa"].values()],
                           )
            except Exception as e:                 # a cube that does not wrap in all three directions
                row.update(refused=str(e))
            run("aerogel_compression", Path(tmp) / "s", set=common, quiet=True)
            row["E_slab_kPa"] = json.loads((Path(tmp) / "s" / "summary.json").read_text())["youngs_modulus_GPa"] * 1e6
        print(row, flush=True)
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["designs", "dilute", "gel", "crossover", "rlca", "loops", "cube", "report"])
    ap.add_argument("--sizes", type=int, nargs="*", default=[2000, 4000])
    ap.add_argument("--n-compare", type=int, default=10000)
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--fractions", type=float, nargs="*", default=[0.0025, 0.005, 0.01, 0.02])
    a = ap.parse_args()
    data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    if a.part != "report":
        if a.part == "designs":
            rows = designs(a)
        elif a.part == "dilute":
            rows = [case(100_000, 0.002, seed) for seed in a.seeds]
        elif a.part == "gel":
            rows = [case(30_000, 0.01, seed) for seed in a.seeds]
        elif a.part == "crossover":
            rows = [case(30_000, phi, seed) for phi in a.fractions for seed in a.seeds]
        elif a.part == "loops":
            rows = loops(a)
        elif a.part == "cube":
            rows = cube(a)
        else:
            rows = [case(20_000, 0.002, seed, p=0.01) for seed in a.seeds] + \
                   [case(30_000, 0.01, seed, p=0.01) for seed in a.seeds]
        data[a.part] = {"rows": rows, "machine": {"host": platform.node(), "cpus": os.cpu_count(),
                                                  "python": platform.python_version(), "date": time.strftime("%Y-%m-%d")}}
        RESULTS.write_text(json.dumps(data, indent=1, default=float))
    report(data)


#: mean sphere volume of the benchmark's diameters, 10 +- 1 nm (nm^3): pi / 6 (mu^3 + 3 mu sigma^2)
V_MEAN = math.pi / 6 * (10.0**3 + 3 * 10.0 * 1.0**2)


def crossover_lines(part: dict) -> list[str]:
    """Two crossover lengths against solid fraction, each with its exponent: R_c = R_g(N_c), the size of the
    clusters at the crossover mass (by its definition (N_c v / phi)^(1/3) / (2 sqrt(5/3))), and xi, the
    cut-off length of the gel's g(r); expected ~ phi^(-1/(3 - D_f)) (Rottereau et al. 2004)."""
    rs = part["rows"]
    out = []
    for key, name in (("crossover_mass", "R_c = R_g(N_c)"), ("correlation_length_nm", "xi of g(r)")):
        ok = [r for r in rs if math.isfinite(r[key])]
        if len({r["solid_fraction"] for r in ok}) < 2:
            continue
        phi = np.array([r["solid_fraction"] for r in ok])
        y = np.array([r[key] for r in ok])
        if key == "crossover_mass":
            y = (y * V_MEAN / phi) ** (1 / 3) / (2 * math.sqrt(5 / 3))
        k, c = np.polyfit(np.log(phi), np.log(y), 1)
        part[f"exponent_{key}"] = float(k)
        out += [f"{name} ~ phi^k: k = {k:.3f} (expected -1/(3 - D_f) = -0.833 for D_f = 1.8); at "
                + ", ".join(f"{f:g}: {np.mean(y[phi == f]):.4g} nm" for f in sorted(set(phi))) + "."]
    return out + [""]


def _d(row, method):
    f = row[method]
    return "-" if not math.isfinite(f["D"]) else f"{f['D']:.3f} [{f['ci95'][0]:.3f}, {f['ci95'][1]:.3f}]"


def report(data: dict) -> None:
    """bench/results/aerogel.md: every table of the parts run so far."""
    out = ["# Aerogel aggregation and fractal dimension (bench/bench_aerogel.py)", ""]
    head = ("| particles | solid fraction | seed | stepping | sticking | s | R_g(N) (dilute) | g(r) | S(q) | mass-radius "
            "| crossover mass | xi (nm) |")
    line = "|---" * 12 + "|"

    def rows(rs):
        return [f"| {r['particles']} | {r['solid_fraction']:g} | {r['seed']} | {r['stepping']} | {r['sticking']:g} | "
                f"{r['seconds']:.1f} | {_d(r, 'R_g(N)')} | {_d(r, 'g(r)')} | {_d(r, 'S(q)')} | {_d(r, 'mass-radius')} | "
                f"{r['crossover_mass']:.4g} | {r['correlation_length_nm']:.4g} |" for r in rs]

    if "designs" in data:
        d = data["designs"]["rows"]
        out += ["## Designs: fixed steps against free-distance jumps", "", "| particles | solid fraction | stepping | s | "
                "moves | jumps |", "|---|---|---|---|---|---|"]
        out += [f"| {r['particles']} | {r['solid_fraction']:g} | {r['stepping']} | {r['seconds']:.1f} | {r['moves']} | "
                f"{r['jumps']} |" for r in d["cost_0.002"]]
        out += ["", "The same D at 0.01:", "", head, line, *rows(d["compare_0.01"]), ""]
    for part, title in (("dilute", "Dilute clusters: 100 000 spheres at 0.002"), ("gel", "The gel at 0.01"),
                        ("crossover", "Correlation length against concentration"), ("rlca", "RLCA, sticking 0.01")):
        if part not in data:
            continue
        out += [f"## {title}", "", head, line, *rows(data[part]["rows"]), ""]
        if part == "crossover":
            out += crossover_lines(data[part])
    if "loops" in data:
        rs = data["loops"]["rows"]
        out += ["## Loop models (20 000 spheres at 0.05, seeds 1-5; slab E static)", "",
                "| model | coordination | loops per 10 000 | cube wraps in (of 3) | slab load paths | E (kPa) | E max/min | "
                "energy bending / twisting / shear / stretching |", "|---|---|---|---|---|---|---|---|"]
        for name in dict.fromkeys(r["model"] for r in rs):
            m = [r for r in rs if r["model"] == name]
            e = [r["E_kPa"] for r in m]
            split = {k: np.mean([r["energy_split"][k] for r in m]) for k in ("bending", "twisting", "shear", "stretching")}
            out.append(f"| {name} | {np.mean([r['cube_coordination'] for r in m]):.3f} | "
                       f"{np.mean([r['cube_loops_per_10k'] for r in m]):.0f} | {', '.join(str(r['winding_rank']) for r in m)} | "
                       f"{', '.join(str(r['slab_load_paths']) for r in m)} | {', '.join(f'{x:.3g}' for x in e)} | "
                       f"{max(e) / min(e):.1f} | " + " / ".join(f"{100 * split[k]:.0f} %" for k in split) + " |")
        out.append("")
    if "cube" in data:
        out += ["## The periodic cube (restructuring, 20 000 spheres at 0.05)", "",
                "| seed | E Hill (kPa) | nu Hill | A^U | E x / y / z (kPa) | slab E (kPa) |", "|---|---|---|---|---|---|"]
        out += [f"| {r['seed']} | " + (f"{r['E_hill_kPa']:.3g} | {r['nu_hill']:.3f} | {r['anisotropy_index']:.2f} | "
                                       + " / ".join(f"{x:.3g}" for x in r["E_xyz_kPa"]) if "E_hill_kPa" in r
                                       else f"refused: {r['refused'][:60]} | - | - | -")
                + f" | {r['E_slab_kPa']:.3g} |" for r in data["cube"]["rows"]]
        out.append("")
    (HERE / "results" / "aerogel.md").write_text("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
