"""Benchmark of the aerogel aggregation (opalflow/aerogel/aggregation.py) and its fractal dimension
(opalflow/aerogel/fractal.py) where the literature measures it.

    python bench/bench_aerogel.py designs      # fixed steps against free-distance jumps: cost at 0.002, D at 0.01
    python bench/bench_aerogel.py dilute       # 100 000 spheres at 0.002: D by R_g(N) of the dilute clusters
    python bench/bench_aerogel.py gel          # 30 000 spheres at 0.01: D by g(r) and S(q) of the gel
    python bench/bench_aerogel.py crossover    # the correlation length at four concentrations, its exponent
    python bench/bench_aerogel.py rlca         # RLCA (sticking 0.01) by the same methods
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
from opalflow.aerogel.run import fractal_fits

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "aerogel.json"


def one(n: int, phi: float, seed: int, *, stepping: str = "jump", p: float = 1.0):
    d = gaussian_diameters(n, 10.0, 1.0, np.random.default_rng(seed))
    return aggregate(d, box_edge(d, phi), seed=seed, stepping=stepping, sticking_probability=p)


def fits_row(agg, seed: int) -> dict:
    """Every D of an aggregate, with its interval, range and note; the crossover mass and length."""
    fits = fractal_fits(agg, seed)
    row = {m: {"D": f.D, "ci95": list(f.ci95), "range": list(f.range), "points": f.points, "note": f.note}
           for m, (f, _) in fits.items()}
    row["crossover_mass"] = fits["R_g(N)"][1]["crossover_mass"]
    row["correlation_length_nm"] = fits["g(r)"][1]["xi_nm"]
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["designs", "dilute", "gel", "crossover", "rlca", "report"])
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
        else:
            rows = [case(20_000, 0.002, seed, p=0.01) for seed in a.seeds] + \
                   [case(30_000, 0.01, seed, p=0.01) for seed in a.seeds]
        data[a.part] = {"rows": rows, "machine": {"host": platform.node(), "cpus": os.cpu_count(),
                                                  "python": platform.python_version(), "date": time.strftime("%Y-%m-%d")}}
        RESULTS.write_text(json.dumps(data, indent=1, default=float))
    report(data)


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
            rs = data[part]["rows"]
            ok = [r for r in rs if math.isfinite(r["correlation_length_nm"])]
            if len({r["solid_fraction"] for r in ok}) >= 2:
                k, c = np.polyfit(np.log([r["solid_fraction"] for r in ok]), np.log([r["correlation_length_nm"] for r in ok]), 1)
                data[part]["exponent"] = float(k)
                out += [f"xi ~ phi^k: k = {k:.3f} (expected -1/(3 - D_f): -0.833 for D_f = 1.8); xi = "
                        f"{math.exp(c):.4g} nm x phi^k.", ""]
    (HERE / "results" / "aerogel.md").write_text("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
