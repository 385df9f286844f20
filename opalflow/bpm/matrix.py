"""The stability matrix: the stability check with bisection (:mod:`opalflow.bpm.stability`) over
corner cases of bonded-particle scenes, in one table.

Each row is a workflow with a few ``--set`` overrides.  Its figures: the deck's time step (the
estimate x ``compression.timestep_safety``), the estimator's stability limit, the largest stable time
step found by bisection, their ratio, and pass/fail at the deck's own time step with the criterion
that failed.  A row that fails at the automatic time step is a defect of the estimator or the deck.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from opalflow.bpm.spec import StabilityMatrixWorkflow
from opalflow.bpm.stability import stability_check
from opalflow.registry import load_spec
from opalflow.resources import WORKFLOWS
from opalflow.spec import InputError
from opalflow.runs.record import finish
from opalflow.runs.result import Result
from opalflow.version import __version__


@dataclass
class Refused:
    """A row whose workflow and overrides are not a valid spec: the one line that says why."""

    label: str
    workflow: str
    set: list[str]
    error: str


@dataclass
class Checked:
    """A row checked: its :class:`opalflow.bpm.stability.StabilityCheck` at the deck's time step and the bisected
    limit (``ratio`` = the estimated limit / the bisected one)."""

    label: str
    workflow: str
    set: list[str]
    strain: float | None
    steps: int
    passed: bool
    failed: str
    timestep_s: float
    timestep_limit_estimate_s: float
    timestep_stable_max_s: float | None
    ratio: float | None
    stiffest_mode: str
    seconds: float


def run_matrix(spec: StabilityMatrixWorkflow, out: Path, say=print) -> Result:
    """Every row: build its scene, check it at the deck's time step and bisect the largest stable one."""
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[Checked | Refused] = []
    for label, row in spec.matrix.rows.items():
        workflow, sets, strain = row["workflow"], list(row.get("set", [])), row.get("strain")
        say(f"[{label}] {workflow} {' '.join(sets)}")
        t = time.perf_counter()
        try:
            job = load_spec(WORKFLOWS / f"{workflow}.toml", sets)
            s = stability_check(job, out / "rows" / label, say=lambda m, lb=label: say(f"[{lb}] {m}"),
                                steps=spec.matrix.steps, strain=strain, bisect=True)
        except InputError as exc:
            rows.append(Refused(label, workflow, sets, str(exc)))
            say(f"[{label}] refused: {exc}")
            continue
        rows.append(Checked(label, workflow, sets, strain, s.steps, s.passed, s.failed, s.timestep_estimate_s,
                            s.timestep_limit_estimate_s, s.timestep_stable_max_s, s.estimate_over_bisected,
                            s.stiffest_mode, time.perf_counter() - t))
    done = [r for r in rows if isinstance(r, Checked)]
    stable = [r for r in done if r.passed]
    in_range = [r for r in done if r.ratio is not None and 0.5 <= r.ratio <= 1.0]
    headline = (f"{len(stable)} of {len(rows)} rows stable at the automatic time step; estimate / "
                f"bisected limit in [0.5, 1] for {len(in_range)} of {len(done)}")
    wall_s = time.perf_counter() - t0
    summary = {"rows": rows, "steps": spec.matrix.steps, "wall_s": wall_s, "opalflow_version": __version__,
               "spec": spec.to_dict(), "headline": headline}
    lines = [f"# Stability matrix ({spec.name})", "",
             f"Each row: the stability check (`python -m opalflow check`, criteria in opalflow/bpm/stability.py) "
             f"over {spec.matrix.steps} time steps (or up to the strain given) at the deck's time step, and the largest stable time step by "
             "bisection. Ratio = the estimator's stability limit / the bisected one (the deck runs at "
             "`timestep_safety` = 0.8 of the limit).", "",
             "| row | workflow and overrides | dt of the deck (s) | estimated limit (s) | bisected limit (s) | "
             "ratio | stiffest mode | at the deck's dt | time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        what = f"`{r.workflow}` " + " ".join(f"`{x}`" for x in r.set)
        if isinstance(r, Refused):
            lines.append(f"| {r.label} | {what} | - | - | - | - | - | refused: {r.error} | - |")
            continue
        if r.strain:
            what += f" to strain {r.strain:g}"
        lines.append(f"| {r.label} | {what} | {r.timestep_s:.3g} | {r.timestep_limit_estimate_s:.3g} | "
                     f"{r.timestep_stable_max_s:.3g} | {r.ratio:.2f} | {r.stiffest_mode} | "
                     f"{'pass' if r.passed else 'FAIL: ' + r.failed} | {r.seconds:.0f} |")
    lines += ["", headline + f". Wall time {wall_s:.0f} s."]
    return finish(out, summary, "\n".join(lines))
