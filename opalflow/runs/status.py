"""``python -m opalflow status DIR``: what the runs of a folder are doing, whatever ran them.

Everything comes from the folders: each run's record (``run.json``: state, sessions, requeues, error and
log tail; a study's jobs are ``jobs/*/``), ``progress.json`` (step, rate, time left, or the job's last
message: :mod:`opalflow.progress`) and ``summary.json`` (the headline of a finished run).
"""
from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

from opalflow import registry
from opalflow.progress import PROGRESS_FILE, ProgressNote
from opalflow.runs.record import RunRecord
from opalflow.runs.result import is_finished, read_summary
from opalflow.spec import InputError, SpecError, is_number
from opalflow.store import RECORD, SUMMARY, DamagedFile, lock_owner, process_alive

#: the record's states (opalflow.runs.record.STATES, built shown as pending) and what status sees besides:
#: died (running, its process gone) and damaged (the record cannot be read)
SHOWN = ("pending", "running", "requeued", "interrupted", "died", "finished", "failed", "damaged")


def _progress(folder: Path) -> tuple[str, float | None]:
    """What the running job says (step, rate, time left; or its last message) and its seconds left; a
    progress.json that is damaged or holds other types says so instead (the run itself is not judged by it)."""
    try:
        p = ProgressNote.read(folder)
    except DamagedFile:
        return ("" if not (folder / PROGRESS_FILE).exists() else f"{PROGRESS_FILE} unreadable"), None
    age = time.time() - p.time if p.time is not None else 0.0
    stale = f" (as of {age:.0f} s ago)" if age > 30 else ""
    if p.message is not None:
        return p.message + stale, None
    if p.step is None or p.total is None or p.rate_steps_s is None:
        return f"{PROGRESS_FILE} holds no step count (damaged?)", None
    rate = f"{p.rate_steps_s:.0f}" if p.rate_steps_s >= 10 else f"{p.rate_steps_s:.2g}"
    return (f"{p.unit} {p.step:.0f}/{p.total:.0f} ({100 * p.step / max(p.total, 1):.0f} %), {rate} {p.unit}s/s, "
            f"{'?' if p.left_s is None else f'{p.left_s:.0f} s'} left{stale}"), p.left_s


def how_to_go_on(folder: str | Path) -> str:
    """What continues an interrupted run in ``folder`` (the same line the run prints when it stops): its
    resume where the kind resumes and something was saved to resume from, else running it again."""
    folder = Path(folder)
    try:
        rec = RunRecord.read(folder)
        kind = registry.get(rec.spec.get("kind", registry.DEFAULT_KIND))
    except InputError:
        return f"nothing was prepared in {folder} yet: run the same command again"
    if rec.spec_hash:
        return "run the study again: it continues this job"
    if "resume" in kind.options:
        if kind.resumable and not registry.resolve(kind.resumable)(folder):
            return "no restart file was written yet: run the same command again (it starts anew)"
        return f"resume with: python -m opalflow run --out {folder} --resume"
    return f"finished parts are kept in {folder}: run the same command again to go on"


def run_state(folder: Path) -> tuple[str, dict]:
    """(state, facts: label, error, log tail, host, SLURM job, ``where``) of one run or job folder, from its
    record and the process that holds it (the folder's lock, else the last session's process and host):

    - ``running``: the record says so and the process lives (or runs on another host: ``where`` says so);
    - ``died``: the record says running but its process is gone (killed by SIGKILL, the machine lost);
    - ``interrupted`` (Ctrl-C, SIGTERM) and ``requeued`` (stopped by SLURM to go on in a requeued job);
    - ``damaged``: run.json cannot be read (``error`` names the file and what to do).
    """
    if is_finished(folder):
        rec = RunRecord.read_or_none(folder)
        return "finished", {"label": rec.label} if rec is not None and rec.label else {}
    if not RunRecord.exists(folder):
        return "pending", {}
    try:
        rec = RunRecord.read(folder)
    except InputError as exc:
        return "damaged", {"error": str(exc)}
    last = rec.sessions[-1] if rec.sessions else None
    meta = {"error": rec.error, "log_tail": rec.log_tail, "host": last.host if last else "",
            "slurm_job": last.slurm_job if last else ""}
    if rec.label:
        meta["label"] = rec.label
    state = {"built": "pending"}.get(rec.state, rec.state)
    if state == "interrupted" and last and last.slurm_job:
        state = "requeued"
    if state == "running":
        owner = lock_owner(folder) or ((last.pid, last.host) if last and last.pid else None)
        alive = process_alive(*owner) if owner else False
        if alive is False:
            state = "died"
            meta["error"] = ((f"its process (pid {owner[0]}) is gone" if owner else "no process holds it")
                             + " without ending the run (killed?): "
                             + how_to_go_on(folder))
        elif alive is None:
            meta["where"] = f"on {owner[1]}, not checked from here"
    return state, meta


def status_lines(folder: str | Path, tail: int = 8) -> list[str]:
    folder = Path(folder)
    if not folder.is_dir():
        raise SpecError("folder", str(folder), "is not a folder")
    jobs = sorted(p.parent for p in folder.glob(f"jobs/*/{RECORD}"))
    if not jobs:
        if not RunRecord.exists(folder):
            raise SpecError("folder", str(folder), f"holds neither a study (jobs/*/{RECORD}) nor a run ({RECORD})")
        jobs = [folder]
    rows, counts, lefts = [], Counter(), []
    for job in jobs:
        state, meta = run_state(job)
        counts[state] += 1
        label = meta.get("label", job.name)
        where = meta.get("where") or " ".join(
            x for x in (meta.get("host", ""), f"slurm {meta['slurm_job']}" if meta.get("slurm_job") else "") if x)
        if state == "finished":
            s = read_summary(job)
            if s is None or not isinstance(s.get("headline"), str):
                rows.append(f"  finished  {label}: its {SUMMARY} is missing or damaged: `python -m opalflow "
                            f"analyze {job}` writes it again")
                continue
            wall = s.get("wall_s")
            took = f" ({wall:.0f} s)" if is_number(wall) else ""
            rows.append(f"  finished  {label}: {s['headline']}" + took)
        elif state in ("failed", "died", "damaged"):
            rows.append(f"  {state.upper():<9} {label}: {meta.get('error') or 'no reason recorded'} [{job}]")
            rows += [f"            | {line}" for line in meta.get("log_tail", "").splitlines()[-tail:]]
        elif state == "interrupted":
            rows.append(f"  {state:<11} {label}: stopped (Ctrl-C or SIGTERM){_sessions(job)}; {how_to_go_on(job)}")
        elif state in ("running", "requeued"):
            said, left = _progress(job)
            if state == "running":
                lefts.append(left)
            rows.append(f"  {state:<9} {label}: {said or 'starting'}{_sessions(job)}" + (f" [{where}]" if where else ""))
        else:
            rows.append(f"  pending   {label}")
    head = f"{folder}: {len(jobs)} job(s): " + ", ".join(f"{counts[s]} {s}" for s in SHOWN if counts[s])
    if lefts and all(x is not None for x in lefts):
        head += f"; running jobs done in ~{max(lefts):.0f} s"
    return [head, *rows]


def _sessions(folder: Path) -> str:
    try:
        rec = RunRecord.read(folder)
    except InputError:
        return ""
    return f", {len(rec.sessions)} session(s), {rec.requeues} requeue(s)" if rec.sessions else ""
