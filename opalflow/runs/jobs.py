"""Jobs: runs of one workflow spec each, in folders named by the spec's hash, so that each is done once.

A job's folder is ``<root>/jobs/<label>-<hash12>``, a run folder like any other: its record (``run.json``,
:class:`opalflow.runs.record.RunRecord`) holds the label, the hash (SHA-256 of the spec's canonical JSON),
the spec and the state: ``pending`` -> ``running`` -> ``finished`` or ``failed`` (with the error and the
LAMMPS log tail) or ``requeued`` (a scheduler stopped it; it continues from where it stopped).  Whatever
ran it (a local pool, Dask, a SLURM array), a job's result lives in its folder: a rerun skips finished jobs,
and :mod:`opalflow.runs.status` reads any of them.  What a job came to is an :class:`Outcome`.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from opalflow import registry
from opalflow.progress import note
from opalflow.runs.record import RunRecord, run_kind, spec_digest
from opalflow.runs.result import Result, finished_summary
from opalflow.spec import WorkflowSpec
from opalflow.store import RECORD, json_text


#: a job folder's note that SLURM's USR1 came (the array's script writes it: the signal may come before the job's
#: handler is in place, and the job reads the note then)
STOP_NOTE = "stop-requested"


def spec_hash(spec: WorkflowSpec) -> str:
    """SHA-256 of the spec's canonical JSON (keys sorted): equal specs, equal jobs."""
    return spec_digest(spec.to_dict())


@dataclass
class Job:
    label: str                  # [A-Za-z0-9_.-]+, shown in reports
    spec: WorkflowSpec
    at: tuple = ()              # where it sits in its study: the values swept (porosity and seed, ...)

    @property
    def key(self) -> str:
        return spec_hash(self.spec)

    def folder(self, root: Path) -> Path:
        return Path(root) / "jobs" / f"{self.label}-{self.key[:12]}"


@dataclass
class Outcome:
    """What a job came to: ``finished`` (its ``result``, of its kind's result class), ``failed`` (``error`` and the LAMMPS ``log_tail``),
    ``requeued`` (its scheduler stopped it at ``step``; the requeued job goes on from there), or ``pending`` /
    ``running`` where it was collected before it ended (``error`` says so)."""

    state: str
    folder: str
    result: Result | None = None
    error: str = ""
    log_tail: str = ""
    step: int | None = None

    @classmethod
    def finished(cls, folder: str | os.PathLike, kind: str, summary: dict) -> Outcome:
        """A finished job: its summary read back as ``kind``'s result class."""
        result_class = registry.get(kind).result_class() if kind else Result
        return cls("finished", str(folder), result_class.from_summary(summary))

    @property
    def ok(self) -> bool:
        return self.state == "finished"

    @property
    def summary(self) -> dict | None:
        """The finished job's summary.json as written, JSON's types (None where it has not finished)."""
        return None if self.result is None else json.loads(json_text(self.result.summary()))


def job_record(folder: str | os.PathLike) -> RunRecord | None:
    """The record of a job folder: None where there is none or it is damaged (a study runs such a job anew)."""
    return RunRecord.read_or_none(folder)


def finished(job: Job, root: Path) -> dict | None:
    """The job's summary if it has completed with this very spec, else None."""
    folder = job.folder(root)
    rec = job_record(folder)
    return finished_summary(folder) if rec is not None and rec.spec_hash == job.key else None


def outcome(folder: str | os.PathLike) -> Outcome:
    """What a job folder holds now: finished with its summary, failed with its error and log tail, or where
    it stands (pending, running, requeued) when it has not ended."""
    summary = finished_summary(folder)
    rec = job_record(folder)
    if summary is not None:
        return Outcome.finished(folder, rec.kind if rec is not None else "", summary)
    state = rec.state if rec is not None else "pending"
    if state == "failed":
        return Outcome("failed", str(folder), error=rec.error or "failed", log_tail=rec.log_tail)
    return Outcome(state, str(folder), error=f"not finished ({state})", log_tail=rec.log_tail if rec else "")


def settle(folder: Path, state: str, **fields) -> None:
    """The job's record ends ``state`` (with ``fields``: error, log tail, peak memory)."""
    rec = job_record(folder)
    if rec is None:
        return
    rec.state = state
    for k, v in fields.items():
        setattr(rec, k, v)
    rec.write(folder)


def file_tail(path: Path, lines: int = 15) -> str:
    """The last lines of a text file ("" where there is none)."""
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:]) if path.exists() else ""


def log_tail(folder: Path, lines: int = 15) -> str:
    """The last lines of the job's LAMMPS log, if it wrote one."""
    logs = sorted(Path(folder).glob("**/log.lammps"), key=lambda p: p.stat().st_mtime)
    return file_tail(logs[-1], lines) if logs else ""


@contextlib.contextmanager
def _stop_on_signals(folder: Path):
    """While in it: SIGUSR1 (SLURM's warning before the time limit) and SIGTERM write a restart and stop; a USR1
    that came before this handler (the folder's :data:`STOP_NOTE`, written by the SLURM array's script) counts too.
    On leaving, the note is gone and the caller's handlers are back (none are replaced off the main thread)."""
    from opalflow.lammps.engine import request_stop

    before = []
    if threading.current_thread() is threading.main_thread():
        before = [(sig, signal.signal(sig, request_stop)) for sig in (signal.SIGUSR1, signal.SIGTERM)]
    try:
        if (folder / STOP_NOTE).exists():
            (folder / STOP_NOTE).unlink()
            request_stop(signal.SIGUSR1, None)
        yield
    finally:
        (folder / STOP_NOTE).unlink(missing_ok=True)       # a USR1 the handler took may have left its note too
        for sig, handler in before:
            signal.signal(sig, handler)


def run_job(folder: str, np_: int = 1, threads: int = 1) -> Outcome:
    """Run the job in ``folder`` (its record says what) and return its :class:`Outcome`: finished, failed
    (the error's first line and the log tail), or requeued (a job stopped by its scheduler's signal writes a
    restart file and is put back in the queue).  It never raises: one failed job must not end a study.

    BLAS and OpenMP run ``threads`` threads in the job (threadpoolctl), whatever the executor's process
    inherited: the same sums in the same order, so a job gives the same numbers to the last digit on a
    local pool, a Dask worker or a SLURM node, and jobs side by side do not oversubscribe the cores."""
    folder = Path(folder).resolve()
    with _stop_on_signals(folder):
        import scipy.linalg  # noqa: F401 - load every BLAS/OpenMP library first: threadpoolctl limits the loaded ones
        import scipy.sparse.linalg  # noqa: F401
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=threads):
            return _run_job(folder, np_)


def _run_job(folder: Path, np_: int) -> Outcome:
    from opalflow.lammps.engine import Preempted

    rec = job_record(folder)
    label = rec.label if rec is not None and rec.label else folder.name
    done = finished_summary(folder)
    if done is not None:
        return Outcome.finished(folder, rec.kind if rec is not None else "", done)

    last = [0.0]

    def say(msg: str) -> None:
        print(f"[{label}] {msg}", file=sys.stderr, flush=True)
        if time.time() - last[0] > 2.0:          # what the job says last, for status (a LAMMPS run's
            last[0] = time.time()                # step counter writes progress.json itself)
            note(folder, msg)

    try:
        if rec is None:
            raise RuntimeError(f"{folder} holds no job (no readable {RECORD}): run its study again")
        rec.state, rec.error, rec.log_tail = "running", "", ""
        rec.attempts, rec.attempted = rec.attempts + 1, time.time()
        rec.write(folder)
        spec = registry.spec_from_dict(rec.spec)
        kind = registry.get(spec.kind)
        # a stopped run goes on from what it left (the kind knows what: restart files, the quasi-static events)
        resume = (bool(rec.deck) and "resume" in kind.options
                  and (not kind.resumable or registry.resolve(kind.resumable)(folder)))
        result = run_kind(kind, spec, folder, np_=np_, resume=resume, say=say)
    except Preempted as exc:
        settle(folder, "requeued")
        requeue_self(say)
        return Outcome("requeued", str(folder), step=exc.step)
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - the job's failure is its result
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        tail = log_tail(folder)
        settle(folder, "failed", error=first, log_tail=tail)
        return Outcome("failed", str(folder), error=first, log_tail=tail)
    settle(folder, "finished", peak_rss_MiB=peak_rss_MiB())
    return Outcome("finished", str(folder), result)


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
    """Summaries of the jobs finished before, and the others, each with its record (state pending; a job
    stopped before keeps its record and where it stood, and goes on from there)."""
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
        rec = job_record(folder)
        if rec is None or rec.spec_hash != job.key:
            rec = RunRecord.job(job.spec, job.label, job.key)
        elif rec.state in ("built", "finished", "failed"):
            rec.state = "pending"
        rec.write(folder)
        todo.append(job)
    return done, todo
