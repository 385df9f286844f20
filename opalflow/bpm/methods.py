"""The methods of a bonded-particle loading: ``compression.method`` -> :class:`Method`.

A method is how the response of the loaded sample is computed: a LAMMPS run (``dynamic``,
:mod:`opalflow.bpm.dynamic_run`), one linear solve of the bond network (``static``: E, no strength,
:mod:`opalflow.bpm.static_run`) or the event-driven fracture of the linear network (``quasistatic``: E and strength
at zero rate, :mod:`opalflow.bpm.quasistatic_run`).  Here are what each method is (light: the spec's validation
calls :meth:`Method.check`): what it needs of the spec, which command-line options it takes, what it gives.  How
each runs, prices and resumes is its runner module's, side by side in :data:`opalflow.bpm.run.RUNNERS`.  A new
method is one class here, one line in :data:`METHODS` and its runner module with one line in ``RUNNERS``.
"""
from __future__ import annotations

from opalflow.bpm.bonds import BOND_MODELS
from opalflow.spec import check


class Method:
    """A way to compute the loading of a bonded-particle sample."""

    name = ""
    #: the command-line options it takes (keywords of the runner): of np_, resume, suffix
    options: tuple[str, ...] = ()
    refusal = ""
    #: the linear bond network (no loading rate, no time step; bonds must carry moments)
    linear = True
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


class Dynamic(Method):
    """LAMMPS integrates the motion (:mod:`opalflow.bpm.dynamic_run`)."""

    name, linear = "dynamic", False
    options = ("np_", "resume", "suffix")


class Static(Method):
    """One linear solve of the bond network (:mod:`opalflow.bpm.static_run`)."""

    name, tensor, strength = "static", True, False
    #: a solve of about a second (d = 60 nm) that three plots would make three times longer: asked, not default
    plots = False
    refusal = "a static solve has no --resume, --np or --suffix"


class Quasistatic(Method):
    """Event-driven breaking of the linear network (:mod:`opalflow.bpm.quasistatic_run`)."""

    name = "quasistatic"
    options = ("resume",)
    refusal = "the quasi-static method has no --np or --suffix"

    paper_rules = True

    def check(self, spec):
        super().check(spec)
        check(spec.bonds.breakable, "bonds.breakable", spec.bonds.breakable,
              "must be true with compression.method = \"quasistatic\" (it breaks bonds; \"static\" gives E alone)")
        check(spec.compression.solver == "auto", "compression.solver", spec.compression.solver,
              "is the static method's: the quasi-static re-solves are set by compression.resolver")


#: ``compression.method`` -> method
METHODS: dict[str, Method] = {m.name: m for m in (Dynamic(), Static(), Quasistatic())}
