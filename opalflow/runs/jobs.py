"""Jobs: runs of one workflow spec each, in folders named by the spec's hash, so that each is done once.

A job's folder is ``<root>/jobs/<label>-<hash12>``; its ``job.json`` holds the label, the hash (SHA-256
of the spec's canonical JSON), the spec and the job's state: ``pending`` -> ``running`` -> ``finished``
or ``failed`` (with the error and the LAMMPS log tail) or ``requeued`` (a scheduler stopped it; it
continues from its restart file).  Whatever ran it (a local pool, Dask, a SLURM array), a job's result
lives in its folder: a rerun skips finished jobs, and :mod:`opalflow.runs.status` reads any of them.
"""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from opalflow.runs.progress import note
from opalflow.runs.record import finished_summary, run_kind, slurm_job
from opalflow.spec import WorkflowSpec
from opalflow.store import DamagedFile, read_json, write_json_atomic

JOB_FILE = "job.json"


def spec_hash(spec: WorkflowSpec) -> str:
    """SHA-256 of the spec's canonical JSON (keys sorted): equal specs, equal jobs."""
    text = json.dumps(spec.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass
class Job:
    label: str                  # [A-Za-z0-9_.-]+, shown in reports
    spec: WorkflowSpec

    @property
    def key(self) -> str:
        return spec_hash(self.spec)

    def folder(self, root: Path) -> Path:
        return Path(root) / "jobs" / f"{self.label}-{self.key[:12]}"


def read_job(folder: str | os.PathLike, *, strict: bool = False) -> dict:
    """The job.json of a job folder: {} where there is none, and where it is damaged unless ``strict``
    (then :class:`opalflow.store.DamagedFile`; a study runs a job with a damaged job.json anew)."""
    path = Path(folder) / JOB_FILE
    if not path.exists():
        return {}
    try:
        return read_json(path, "a study job's state", "run the study again: the job runs anew")
    except DamagedFile:
        if strict:
            raise
        return {}


def update_job(folder: str | os.PathLike, **fields) -> dict:
    meta = {**read_job(folder), **fields}
    write_json_atomic(Path(folder) / JOB_FILE, meta)
    return meta


def finished(job: Job, root: Path) -> dict | None:
    """The job's summary if it has completed with this very spec, else None."""
    folder = job.folder(root)
    return finished_summary(folder) if read_job(folder).get("hash") == job.key else None


def outcome(folder: str | os.PathLike) -> dict:
    """What a job folder holds now: its summary when finished, else ``{"failed": ..., "log_tail": ...}``
    (with ``"state"``: failed, or pending / running / requeued for one that has not ended)."""
    summary = finished_summary(folder)
    if summary is not None:
        return summary
    meta = read_job(folder)
    state = meta.get("state", "pending")
    if state == "failed":
        return {"failed": meta.get("error", "failed"), "log_tail": meta.get("log_tail", ""), "folder": str(folder),
                "state": "failed"}
    return {"failed": f"not finished ({state})", "log_tail": meta.get("log_tail", ""), "folder": str(folder),
            "state": state}


def log_tail(folder: Path, lines: int = 15) -> str:
    """The last lines of the job's LAMMPS log, if it wrote one."""
    logs = sorted(Path(folder).glob("**/log.lammps"), key=lambda p: p.stat().st_mtime)
    if not logs:
        return ""
    return "\n".join(logs[-1].read_text(errors="replace").splitlines()[-lines:])


def _stop_on_signals() -> None:
    """SIGUSR1 (SLURM's warning before the time limit) and SIGTERM: write a restart and stop."""
    from opalflow.lammps.engine import request_stop

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGUSR1, signal.SIGTERM):
            signal.signal(sig, request_stop)


def run_job(folder: str, np_: int = 1, threads: int = 1) -> dict:
    """Run the job in ``folder`` (its job.json says what) and return its outcome: the summary, or
    ``{"failed": first line, "log_tail": ..., "folder": ...}``; a job stopped by its scheduler's signal
    writes a restart file, is requeued (SLURM) and returns ``{"requeued": True}``.  It never raises:
    one failed job must not end a study.

    BLAS and OpenMP run ``threads`` threads in the job (threadpoolctl), whatever the executor's process
    inherited: the same sums in the same order, so a job gives the same numbers to the last digit on a
    local pool, a Dask worker or a SLURM node, and jobs side by side do not oversubscribe the cores."""
    import scipy.linalg  # noqa: F401 - load every BLAS/OpenMP library first: threadpoolctl limits the loaded ones
    import scipy.sparse.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=threads):
        return _run_job(Path(folder).resolve(), np_)


def _run_job(folder: Path, np_: int) -> dict:
    from opalflow import registry
    from opalflow.lammps.engine import Preempted

    meta = read_job(folder)
    label = meta.get("label", folder.name)
    done = finished_summary(folder)
    if done is not None:
        return done

    last = [0.0]

    def say(msg: str) -> None:
        print(f"[{label}] {msg}", file=sys.stderr, flush=True)
        if time.time() - last[0] > 2.0:          # what the job says last, for status (a LAMMPS run's
            last[0] = time.time()                # step counter writes progress.json itself)
            note(folder, msg)

    update_job(folder, state="running", host=os.uname().nodename, slurm_job=slurm_job(), pid=os.getpid(),
               attempted=time.time(), error="", log_tail="")
    _stop_on_signals()
    try:
        spec = registry.spec_from_dict(meta["spec"])
        kind = registry.get(spec.kind)
        # a stopped run goes on from what it left (the kind knows what: restart files, the quasi-static events)
        resume = ((folder / "run.json").exists() and "resume" in kind.options
                  and (not kind.resumable or registry.resolve(kind.resumable)(folder)))
        summary = run_kind(kind, spec, folder, np_=np_, resume=resume, say=say)
    except Preempted as exc:
        update_job(folder, state="requeued", stopped_step=exc.step)
        requeue_self(say)
        return {"requeued": True, "folder": str(folder)}
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - the job's failure is its result
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        tail = log_tail(folder)
        update_job(folder, state="failed", error=first, log_tail=tail, ended=time.time())
        return {"failed": first, "log_tail": tail, "folder": str(folder), "state": "failed"}
    update_job(folder, state="finished", ended=time.time(), peak_rss_MiB=peak_rss_MiB())
    return summary


def peak_rss_MiB() -> float:
    """Peak resident memory of this process and the LAMMPS processes it waited for (MiB)."""
    import resource

    return max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)) / 1024


def requeue_self(say) -> None:
    """Put this SLURM job back in the queue (it continues from its restart file when it starts again)."""
    job = os.environ.get("SLURM_JOB_ID")
    if not job:
        return
    res = subprocess.run(["scontrol", "requeue", job], capture_output=True, text=True)
    say(f"requeued SLURM job {job}" if res.returncode == 0 else f"scontrol requeue {job} failed: {res.stderr.strip()}")


def prepare(jobs: list[Job], root: Path) -> tuple[dict[str, dict], list[Job]]:
    """Summaries of the jobs finished before, and the others, each with a job.json (state pending)."""
    labels = [j.label for j in jobs]
    if len(set(labels)) != len(labels):
        raise ValueError("job labels must be unique")
    done, todo = {}, []
    for job in jobs:
        summary = finished(job, root)
        if summary is not None:
            done[job.label] = summary
            continue
        folder = job.folder(root)
        folder.mkdir(parents=True, exist_ok=True)
        old = read_job(folder)
        state = "pending" if old.get("state") in (None, "finished", "failed") else old["state"]
        write_json_atomic(folder / JOB_FILE, {"label": job.label, "hash": job.key, "spec": job.spec.to_dict(),
                                              "state": state})
        todo.append(job)
    return done, todo
