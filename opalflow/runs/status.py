"""``python -m opalflow status DIR``: what the runs of a folder are doing, whatever ran them.

Everything comes from the folders: a study's ``jobs/*/job.json`` (state, error, log tail, host, SLURM
job), each run's ``run.json`` (sessions, requeues) and ``progress.json`` (step, rate, time left, written
by the running LAMMPS loop), and ``summary.json`` (the headline of a finished run).
"""
from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

from opalflow.runs.jobs import read_job
from opalflow.runs.record import RunRecord, is_finished, read_summary
from opalflow.spec import SpecError

STATES = ("pending", "running", "requeued", "finished", "failed")


def _progress(folder: Path) -> tuple[str, float | None]:
    """What the running job says (step, rate, time left; or its last message) and its seconds left."""
    import json

    try:
        p = json.loads((folder / "progress.json").read_text())
    except (OSError, ValueError):
        return "", None
    age = time.time() - p.get("time", 0)
    stale = f" (as of {age:.0f} s ago)" if age > 30 else ""
    if "message" in p:
        return p["message"] + stale, None
    left = p.get("left_s")
    return (f"step {p['step']}/{p['total']} ({100 * p['step'] / max(p['total'], 1):.0f} %), "
            f"{p['rate_steps_s']:.0f} steps/s, {'?' if left is None else f'{left:.0f} s'} left{stale}"), left


def run_state(folder: Path) -> tuple[str, dict]:
    """(state, job.json or {}) of one run or job folder."""
    meta = read_job(folder)
    if is_finished(folder):
        return "finished", meta
    if meta.get("state") in STATES:
        return meta["state"], meta
    if RunRecord.exists(folder):
        try:
            rec = RunRecord.read(folder)
            return {"built": "pending", "interrupted": "requeued"}.get(rec.state, rec.state), meta
        except SpecError:
            pass
    return "pending", meta


def status_lines(folder: str | Path, tail: int = 8) -> list[str]:
    folder = Path(folder)
    if not folder.is_dir():
        raise SpecError("folder", str(folder), "is not a folder")
    jobs = sorted(p.parent for p in folder.glob("jobs/*/job.json"))
    if not jobs:
        if not RunRecord.exists(folder) and not (folder / "job.json").exists():
            raise SpecError("folder", str(folder), "holds neither a study (jobs/*/job.json) nor a run (run.json)")
        jobs = [folder]
    rows, counts, lefts = [], Counter(), []
    for job in jobs:
        state, meta = run_state(job)
        counts[state] += 1
        label = meta.get("label", job.name)
        where = " ".join(x for x in (meta.get("host", ""), f"slurm {meta['slurm_job']}" if meta.get("slurm_job") else "")
                         if x)
        if state == "finished":
            s = read_summary(job) or {}
            wall = s.get("wall_s")
            rows.append(f"  finished  {label}: {s.get('headline', '')}" + (f" ({wall:.0f} s)" if wall else ""))
        elif state == "failed":
            rows.append(f"  FAILED    {label}: {meta.get('error', '')} [{job}]")
            rows += [f"            | {line}" for line in meta.get("log_tail", "").splitlines()[-tail:]]
        elif state in ("running", "requeued"):
            said, left = _progress(job)
            if state == "running":
                lefts.append(left)
            rows.append(f"  {state:<9} {label}: {said or 'starting'}{_sessions(job)}" + (f" [{where}]" if where else ""))
        else:
            rows.append(f"  pending   {label}")
    head = f"{folder}: {len(jobs)} job(s): " + ", ".join(f"{counts[s]} {s}" for s in STATES if counts[s])
    if lefts and all(x is not None for x in lefts):
        head += f"; running jobs done in ~{max(lefts):.0f} s"
    return [head, *rows]


def _sessions(folder: Path) -> str:
    try:
        rec = RunRecord.read(folder)
    except SpecError:
        return ""
    return f", {len(rec.sessions)} session(s), {rec.requeues} requeue(s)" if rec.sessions else ""
