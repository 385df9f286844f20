"""The bonded-particle methods side by side: ``compression.method`` -> its runner module, each with the same three
functions: ``run(spec, out, say=..., **options)`` -> its :class:`opalflow.bpm.result.CompressionResult` (summary.json
read back), ``price(spec, structure)`` -> the :class:`opalflow.runs.plan.CostFacts` that :mod:`opalflow.runs.plan`
prices a run by, and (where the method can go on) ``resumable(folder)`` -> bool.

Every runner starts from the shared sample side (:func:`opalflow.bpm.pipeline.prepare` or the network built from
it) and writes its results through :func:`opalflow.runs.record.finish`.  This module is what the compression
kinds of :mod:`opalflow.registry` name (``run_workflow``, ``cost_facts``, ``resumable``).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from opalflow.bpm import dynamic_run, quasistatic_run, static_run
from opalflow.bpm.methods import METHODS
from opalflow.bpm.result import CompressionResult
from opalflow.bpm.scene import scene_of
from opalflow.bpm.spec import BpmWorkflow
from opalflow.runs.plan import CostFacts
from opalflow.runs.record import RunRecord
from opalflow.spec import SpecError


@dataclass(frozen=True)
class Runner:
    """How a method runs (``run``), what a run of it costs (``price``) and whether a folder has something to go
    on from (``resumable``; None: the method does not resume)."""

    run: Callable[..., CompressionResult]
    price: Callable[..., CostFacts]
    resumable: Callable[[Path], bool] | None = None


#: ``compression.method`` -> its runner (a method of :data:`opalflow.bpm.methods.METHODS`)
RUNNERS: dict[str, Runner] = {
    "dynamic": Runner(dynamic_run.run_dynamic, dynamic_run.price, dynamic_run.has_restart),
    "static": Runner(static_run.run_static, static_run.price),
    "quasistatic": Runner(quasistatic_run.run_quasistatic, quasistatic_run.price, quasistatic_run.has_state),
}


def run_workflow(spec: BpmWorkflow, out: Path, *, np_: int = 1, resume: bool = False, say=print,
                 suffix: str | None = None) -> CompressionResult:
    """The run of a bonded-particle workflow by its ``compression.method``; options the method does not take must
    be at their defaults (one line naming the method where one is given)."""
    method = METHODS[spec.compression.method]
    given = {"np_": np_ != 1, "resume": resume, "suffix": suffix is not None}
    if any(on and o not in method.options for o, on in given.items()):
        raise SpecError("compression.method", method.name, method.refusal)
    values = {"np_": np_, "resume": resume, "suffix": suffix}
    return RUNNERS[method.name].run(spec, out, say=say, **{o: values[o] for o in method.options})


def cost_facts(spec: BpmWorkflow) -> CostFacts:
    """What :mod:`opalflow.runs.plan` prices a run by: its method and what the method adds (a dynamic run's
    steps, a solve's solver), particles, bonds, and the seconds the structure took to build here.  Writes
    nothing."""
    method = spec.compression.method
    t = time.perf_counter()
    s = scene_of(spec).structure(spec)
    return dataclasses.replace(RUNNERS[method].price(spec, s), build_s=time.perf_counter() - t)


def resumable(out: Path) -> bool:
    """Whether ``--resume`` can go on in ``out``: what the method of its run resumes from (a restart file, the
    quasi-static state)."""
    runner = RUNNERS[RunRecord.read(out).spec["compression"].get("method", "dynamic")]
    return runner.resumable is not None and runner.resumable(out)
