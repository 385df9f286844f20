"""The stability matrix: the stability check with bisection (:mod:`opalflow.bpm.stability`) over
corner cases of bonded-particle scenes, in one table.

Each row is a workflow with a few ``--set`` overrides.  Its figures: the deck's time step (the
estimate x ``compression.timestep_safety``), the estimator's stability limit, the largest stable time
step found by bisection, their ratio, and pass/fail at the deck's own time step with the criterion
that failed.  A row that fails at the automatic time step is a defect of the estimator or the deck.
"""
from __future__ import annotations

import time
from pathlib import Path

from opalflow.bpm.spec import StabilityMatrixWorkflow
from opalflow.bpm.stability import stability_check
from opalflow.registry import load_spec
from opalflow.resources import WORKFLOWS
from opalflow.spec import InputError
from opalflow.runs.record import finish
from opalflow.runs.result import Result
from opalflow.version import __version__


def run_matrix(spec: StabilityMatrixWorkflow, out: Path, say=print) -> Result:
    """Every row: build its scene, check it at the deck's time step and bisect the largest stable one."""
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for label, row in spec.matrix.rows.items():
        sets = list(row.get("set", []))
        say(f"[{label}] {row['workflow']} {' '.join(sets)}")
        t = time.perf_counter()
        try:
            job = load_spec(WORKFLOWS / f"{row['workflow']}.toml", sets)
            s = stability_check(job, out / "rows" / label, say=lambda m, lb=label: say(f"[{lb}] {m}"),
                                steps=spec.matrix.steps, strain=row.get("strain"), bisect=True)
        except InputError as exc:
            rows.append({"label": label, "workflow": row["workflow"], "set": sets, "error": str(exc)})
            say(f"[{label}] refused: {exc}")
            continue
        rows.append({"label": label, "workflow": row["workflow"], "set": sets, "strain": row.get("strain"),
                     "steps": s.steps, "passed": s.passed, "failed": s.failed, "timestep_s": s.timestep_estimate_s,
                     "timestep_limit_estimate_s": s.timestep_limit_estimate_s,
                     "timestep_stable_max_s": s.timestep_stable_max_s, "ratio": s.estimate_over_bisected,
                     "stiffest_mode": s.stiffest_mode, "seconds": time.perf_counter() - t})
    done = [r for r in rows if "error" not in r]
    stable = [r for r in done if r["passed"]]
    in_range = [r for r in done if r["ratio"] is not None and 0.5 <= r["ratio"] <= 1.0]
    summary = {"rows": rows, "steps": spec.matrix.steps, "wall_s": time.perf_counter() - t0,
               "opalflow_version": __version__, "spec": spec.to_dict(),
               "headline": f"{len(stable)} of {len(rows)} rows stable at the automatic time step; estimate / "
                           f"bisected limit in [0.5, 1] for {len(in_range)} of {len(done)}"}
    lines = [f"# Stability matrix ({spec.name})", "",
             f"Each row: the stability check (`python -m opalflow check`, criteria in opalflow/bpm/stability.py) "
             f"over {spec.matrix.steps} time steps (or up to the strain given) at the deck's time step, and the largest stable time step by "
             "bisection. Ratio = the estimator's stability limit / the bisected one (the deck runs at "
             "`timestep_safety` = 0.8 of the limit).", "",
             "| row | workflow and overrides | dt of the deck (s) | estimated limit (s) | bisected limit (s) | "
             "ratio | stiffest mode | at the deck's dt | time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        what = f"`{r['workflow']}` " + " ".join(f"`{x}`" for x in r["set"])
        if r.get("strain"):
            what += f" to strain {r['strain']:g}"
        if "error" in r:
            lines.append(f"| {r['label']} | {what} | - | - | - | - | - | refused: {r['error']} | - |")
            continue
        lines.append(f"| {r['label']} | {what} | {r['timestep_s']:.3g} | {r['timestep_limit_estimate_s']:.3g} | "
                     f"{r['timestep_stable_max_s']:.3g} | {r['ratio']:.2f} | {r['stiffest_mode']} | "
                     f"{'pass' if r['passed'] else 'FAIL: ' + r['failed']} | {r['seconds']:.0f} |")
    lines += ["", summary["headline"] + f". Wall time {summary['wall_s']:.0f} s."]
    return finish(out, summary, "\n".join(lines))
