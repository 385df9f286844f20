"""Sweeps: many independent compression jobs, run in parallel, each done once.

A job is a workflow spec.  Its folder is ``<study>/jobs/<label>-<hash>`` where the hash is
the SHA-256 of the spec's canonical JSON: a finished job (``summary.json`` beside a
``job.json`` with the same hash) is never run again, so rerunning a finished sweep does no
LAMMPS work and a killed sweep completes only what is missing (a job killed after a
restart file continues from it).  Jobs go to a local pool of ``workers`` processes (spawn),
each job with ``np`` MPI processes.
"""
from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from opalflow import registry
from opalflow.resources import WORKFLOWS
from opalflow.spec import SpecError, WorkflowSpec
from opalflow.store import write_json_atomic


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
        return root / "jobs" / f"{self.label}-{self.key[:12]}"


def finished(job: Job, root: Path) -> dict | None:
    """The job's summary if it has completed with this very spec, else None."""
    folder = job.folder(root)
    try:
        meta = json.loads((folder / "job.json").read_text())
        if meta["hash"] != job.key:
            return None
        summary = json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError, KeyError, TypeError):   # missing, cut short, binary: run it again
        return None
    return summary if isinstance(summary, dict) else None


def _run_job(args) -> tuple[str, dict]:
    """One job; a job that fails (bad geometry, LAMMPS error) returns {"failed": first line} and stays
    unfinished (its folder is kept for inspection and a rerun tries it again)."""
    spec_dict, folder, np_, label = args
    folder = Path(folder)
    resume = (folder / "run.json").exists() and any(folder.glob("restart.*.bin"))

    def say(msg: str) -> None:
        print(f"[{label}] {msg}", file=sys.stderr, flush=True)

    try:
        spec = registry.spec_from_dict(spec_dict)
        summary = registry.get(spec.kind).run_workflow(spec, folder, np_=np_, resume=resume, say=say)
    except Exception as exc:  # noqa: BLE001 - one failed job must not end the sweep
        return label, {"failed": str(exc).splitlines()[0], "folder": str(folder)}
    return label, summary


def run_jobs(jobs: list[Job], root: Path, *, workers: int = 0, np_: int = 1, say=print) -> dict[str, dict]:
    """Run every unfinished job (``workers`` at once; 0: cores / np) and return label -> summary
    (``{"failed": reason, "folder": ...}`` for a job that failed).

    Finished jobs are read from their folders; ``job.json`` is written before a job starts and
    its ``summary.json`` only when it has finished, so a killed job is never taken as done.
    """
    root = Path(root)
    labels = [j.label for j in jobs]
    if len(set(labels)) != len(labels):
        raise ValueError("job labels must be unique")
    results, todo = {}, []
    for job in jobs:
        done = finished(job, root)
        if done is not None:
            results[job.label] = done
            continue
        folder = job.folder(root)
        folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(folder / "job.json", {"label": job.label, "hash": job.key, "spec": job.spec.to_dict()})
        todo.append((job.spec.to_dict(), str(folder), np_, job.label))
    say(f"{len(jobs)} jobs: {len(results)} finished before, {len(todo)} to run")
    if not todo:
        return {label: results[label] for label in labels}
    workers = max(1, min(workers or max(1, (os.cpu_count() or 1) // np_), len(todo)))
    t0 = time.perf_counter()
    if workers == 1:
        for n, args in enumerate(todo, 1):
            label, summary = _run_job(args)
            results[label] = summary
            _report(say, label, summary, n, len(todo), t0)
    else:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(_run_job, args) for args in todo]
            for n, fut in enumerate(as_completed(futures), 1):
                label, summary = fut.result()
                results[label] = summary
                _report(say, label, summary, n, len(todo), t0)
    return {label: results[label] for label in labels}


def _report(say, label: str, summary: dict, n: int, total: int, t0: float) -> None:
    state = f"FAILED: {summary['failed']}" if "failed" in summary else "done"
    say(f"job {label} {state} ({n}/{total}, {time.perf_counter() - t0:.0f} s)")


# ----------------------------------------------------------------------------- a study's jobs
def job_spec(spec, overrides: list[str]) -> WorkflowSpec:
    """A study's (:class:`opalflow.studies.spec.StudyWorkflow`) base workflow with the study's and the
    job's overrides."""
    st = spec.study
    base = st.paper_base if st.paper_scale else st.base
    path = WORKFLOWS / f"{base}.toml"
    if not path.exists():
        raise SpecError("study.paper_base" if st.paper_scale else "study.base", base,
                        f"no workflow {path.name} in {WORKFLOWS}")
    static = ["compression.method=static", "compression.drop_loose=true"] if st.method == "static" else []
    return registry.load_spec(path, [*static, *st.set, *overrides])


#: label -> reason of the jobs of the running study that failed
FAILED: dict[str, str] = {}


def sweep(spec, out: Path, jobs: list[Job], say) -> dict[str, dict]:
    """Run a study's jobs; failed ones are left out of the result and listed in FAILED (label -> reason)."""
    res = run_jobs(jobs, out, workers=spec.study.workers, np_=spec.study.np, say=say)
    FAILED.update({k: v["failed"] for k, v in res.items() if "failed" in v})
    return {k: v for k, v in res.items() if "failed" not in v}


def fmt_value(value, spec: str) -> str:
    """``value`` formatted, or "-" where a static job has none (strength, strain at peak, broken bonds)."""
    return "-" if value is None else format(value, spec)


def label_number(x: float) -> str:
    """A number as it appears in job labels."""
    return f"{x:.6g}"
