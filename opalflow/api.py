"""The Python API: one function per CLI verb (the CLI parses its arguments and calls these).

>>> import opalflow
>>> result = opalflow.run("lattice_sc", "runs/sc", set={"compression.strain_max": 0.002})
>>> result.youngs_modulus_GPa                   # (also result["youngs_modulus_GPa"]: summary.json's table)
>>> res = opalflow.load_results("runs/sc")
>>> res["curve/stress_MPa"], res.units("curve/stress_MPa")

``run``, ``build``, ``analyze`` give the run's result: its kind's :class:`opalflow.runs.result.Result` class
(:class:`opalflow.bpm.result.CompressionResult` for a compression), typed, and a read-only mapping of its
summary.json; ``check`` gives its :class:`opalflow.bpm.stability.StabilityCheck`, ``info`` an :class:`Info`.

A workflow is a file path, the name of a file in ``workflows/`` (``opalflow.workflows()`` lists them), a
workflow table as a dict (the TOML's content), or a spec already made.  ``set`` overrides fields: a dict
``{"section.key": value}`` (Python values), or one ``"section.key=value"`` string or a list of them (TOML values, as
``--set``).  Bad input raises :class:`opalflow.spec.InputError` (one line: field, value, what is allowed)
before anything is written; a failed LAMMPS run raises :class:`opalflow.lammps.engine.EngineError` with
its log tail and keeps the folder; Ctrl-C raises :class:`opalflow.lammps.engine.Interrupted` (a
KeyboardInterrupt with the step reached) and leaves the folder resumable.
"""
from __future__ import annotations

import copy
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from opalflow import registry
from opalflow.resources import WORKFLOWS
from opalflow.runs.result import Result
from opalflow.runs.spec import executor_from_raw
from opalflow.spec import SpecError, WorkflowSpec, apply_overrides, read_toml, set_value
from opalflow.store import usable_folder

if TYPE_CHECKING:
    from opalflow.lammps.engine import LammpsInfo

Settings = dict[str, Any] | list[str] | str | None


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _say(quiet: bool) -> Callable[[str], None]:
    return (lambda msg: None) if quiet else _stderr


def workflow_path(name: str | Path) -> Path:
    """A workflow file: a path, or the name of a file in workflows/ (with or without .toml)."""
    p = Path(name)
    if p.exists():
        return p
    for cand in (WORKFLOWS / str(name), WORKFLOWS / f"{name}.toml"):
        if cand.exists():
            return cand
    raise SpecError("workflow", str(name), f"no such file, nor a workflow in {WORKFLOWS} "
                    "(opalflow.workflows() or python -m opalflow list shows them)")


def raw_workflow(workflow: str | Path | dict | WorkflowSpec, set: Settings = None) -> dict:
    """The raw table of ``workflow`` (a copy) with the ``set`` overrides applied, not yet validated."""
    if isinstance(workflow, WorkflowSpec):
        raw = workflow.to_dict()
    elif isinstance(workflow, dict):
        raw = copy.deepcopy(workflow)
    else:
        path = workflow_path(workflow)
        raw = read_toml(path)
        if not any(isinstance(v, dict) for v in raw.values()):
            # else every default holds: for an opal, the paper's full sample (1.6 M particles, days of LAMMPS)
            raise SpecError("workflow", str(path), "has no [section]: a workflow file says what it builds "
                            "([packing], [lattice], [study], ...); start from one in workflows/ (python -m opalflow "
                            "list)")
    if isinstance(set, dict):
        for path, value in set.items():
            set_value(raw, str(path), value)
    elif isinstance(set, str):                  # one "section.key=value" (not a list of its characters)
        apply_overrides(raw, [set])
    elif isinstance(set, (list, tuple)) and all(isinstance(x, str) for x in set):
        apply_overrides(raw, list(set))
    elif set is not None:
        raise SpecError("set", repr(set)[:80], "must be a dict {'section.key': value}, a 'section.key=value' "
                        "string or a list of them")
    return raw


def load_workflow(workflow: str | Path | dict | WorkflowSpec, set: Settings = None) -> WorkflowSpec:
    """The validated spec of ``workflow`` with the ``set`` overrides applied."""
    raw = raw_workflow(workflow, set)
    executor_from_raw(dict(raw))                # (every kind's [executor], checked for a single run too)
    return registry.spec_from_dict(raw, raw_workflow(workflow) if set else None)


def run(workflow: str | Path | dict | WorkflowSpec | None, out: str | Path, *, set: Settings = None, np: int = 1,
        resume: bool = False, suffix: str | None = None, executor: str | None = None, quiet: bool = False
        ) -> Result:
    """Build, run and analyze ``workflow`` into the folder ``out``; returns its result (summary.json as its kind's
    result class).

    ``np``: MPI processes (runs ``lmp`` under mpiexec); ``resume``: continue the run in ``out`` from its
    newest restart file (``workflow`` None: the spec comes from ``out/run.json``); ``suffix``: accelerator
    styles ('omp', 'kk', 'gpu') where the LAMMPS build has them; ``executor``: 'local', 'dask' or 'slurm'
    (else the workflow's ``[executor]``): a study sends its jobs there, any other workflow goes there as one
    job; ``quiet``: no progress lines on stderr.
    """
    out = usable_folder(out, "out")
    if resume:
        spec = resumed_spec(out, workflow, set)
    elif workflow is None:
        raise SpecError("workflow", None, "give a workflow file or name (or resume with an out folder)")
    else:
        spec = load_workflow(workflow, set)
    if isinstance(np, bool) or not isinstance(np, int) or np < 1:
        raise SpecError("--np", np, "must be an integer >= 1")
    if suffix:
        from opalflow.lammps.engine import lammps_info

        usable = lammps_info().accelerators
        if suffix not in usable:
            raise SpecError("--suffix", suffix, f"this LAMMPS build offers {', '.join(usable) or 'none'}")
    from opalflow.runs.record import refuse_finished, run_kind

    kind = registry.get(spec.kind)
    if not resume and "executor" not in kind.options:      # (a study run again goes on: its finished jobs kept)
        refuse_finished(out)
    ex = executor_of(None if resume and workflow is None else workflow, set, executor)
    if "executor" in kind.options:              # a kind of many jobs sends them there
        return run_kind(kind, spec, out, np_=np, resume=resume, say=_say(quiet), suffix=suffix,
                        executor=ex if executor is not None else None)
    if ex.type != "local":                      # any other run goes there as one job
        if suffix:
            raise SpecError("--suffix", suffix, "is for runs on this machine (a submitted run uses the launcher)")
        return submit(spec, out, ex, np_=np, say=_say(quiet))
    return run_kind(kind, spec, out, np_=np, resume=resume, say=_say(quiet), suffix=suffix)


def resumed_spec(out: Path, workflow=None, set: Settings = None) -> WorkflowSpec:
    """The spec a ``--resume`` of ``out`` goes on with: the one its run.json stores (the truth).  A workflow or
    ``set`` given beside it must give the same spec, else one line names the first difference; a finished run
    is not resumed (one line)."""
    from opalflow.runs.record import RunRecord
    from opalflow.runs.result import is_finished

    record = RunRecord.read(out, "--resume")
    stored = registry.spec_from_dict(record.spec)
    if workflow is not None or set:
        given = load_workflow(stored if workflow is None else workflow, set).to_dict()
        where = first_difference(record.spec, given)
        if where is not None:
            path, was, now = (where[0], *(repr(v) if len(repr(v)) <= 60 else repr(v)[:57] + "..." for v in where[1:]))
            raise SpecError("--resume", str(out), f"its run has {path} = {was}, this command gives {now}; a "
                            "resume goes on with the spec it started with: drop the workflow and --set, or run "
                            "the new spec into another folder")
    if record.state == "finished" or is_finished(out):
        raise SpecError("--resume", str(out), "holds a finished run: nothing to resume (status shows it; run "
                        "into another folder to run it again)")
    return stored


def first_difference(a, b, path: str = ""):
    """(dotted path, value in ``a``, value in ``b``) of the first place two spec tables differ, None if equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        # kind and name first, then a table's own values, then its sub-tables: the difference a user recognises
        def order(k):
            return (k not in ("kind", "name"), isinstance(a.get(k), dict) or isinstance(b.get(k), dict), k)

        for key in sorted(set(a) | set(b), key=order):
            where = first_difference(a.get(key), b.get(key), f"{path}.{key}" if path else key)
            if where is not None:
                return where
        return None
    return None if a == b else (path, a, b)


def executor_of(workflow, set: Settings = None, override: str | None = None):
    """The ``[executor]`` of a workflow (with the ``set`` overrides; ``override``: its type, as
    ``--executor``); a resumed run without a workflow has only the override."""
    return executor_from_raw({} if workflow is None else raw_workflow(workflow, set), override)


def submit(spec: WorkflowSpec, out: str | Path, ex, *, np_: int = 1, say=_stderr) -> Result:
    """One run as a job of the executor ``ex`` (Dask, SLURM): the folder ``out`` is its job folder
    (resumed from its restart file where it has one); returns its result, or raises EngineError with
    its log tail when it failed."""
    from opalflow.lammps.engine import EngineError
    from opalflow.runs.executors import executor
    from opalflow.runs.jobs import job_record, spec_hash
    from opalflow.runs.record import RunRecord

    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    rec = job_record(out)
    if rec is None or rec.spec_hash != spec_hash(spec):
        RunRecord.job(spec, spec.name, spec_hash(spec)).write(out)
    (_, got), = list(executor(ex, np_).run([str(out)], say))
    if not got.ok:
        raise EngineError(f"{got.error or got.state}\n--- log tail ---\n{got.log_tail}")
    return got.result


def build(workflow: str | Path | dict | WorkflowSpec, out: str | Path, *, set: Settings = None,
          quiet: bool = False) -> Result:
    """Everything a run writes before it runs (structure, data.lmp, in.lmp, run.sh, summary.json); no run.  Its
    result holds what is known before the run (the structure's statistics; ``state`` "built")."""
    from opalflow.runs.result import read_summary

    spec = load_workflow(workflow, set)
    out = usable_folder(out, "out")
    kind = registry.get(spec.kind)
    kind.build_workflow(spec, out, say=_say(quiet))
    return kind.result_class().from_summary(read_summary(out))


def check(workflow: str | Path | dict | WorkflowSpec, out: str | Path, *, set: Settings = None, steps: int = 3000,
          timestep_factor: float = 1.0, strain: float | None = None, bisect: bool = False,
          quiet: bool = False):
    """A short run of the scene's real deck judged for numerical stability: the kind's check (a bonded-particle
    scene's :class:`opalflow.bpm.stability.StabilityCheck`: ``.passed``, ``.headline``; stability.json)."""
    if steps < 100:
        raise SpecError("--steps", steps, "must be >= 100")
    if not 0 < timestep_factor <= 100:
        raise SpecError("--timestep-factor", timestep_factor, "must be in (0, 100]")
    if strain is not None and not 0 < strain <= 0.9:
        raise SpecError("--strain", strain, "must be in (0, 0.9] (compress the sample this far)")
    spec = load_workflow(workflow, set)
    return registry.get(spec.kind).check_workflow(spec, usable_folder(out, "out"), say=_say(quiet), steps=steps,
                                                  timestep_factor=timestep_factor, bisect=bisect, strain=strain)


def analyze(folder: str | Path) -> Result:
    """The results of a run folder whose deck ran outside opalflow (``bash run.sh``): writes and returns them."""
    from opalflow.runs.record import RunRecord

    folder = Path(folder)
    kind = RunRecord.read(folder).kind or registry.DEFAULT_KIND
    return registry.get(kind).analyze_folder(folder)


@dataclass
class Workflow:
    """A workflow file of ``workflows/``: its name (the file's stem), kind, description and path."""

    name: str
    kind: str
    description: str
    path: str


def workflows() -> list[Workflow]:
    """The workflows in workflows/, by name."""
    out = []
    for path in sorted(WORKFLOWS.glob("*.toml")):
        raw = tomllib.loads(path.read_text())
        out.append(Workflow(path.stem, raw.get("kind", registry.DEFAULT_KIND), raw.get("description", ""), str(path)))
    return out


@dataclass
class Info:
    """What ``python -m opalflow info`` shows: opalflow's version, the LAMMPS library's facts (version, packages,
    accelerators, the executables found: lmp, mpiexec, liggghts) and the workflow kinds ({name: what it does})."""

    opalflow_version: str
    lammps: LammpsInfo
    kinds: dict[str, str]


def info() -> Info:
    """This installation's :class:`Info`."""
    from opalflow.lammps.engine import lammps_info
    from opalflow.version import __version__

    return Info(__version__, lammps_info(), {k.name: k.summary for k in registry.kinds().values()})
