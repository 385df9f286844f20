"""Spec of the studies (kind = "study"): the ``[study]`` section."""
from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields

from opalflow.bpm.methods import METHODS
from opalflow.runs.spec import ExecutorSpec
from opalflow.spec import WorkflowSpec, check, check_name
from opalflow.vocabulary import LOOP_MODELS


@dataclass(frozen=True)
class StudyType:
    """A study type: its steps, named ``"module:function"`` and imported when a study runs (this module stays light:
    every workflow file's spec is read through it), and the ``[study]`` fields it reads beside :data:`COMMON`.

    ``jobs(spec)`` -> the :class:`opalflow.runs.jobs.Job` list it runs (what ``python -m opalflow plan`` prices; an
    iteration's first round where later ones depend on the results); ``analyse(spec, jobs, results)`` -> its result
    dataclass (None where too few jobs finished); ``render(spec, result, out)`` -> report.md's lines (and the
    figures they show, drawn into ``out``); ``iterate(spec, out, say)`` in place of jobs and analyse for a study
    whose jobs depend on earlier results (the Newton calibration).
    """

    name: str
    jobs: str
    analyse: str
    render: str
    fields: tuple[str, ...] = ()
    summary: str = ""
    iterate: str = ""


def _type(name: str, module: str, fields: tuple[str, ...], summary: str, *, iterate: bool = False) -> StudyType:
    """The study type ``name`` whose steps are ``NAME_jobs``, ``NAME_analyse`` (or ``NAME`` iterating) and
    ``NAME_render`` of ``module``."""
    return StudyType(name, f"{module}:{name}_jobs", "" if iterate else f"{module}:{name}_analyse",
                     f"{module}:{name}_render", fields, summary, f"{module}:{name}" if iterate else "")


#: the fields every study reads
COMMON = ("type", "base", "paper_base", "paper_scale", "set", "paper_set", "np", "method")
_RUN, _AEROGEL = "opalflow.studies.run", "opalflow.studies.aerogel"
STUDY_TYPES = {t.name: t for t in (
    _type("calibration", _RUN, ("target_E_GPa", "target_strength_MPa", "tolerance", "max_runs", "jacobian", "fd_step",
                                "start_E_GPa", "start_strength_MPa"),
          "Newton iteration on bond E_b and strength to E* and sigma* (eqs. 18-19)", iterate=True),
    _type("bulk", _RUN, ("diameters_nm",), "K_E = E_macro / E_b (eq. 20) of pore-free samples at each diameter"),
    _type("coating", _RUN, ("thicknesses_nm",), "titania coatings at E_exp -+ std (Fig. 9)"),
    _type("porosity", _RUN, ("porosities", "seeds", "diameter_nm"),
          "random pores: fits of eqs. 22, 23, 26 with 95 % intervals"),
    _type("convergence", _RUN, ("cells", "diameters_nm", "seeds"),
          "cross-section and diameter x seeds: the resolution's effect"),
    _type("sides", _RUN, (), "periodic against open sides (section 3.1.3)"),
    _type("aerogel_models", _AEROGEL, ("seeds",),
          "bond model x contact law of the aerogel, with a static solve and a rate check"),
    _type("aerogel_density", _AEROGEL, ("solid_fractions", "loop_models", "seeds"),
          "E and strength against density: the scaling exponents"),
)}
STUDIES = tuple(STUDY_TYPES)


@dataclass
class StudySpec:
    """A study (kind = "study"): many compression jobs made from one base workflow (Dosta et al.)."""

    #: which study: calibration, bulk, coating, porosity, convergence, sides, aerogel_models, aerogel_density
    type: str = "calibration"
    base: str = "quickstart"     # the workflow every job is made from (a name in workflows/ or a path)
    paper_base: str = "opal_fcc"  # the base taken instead when paper_scale is true
    paper_scale: bool = False    # true: the jobs at the paper's resolution (paper_base), hours to days
    set: list[str] = field(default_factory=list)  # "section.key=value" overrides applied to every job's base
    #: at paper scale, the overrides applied instead of ``set`` (whose coarse diameter, tile and cells would
    #: undo the paper's sample): the run's settings alone, e.g. the strain to reach
    paper_set: list[str] = field(default_factory=list)
    np: int = 1                  # MPI ranks per job (the [executor] section says where the jobs run)
    #: dynamic: LAMMPS; static: moduli by one linear solve per job (no strength; not calibration);
    #: quasistatic: E and strength at zero rate by the event-driven fracture method
    method: str = "dynamic"
    # calibration (eqs. 18-19)
    target_E_GPa: float = 1.7    # calibration: the opal's E* (the experiment's, Dosta et al. 3.1.2)
    target_strength_MPa: float = 41.3  # calibration: the opal's strength sigma*
    tolerance: float = 0.005     # calibration: stop when E and strength are both within this fraction of the targets
    max_runs: int = 8            # calibration: at most this many rounds
    #: calibration: decoupled (the paper's: E from E_b, strength from sigma_b) or full (2 x 2)
    jacobian: str = "decoupled"
    fd_step: float = 0.1         # calibration: Delta E_b / E_b of the finite-difference Jacobian (eq. 19)
    start_E_GPa: float = 0.0     # calibration: the bond E_b to start from (0: the material's)
    start_strength_MPa: float = 0.0  # calibration: the bond strength to start from (0: the material's)
    # bulk (K_E), coating, porosity, convergence
    diameters_nm: list[float] = field(default_factory=lambda: [60.0, 45.0])  # bulk, convergence: the particle diameters
    #: coating: the titania thicknesses
    thicknesses_nm: list[float] = field(default_factory=lambda: [0.0, 10.0, 20.0, 34.0])
    #: porosity: the targets of random pores
    porosities: list[float] = field(default_factory=lambda: [0.30, 0.36, 0.42, 0.49, 0.55, 0.62])
    #: porosity: every job's particle diameter, the study's resolution (0: the base's; the paper's 15 nm at paper
    #: scale): the same study at several resolutions finds the coarsest that gives the paper's exponents
    diameter_nm: float = 0.0
    #: porosity, convergence, aerogel studies: one job per seed
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    #: convergence: pore cells [x, y] of each cross-section
    cells: list[list[int]] = field(default_factory=lambda: [[1, 1], [2, 1], [2, 2]])
    # aerogel_density
    #: aerogel_density: the aggregates' solid fractions
    solid_fractions: list[float] = field(default_factory=lambda: [0.04, 0.05, 0.06, 0.08, 0.10])
    loop_models: list[str] = field(default_factory=lambda: ["none"])     # aggregate.loops of each series


@dataclass
class StudyWorkflow(WorkflowSpec):
    """A study: many compression jobs made from one base workflow (Dosta et al.)."""

    study: StudySpec = field(default_factory=StudySpec)
    executor: ExecutorSpec = field(default_factory=ExecutorSpec)

    def validate(self) -> None:
        """The [study] section; the jobs' own specs are validated when the study builds them."""
        super().validate()
        st = self.study
        check(st.type in STUDIES, "study.type", st.type, f"must be one of {', '.join(STUDIES)}")
        reads = COMMON + STUDY_TYPES[st.type].fields
        for f in fields(StudySpec):
            default = f.default if f.default is not MISSING else f.default_factory()
            check(f.name in reads or getattr(st, f.name) == default, f"study.{f.name}", getattr(st, f.name),
                  f"is not read by a '{st.type}' study (it reads {', '.join(STUDY_TYPES[st.type].fields) or 'none'} "
                  f"besides {', '.join(COMMON[1:])})")
        for where, name in (("study.base", st.base), ("study.paper_base", st.paper_base)):
            check_name(where, name)
        check(st.np >= 1, "study.np", st.np, "must be >= 1 (MPI processes per job)")
        self.executor.validate()
        check(st.method in METHODS, "study.method", st.method, f"must be one of {', '.join(METHODS)}")
        check(METHODS[st.method].strength or st.type != "calibration", "study.method", st.method,
              "must give a strength for a calibration ('dynamic' or 'quasistatic': it fits the strength, which a "
              "static solve has not)")
        check(st.target_E_GPa > 0, "study.target_E_GPa", st.target_E_GPa, "must be > 0")
        check(st.target_strength_MPa > 0, "study.target_strength_MPa", st.target_strength_MPa, "must be > 0")
        check(0 < st.tolerance < 0.5, "study.tolerance", st.tolerance, "must be in (0, 0.5) (relative)")
        check(2 <= st.max_runs <= 100, "study.max_runs", st.max_runs, "must be in [2, 100]")
        check(st.jacobian in ("decoupled", "full"), "study.jacobian", st.jacobian, "must be 'decoupled' or 'full'")
        check(0.001 <= st.fd_step <= 0.5, "study.fd_step", st.fd_step, "must be in [0.001, 0.5] (relative step, eq. 19)")
        check(st.start_E_GPa >= 0, "study.start_E_GPa", st.start_E_GPa, "must be >= 0 (0: the material's)")
        check(st.start_strength_MPa >= 0, "study.start_strength_MPa", st.start_strength_MPa,
              "must be >= 0 (0: the material's)")
        check(len(st.diameters_nm) >= 1 and all(d > 0 for d in st.diameters_nm), "study.diameters_nm",
              st.diameters_nm, "must be a non-empty list of diameters > 0")
        check(st.diameter_nm == 0 or 5 <= st.diameter_nm <= 200, "study.diameter_nm", st.diameter_nm,
              "must be 0 (the base's) or a particle diameter in [5, 200] nm")
        check(all(0 <= t < 200 for t in st.thicknesses_nm), "study.thicknesses_nm", st.thicknesses_nm,
              "must be thicknesses in [0, 200) nm")
        check(len(st.porosities) >= 1 and all(0 < p <= 0.66 for p in st.porosities), "study.porosities",
              st.porosities, "must be porosities in (0, 0.66]")
        check(len(st.seeds) >= 1 and all(s >= 0 for s in st.seeds) and len(set(st.seeds)) == len(st.seeds),
              "study.seeds", st.seeds, "must be distinct seeds >= 0")
        check(len(st.solid_fractions) >= 2 and all(0 < f <= 0.5 for f in st.solid_fractions), "study.solid_fractions",
              st.solid_fractions, "must be at least two solid fractions in (0, 0.5]")
        check(len(st.loop_models) >= 1 and all(m in LOOP_MODELS for m in st.loop_models)
              and len(set(st.loop_models)) == len(st.loop_models), "study.loop_models", st.loop_models,
              f"must be distinct loop models among {', '.join(LOOP_MODELS)}")
        check(len(st.cells) >= 1 and all(len(c) == 2 and min(c) >= 1 for c in st.cells), "study.cells",
              st.cells, "must be [cells_x, cells_y] pairs >= 1")
