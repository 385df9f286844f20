"""The one switch: workflow ``kind`` -> the track that reads, validates, builds and runs it.

A kind is a :class:`Kind`: its spec class (a :class:`opalflow.spec.WorkflowSpec` subclass
with the sections it reads and their validation), its runner, and what it offers besides
(a deck built alone, an analysis of a run folder, the CLI options it takes).  Runners are
named as ``"module:function"`` and imported only when used, so ``list`` and ``info`` stay
fast and no track is imported by another.

Kinds come from three places, looked up in this order:

1. :func:`register` at run time (a notebook, a test);
2. the built-in tracks below, one line each;
3. installed plugins: packages that declare an entry point in the group ``opalflow.kinds``
   (``toy = "toytrack:KIND"`` in their ``pyproject.toml``) whose object is a :class:`Kind`.

Adding a track is a new package plus one line here (or one entry point in its own package).
"""
from __future__ import annotations

import copy
import importlib
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from opalflow.spec import InputError, SpecError, WorkflowSpec, apply_overrides, convert, read_toml
from opalflow.store import folder_lock

#: CLI options a kind may take, besides --out and --set, and the runner's keyword for each
OPTIONS = {"np": "np_", "suffix": "suffix", "resume": "resume", "executor": "executor"}

#: a workflow file without ``kind`` is an opal
DEFAULT_KIND = "opal"

ENTRY_POINT_GROUP = "opalflow.kinds"


def resolve(target: str) -> Any:
    """The object named ``"module:attribute"``."""
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class Kind:
    """A workflow kind.

    Parameters
    ----------
    name : the ``kind`` value of workflow files.
    spec : ``"module:Class"`` of its workflow spec (a dataclass subclass of WorkflowSpec with a
        ``validate`` method); the module must be light (dataclasses and checks only).
    run : ``"module:function"`` called as ``run(spec, out, say=..., **options)`` -> the run's result, an
        instance of ``result`` (summary.json, with ``headline`` and ``wall_s``, read back by
        :func:`opalflow.runs.record.finish`), where options are the keywords of :data:`OPTIONS` that the kind takes.
    build : ``"module:function"`` called as ``build(spec, out, say=...)``: writes everything ``run`` writes before
        it runs, summary.json with ``state = "built"`` (``python -m opalflow build``); "" if none.
    analyze : ``"module:function"`` called as ``analyze(folder)`` -> its result (as ``run``): the results of
        a run folder whose deck ran outside opalflow (``python -m opalflow analyze``); "" if none.
    check : ``"module:function"`` called as ``check(spec, out, say=..., steps=..., timestep_factor=...,
        bisect=...)`` -> its :class:`opalflow.bpm.stability.StabilityCheck`: a short run judged for numerical stability
        (``python -m opalflow check``); "" if none.
    scene : ``"module:attribute"`` of the :class:`opalflow.bpm.scene.Scene` that the compression
        pipeline builds the structure with; "" for kinds that are not bonded-particle scenes.
    cost : ``"module:function"`` called as ``cost(spec)`` -> :class:`opalflow.runs.plan.CostFacts` (method,
        particles, bonds, steps, ...): what ``python -m opalflow plan`` prices a run by; "" if it has none.
    jobs : ``"module:function"`` called as ``jobs(spec)`` -> the :class:`opalflow.runs.jobs.Job` list a kind that
        runs many jobs would run (``python -m opalflow plan`` prices each); "" for a kind that is one run.
    options : the names in :data:`OPTIONS` it takes.
    resumable : ``"module:function"`` called as ``resumable(folder)`` -> bool: whether ``--resume`` has something
        to go on from in the folder (a restart file); "" where a written run record is enough.
    result : ``"module:Class"`` of its :class:`opalflow.runs.result.Result` subclass: what its summary.json reads
        back as (a finished job's :attr:`opalflow.runs.jobs.Outcome.result`); "" for the generic class (every key
        in ``extra``).
    refusal : why it does not take the others (said when one is given).
    summary : one line for ``list`` and ``info``.
    """

    name: str
    spec: str
    run: str
    build: str = ""
    analyze: str = ""
    check: str = ""
    scene: str = ""
    cost: str = ""
    jobs: str = ""
    options: tuple[str, ...] = ()
    resumable: str = ""
    result: str = ""
    refusal: str = ""
    summary: str = ""

    def spec_class(self) -> type[WorkflowSpec]:
        return resolve(self.spec)

    def result_class(self) -> type:
        """Its result class (:class:`opalflow.runs.result.Result` where it names none)."""
        return resolve(self.result or "opalflow.runs.result:Result")

    def run_workflow(self, spec: WorkflowSpec, out: Path, *, say=print, np_: int = 1, resume: bool = False,
                     suffix: str | None = None, executor=None):
        """Run ``spec`` into ``out`` -> its result (an instance of :meth:`result_class`); options the kind does not
        take must be at their defaults (``executor``: an :class:`opalflow.runs.spec.ExecutorSpec` for kinds that run
        many jobs).  The registry names the run layer's classes, it does not import them."""
        given = {"np": np_ != 1, "resume": resume, "suffix": suffix is not None, "executor": executor is not None}
        if any(on and o not in self.options for o, on in given.items()):
            raise SpecError("/".join(f"--{o}" for o in OPTIONS if o != "executor"), self.name,
                            self.refusal or f"it takes only {', '.join(self.options) or 'none of them'}")
        values = {"np": np_, "resume": resume, "suffix": suffix, "executor": executor}
        with folder_lock(out):
            return resolve(self.run)(spec, out, say=say, **{OPTIONS[o]: values[o] for o in self.options})

    def build_workflow(self, spec: WorkflowSpec, out: Path, *, say=print) -> None:
        if not self.build:
            raise SpecError("kind", self.name, "has no deck of its own to build (it runs several or none): use 'run'")
        with folder_lock(out):
            resolve(self.build)(spec, out, say=say)

    def check_workflow(self, spec: WorkflowSpec, out: Path, *, say=print, **options):
        """The kind's stability check of ``spec`` in ``out`` (its ``check``: a bonded-particle scene's
        :class:`opalflow.bpm.stability.StabilityCheck`)."""
        if not self.check:
            raise SpecError("kind", self.name, "has no stability check (bonded-particle scenes have one)")
        with folder_lock(out):
            return resolve(self.check)(spec, out, say=say, **options)

    def analyze_folder(self, folder: Path):
        """The results of a run folder whose deck ran outside opalflow -> its result (as :meth:`run_workflow`)."""
        if not self.analyze:
            raise SpecError("folder", str(folder), f"a {self.name} run has no analysis of its own: its run "
                            "writes the results")
        with folder_lock(folder, "folder"):
            return resolve(self.analyze)(folder)


def _compression(name: str, spec: str, scene: str, summary: str,
                 result: str = "opalflow.bpm.result:CompressionResult") -> Kind:
    """A bonded-particle scene compressed by a plate: the pipeline of :mod:`opalflow.bpm`; ``result``: its
    track's subclass of :class:`opalflow.bpm.result.CompressionResult` where it has one."""
    return Kind(name, spec, run="opalflow.bpm.run:run_workflow", build="opalflow.bpm.pipeline:build",
                analyze="opalflow.bpm.dynamic_run:analyze_folder",
                check="opalflow.bpm.stability:stability_check", scene=scene, cost="opalflow.bpm.run:cost_facts",
                options=("np", "resume", "suffix"), resumable="opalflow.bpm.run:resumable",
                result=result, summary=summary)


_TERSOFF_REFUSAL = ("atomistic workflows run in-process and take seconds; stability.workers sets how many "
                    "MD runs go at once")

_TERSOFF_RESULT = "opalflow.tersoff.result:TersoffResult"

_POLYCRYSTAL_REFUSAL = "the samples run batched in-process (JAX); --resume skips finished runs"

BUILTIN = {k.name: k for k in (
    _compression("opal", "opalflow.opal.spec:OpalWorkflow", "opalflow.opal.scene:SCENE",
                 "inverse opal (packing, pores, coating, substrate) compressed by a plate",
                 "opalflow.opal.result:OpalResult"),
    _compression("lattice", "opalflow.lattice.spec:LatticeWorkflow", "opalflow.lattice.scene:SCENE",
                 "regular lattice of bonded spheres compressed by a plate (analytic checks)"),
    _compression("datafile", "opalflow.datafile.spec:DatafileWorkflow", "opalflow.datafile.scene:SCENE",
                 "your own bpm/sphere data file compressed by a plate"),
    _compression("aerogel", "opalflow.aerogel.spec:AerogelWorkflow", "opalflow.aerogel.scene:SCENE",
                 "silica aerogel: a DLCA/RLCA aggregate bonded at its contacts, compressed between walls",
                 "opalflow.aerogel.result:AerogelResult"),
    Kind("aggregation", "opalflow.aerogel.spec:AggregationWorkflow", "opalflow.aerogel.run:run_aggregation",
         refusal="an aggregation runs in-process (numba); aggregate.particles sets its size",
         summary="DLCA/RLCA aggregate in a periodic cube: fractal dimension two ways, pictures, data file"),
    Kind("tersoff_properties", "opalflow.tersoff.spec:TersoffWorkflow", "opalflow.tersoff.workflow:run_properties",
         options=("suffix",), result=_TERSOFF_RESULT, refusal=_TERSOFF_REFUSAL, summary="lattice constant, cohesive energy, elastic constants of a .tersoff file"),
    Kind("tersoff_fit", "opalflow.tersoff.spec:TersoffWorkflow", "opalflow.tersoff.workflow:run_fit",
         result=_TERSOFF_RESULT, refusal=_TERSOFF_REFUSAL, summary="fit of a Tersoff set to target properties (loss eq. 13)"),
    Kind("tersoff_stability", "opalflow.tersoff.spec:TersoffWorkflow", "opalflow.tersoff.workflow:run_stability",
         options=("suffix",), result=_TERSOFF_RESULT, refusal=_TERSOFF_REFUSAL, summary="MD stability of a Tersoff set under four boundary conditions"),
    Kind("polycrystal_tension", "opalflow.tersoff.polycrystal.spec:TensionWorkflow",
         "opalflow.tersoff.polycrystal.run:run_tension", options=("resume",), refusal=_POLYCRYSTAL_REFUSAL,
         result="opalflow.tersoff.polycrystal.result:TensionResult",
         summary="polycrystal of tetrahedral elements with 64-atom Tersoff samples: tension -> E, Poisson ratio"),
    Kind("polycrystal_waves", "opalflow.tersoff.polycrystal.spec:WavesWorkflow",
         "opalflow.tersoff.polycrystal.run:run_waves", options=("resume",), refusal=_POLYCRYSTAL_REFUSAL,
         result="opalflow.tersoff.polycrystal.result:WavesResult",
         summary="polycrystal of tetrahedral elements: plate, rod and shear wave speeds"),
    Kind("granular", "opalflow.granular.spec:GranularWorkflow", "opalflow.granular.run:run_granular",
         options=("suffix",), result="opalflow.granular.result:GranularResult",
         refusal="a contact-only scene runs in-process (LAMMPS) or as one liggghts process",
         summary="unbonded packing compressed by a plate on LAMMPS, LIGGGHTS or both (cross-check)"),
    Kind("granular_impacts", "opalflow.granular.spec:ImpactsWorkflow", "opalflow.granular.impacts:run_impacts",
         result="opalflow.granular.result:ImpactsResult",
         refusal="each impact is two spheres: one LAMMPS and one liggghts process per case",
         summary="single impacts on LAMMPS and LIGGGHTS: where the contact laws agree and part"),
    Kind("stability_matrix", "opalflow.bpm.spec:StabilityMatrixWorkflow", "opalflow.bpm.matrix:run_matrix",
         refusal="each row is a short in-process run; matrix.steps sets its length",
         summary="the stability check with bisection over corner cases of bonded-particle scenes"),
    Kind("study", "opalflow.studies.spec:StudyWorkflow", "opalflow.studies.run:run", jobs="opalflow.studies.run:jobs",
         options=("executor",),
         refusal="a study sets study.np and [executor] (where its jobs run); rerunning it resumes it (finished "
                 "jobs are kept)",
         summary="many compression jobs from one base workflow: the paper's studies"),
)}

_REGISTERED: dict[str, Kind] = {}


def register(kind: Kind) -> Kind:
    """Make ``kind`` available to this process (replaces a kind of the same name)."""
    _REGISTERED[kind.name] = kind
    return kind


def _plugins() -> dict[str, metadata.EntryPoint]:
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def kinds() -> dict[str, Kind]:
    """Every kind known to this process: registered, built-in and installed plugins."""
    found = {name: ep.load() for name, ep in _plugins().items()}
    return {**found, **BUILTIN, **_REGISTERED}


def get(name: str) -> Kind:
    """The kind of that name; SpecError listing the known ones if there is none."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in BUILTIN:
        return BUILTIN[name]
    plugin = _plugins().get(name)
    if plugin is not None:
        return plugin.load()
    raise SpecError("kind", name, f"must be one of {', '.join(kinds())}")


# ----------------------------------------------------------------------------- specs
def spec_from_dict(raw: dict, base: dict | None = None) -> WorkflowSpec:
    """The validated spec of a raw workflow table (kind picks the class).

    Every section and top-level key is checked against the kind's spec before anything runs: a key that no
    kind reads is refused by its section, and a section that only other kinds read is refused naming them;
    ``[executor]`` (where the run goes, any kind's: :mod:`opalflow.runs.spec`, checked by
    :func:`opalflow.api.load_workflow`) is left out.
    ``base`` (the workflow file's table before ``--set``): where ``--set kind=...`` switched the file to
    another kind, the file's own sections that the new kind does not read are left out.
    """
    name = raw.get("kind", DEFAULT_KIND)
    if not isinstance(name, str):
        raise SpecError("kind", name, "must be a string")
    cls = get(name).spec_class()
    own = set(cls.__dataclass_fields__)
    readers: dict[str, list[str]] = {}
    for other, kind in kinds().items():
        for f in kind.spec_class().__dataclass_fields__:
            readers.setdefault(f, []).append(other)
    switched = base is not None and base.get("kind", DEFAULT_KIND) != name
    kept = {}
    for key, value in raw.items():
        if key == "executor" and key not in own:        # the run layer's, of any workflow (checked by the API)
            continue
        if key in own or key not in readers:            # (a key no kind reads: convert refuses it)
            kept[key] = value
        elif not (switched and key in base and base[key] == value):
            what = f"[{key}]" if isinstance(value, dict) else f"'{key}'"
            raise InputError(f"{what}: kind {name!r} does not read it (read by: {', '.join(readers[key])}); remove "
                             f"it, or set kind to one of those")
    spec = convert(cls, kept)
    spec.validate()
    return spec


def load_spec(path: str | Path, overrides: list[str] | None = None) -> WorkflowSpec:
    """Read, override and validate a workflow file."""
    base = read_toml(path)
    raw = copy.deepcopy(base)
    apply_overrides(raw, overrides or [])
    return spec_from_dict(raw, base)
