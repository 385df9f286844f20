"""Stiffness error of length-binned bond types against the bin count.

    python bench/bench_bond_bins.py [WORKFLOW]

kt and kb of bpm/rotational scale with 1/L0; a bond type per length bin uses one
length for all its bonds.  For bin counts 1..32 this prints and writes
(bench/results/bond_bins_<workflow>.json) the largest and rms relative error of a
bond's kb and kt, and the number of bond types.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from opalflow.bpm.deck import bin_bonds
from opalflow.bpm.pipeline import build_structure
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec

HERE = Path(__file__).resolve().parent


def main() -> int:
    workflow = sys.argv[1] if len(sys.argv) > 1 else "quickstart"
    s = build_structure(load_spec(WORKFLOWS / f"{workflow}.toml"))
    rows = []
    for n in (1, 2, 4, 8, 16, 32):
        b = bin_bonds(s, n)
        rows.append({"bins": n, "bond_types": len(b.lengths), "error_max": b.stiffness_error_max,
                     "error_rms": b.stiffness_error_rms})
        print(f"{n:3d} bins: {len(b.lengths):3d} types, kb/kt error max {100 * b.stiffness_error_max:5.2f} %, "
              f"rms {100 * b.stiffness_error_rms:5.2f} %")
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"bond_bins_{workflow}.json").write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
