"""A study's jobs: the base workflow with each job's overrides, run through the run layer
(:mod:`opalflow.runs.jobs`: one folder per spec hash, each job done once; :mod:`opalflow.runs.executors`:
a local pool, Dask or SLURM job arrays, as the workflow's ``[executor]`` says).  A job that fails keeps
its failure in its own folder (its run.json: the error and the log tail); the study lists those of its
jobs."""
from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

from opalflow import registry
from opalflow.bpm.methods import METHODS
from opalflow.bpm.result import CompressionResult
from opalflow.resources import WORKFLOWS
from opalflow.runs.executors import run_jobs
from opalflow.runs.jobs import Job, job_record
from opalflow.spec import SpecError, WorkflowSpec, apply_overrides, read_toml, set_value
from opalflow.store import RECORD

__all__ = ["Job", "FailedJob", "job_spec", "study_set", "sweep", "failed_jobs", "fmt_value", "label_number"]


# ----------------------------------------------------------------------------- a study's jobs
def job_spec(spec, values: dict | None = None) -> WorkflowSpec:
    """A study's (:class:`opalflow.studies.spec.StudyWorkflow`) base workflow with the study's overrides
    (``study.set``, or at paper scale ``study.paper_base`` and ``study.paper_set``: the user's ``--set`` text) and
    the job's ``values`` ({"section.key": a Python value}, set as they are: no text is parsed)."""
    st = spec.study
    base = st.paper_base if st.paper_scale else st.base
    path = WORKFLOWS / f"{base}.toml"
    if not path.exists():
        raise SpecError("study.paper_base" if st.paper_scale else "study.base", base,
                        f"no workflow {path.name} in {WORKFLOWS}")
    raw = read_toml(path)
    job = copy.deepcopy(raw)
    if METHODS[st.method].linear:         # the study's method first: study.set may still change it
        set_value(job, "compression.method", st.method)
        set_value(job, "compression.drop_loose", True)
    apply_overrides(job, study_set(st))
    for key, value in (values or {}).items():
        set_value(job, key, value)
    return registry.spec_from_dict(job, raw)


def study_set(st) -> list[str]:
    """The overrides every job of study section ``st`` gets: ``set``, or ``paper_set`` at paper scale."""
    return st.paper_set if st.paper_scale else st.set


def sweep(spec, out: Path, jobs: list[Job], say) -> dict[str, CompressionResult]:
    """Run a study's jobs through its executor (``spec.executor``): label -> the result of each finished job (its
    kind's class: :class:`opalflow.bpm.result.CompressionResult` or a track's subclass); the failed ones are left
    out (their folders say why: :func:`failed_jobs`)."""
    res = run_jobs(jobs, out, spec.executor, np_=spec.study.np, say=say)
    return {k: v.result for k, v in res.items() if v.ok}


@dataclass
class FailedJob:
    """A study job that failed: its label, the error's first line, the LAMMPS log's tail and its folder."""

    label: str
    error: str
    log_tail: str
    folder: str


def failed_jobs(out: Path, since: float) -> list[FailedJob]:
    """The study's jobs that failed in a run started at ``since`` (time.time()), read from each job's folder."""
    failed = []
    for path in sorted(Path(out).glob(f"jobs/*/{RECORD}")):
        rec = job_record(path.parent)
        if rec is not None and rec.state == "failed" and (rec.attempted or 0) >= since:
            failed.append(FailedJob(rec.label or path.parent.name, rec.error, rec.log_tail, str(path.parent)))
    return failed


def fmt_value(value, spec: str) -> str:
    """``value`` formatted, or "-" where a static job has none (strength, strain at peak, broken bonds)."""
    return "-" if value is None else format(value, spec)


def label_number(x: float) -> str:
    """A number as it appears in job labels."""
    return f"{x:.6g}"
