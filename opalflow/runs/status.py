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


def _progress(folder: Path) -> str:
    import json

    try:
        p = json.loads((folder / "progress.json").read_text())
    except (OSError, ValueError):
        return ""
    age = time.time() - p.get("time", 0)
    if "message" in p:
        return p["message"] + (f" (as of {age:.0f} s ago)" if age > 30 else "")
    left = p.get("left_s")
    return (f"step {p['step']}/{p['total']} ({100 * p['step'] / max(p['total'], 1):.0f} %), "
            f"{p['rate_steps_s']:.0f} steps/s, {'?' if left is None else f'{left:.0f} s'} left"
            + (f" (as of {age:.0f} s ago)" if age > 30 else ""))


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
    rows, counts = [], Counter()
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
            rec_note = ""
            if RunRecord.exists(job):
                try:
                    rec = RunRecord.read(job)
                    rec_note = f", {len(rec.sessions)} session(s), {rec.requeues} requeue(s)" if rec.sessions else ""
                except SpecError:
                    pass
            rows.append(f"  {state:<9} {label}: {_progress(job) or 'starting'}{rec_note}" + (f" [{where}]" if where else ""))
        else:
            rows.append(f"  pending   {label}")
    head = f"{folder}: {len(jobs)} job(s): " + ", ".join(f"{counts[s]} {s}" for s in STATES if counts[s])
    left = [_left(j) for j in jobs if run_state(j)[0] == "running"]
    if left and all(x is not None for x in left):
        head += f"; running jobs done in ~{max(left):.0f} s"
    return [head, *rows]


def _left(folder: Path) -> float | None:
    import json

    try:
        return json.loads((folder / "progress.json").read_text()).get("left_s")
    except (OSError, ValueError):
        return None
