"""Loadings and contact laws of the bonded-particle scenes, as objects the dynamic deck
(:func:`opalflow.bpm.deck.compression_deck`) and the static and quasi-static solvers share.

A loading says how the top of the sample is moved (its LAMMPS groups, wall and start blocks) and, for
the solvers, which degrees of freedom of the top layer it prescribes and in which sense.  Strain and
stress are reported positive in the loading's own sense (``sense`` +1: compression, -1: tension).  A
contact law gives the ``pair_coeff`` / wall arguments of ``pair_style granular`` and its normal stiffness
for the time step.  (Bond models live with the bonds: :data:`opalflow.bpm.bonds.BOND_MODELS`.)  A new loading (contact
law) is one class here and one line in :data:`LOADINGS` (:data:`CONTACT_LAWS`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from opalflow.lammps.syntax import num, render
from opalflow.materials import ContactProperties, linear_contact_stiffness
from opalflow.spec import SpecError


class ContactLaw:
    """A contact force law between unbonded particles (``pair_style granular``)."""

    def prepare(self, contact: ContactProperties, radius: float) -> ContactProperties:
        """The contact properties this law uses for particles of that radius."""
        return contact

    def args(self, contact: ContactProperties, E: float | None = None, k: float | None = None) -> str:
        raise NotImplementedError

    def stiffness(self, contact: ContactProperties, radius, overlap, E: float | None = None, wall: bool = False):
        """Normal contact stiffness (pN/nm) for the time step: two particles of effective radius ``radius``
        (nm) at ``overlap`` (nm), or (``wall``) one particle on a rigid wall whose contact has modulus E."""
        raise NotImplementedError


class HertzMindlin(ContactLaw):
    """Hertz normal force (``hertz/material``, Young's modulus ``E``: for a wall, E such that its E* is
    particle-on-plate) and Mindlin's tangential spring with Coulomb friction."""

    def args(self, contact, E=None, k=None):
        return (f"hertz/material {num(E if E is not None else contact.youngs_modulus_MPa)} "
                f"{num(contact.restitution)} {num(contact.poisson_ratio)} tangential mindlin NULL 1.0 "
                f"{num(contact.friction)} damping coeff_restitution")


    def stiffness(self, contact, radius, overlap, E=None, wall=False):
        """dF/d(overlap) of Hertz's F = 4/3 E* sqrt(R) overlap^1.5 is 2 E* sqrt(R overlap), with E* =
        E / (2 (1 - nu^2)) (equal materials: LAMMPS's hertz/material)."""
        e_star = (E if E is not None else contact.youngs_modulus_MPa) / (2 * (1 - contact.poisson_ratio**2))
        return 2 * e_star * np.sqrt(radius * overlap)


class LinearContact(ContactLaw):
    """PFC's linear contact: normal stiffness K = 2 R E (``hooke``, :func:`linear_contact_stiffness`),
    tangential k_t = ``tangential_ratio`` K (``linear_history``), Coulomb friction."""

    def prepare(self, contact, radius):
        return dataclasses.replace(contact, model="linear", stiffness=linear_contact_stiffness(contact, radius))

    def args(self, contact, E=None, k=None):
        kn = k if k is not None else contact.stiffness
        return (f"hooke {num(kn)} {num(contact.restitution)} tangential linear_history "
                f"{num(contact.tangential_ratio * kn)} 1.0 {num(contact.friction)} damping coeff_restitution")

    def stiffness(self, contact, radius, overlap, E=None, wall=False):
        """K as it is; on a wall one ball of the two in series: 2 K."""
        return (2.0 if wall else 1.0) * contact.stiffness


#: ``contacts.model`` -> law
CONTACT_LAWS: dict[str, ContactLaw] = {"hertz": HertzMindlin(), "linear": LinearContact()}


@dataclass
class Supports:
    """What the linear solvers (the static and quasi-static methods) hold and move, for one loading of one
    sample: ``held`` (n, 6) the prescribed degrees of freedom, ``drive`` (n, 6) their displacement per unit
    strain (zero where held still), ``loaded`` the particles whose z reaction is the load, ``anchored`` the
    particles that hold the network in place (one with no bond path to them is loose), and the stress and
    strain measures: stress = -``sense`` x (the loaded particles' z reaction) / ``area_nm2``, strain =
    displacement / ``gauge_nm``."""

    held: np.ndarray
    drive: np.ndarray
    loaded: np.ndarray
    anchored: np.ndarray
    sense: int
    area_nm2: float
    gauge_nm: float

    def without(self, loose: np.ndarray) -> "Supports":
        """The same with the ``loose`` particles held still (they carry nothing)."""
        held, drive = self.held.copy(), self.drive.copy()
        held[loose], drive[loose] = True, 0.0
        return dataclasses.replace(self, held=held, drive=drive, loaded=self.loaded & ~loose)

    def stress(self, force: np.ndarray) -> float:
        """The stress (MPa, positive in the loading's sense) of an internal force ``force`` = K x (n x 6)."""
        return -self.sense * float(np.sum(force.reshape(len(self.loaded), 6)[self.loaded, 2])) / self.area_nm2


@dataclass
class Placement:
    """Where a loading holds a sample (:meth:`Loading.place`): the strain's gauge ``height_nm`` and the stress's
    ``area_nm2``, the substrate's top ``base_nm``, the sample's top ``plate_z0_nm``, the driven particles
    (``top_layer``) and their mean centre height ``top_z0_nm``, and what else it placed (``marks``; bending:
    span, supports, nose)."""

    height_nm: float
    area_nm2: float
    base_nm: float
    plate_z0_nm: float
    top_z0_nm: float
    top_layer: np.ndarray
    marks: dict


class Loading:
    """How the sample is held and moved.  Its measures make every method's stress and strain: the strain
    is the driven particles' displacement over ``height_nm`` and the stress their force over ``area_nm2``
    (:meth:`place`), both positive in the loading's ``sense`` (+1: the driven particles move down, -1: up).

    This base class is the uniaxial test of a sample on its fixed substrate: the top particle layer is
    driven (LAMMPS group ``top``); ``glued``: it moves with the wall in all six degrees of freedom (held in
    x, y and rotation), else only its z is pushed (a frictionless plate, in the static solvers)."""

    name = ""
    sense = 1
    glued = True
    title = ""
    #: the dynamic deck starts the mobile particles on the homogeneous strain field and drags them relative to it
    affine = True
    #: the sample stands on a fixed substrate (scenes that may leave it out, the lattice, ask)
    substrate = True
    #: the deck's name of the held particles' z force (the plate block defines it)
    support_force = "c_substrate_fz"
    #: LAMMPS's boundary along z: fixed at the substrate and the plate ("f"), or shrink-wrapped
    z_boundary = "f"

    def check(self, spec) -> None:
        """Refuse a spec this loading cannot hold (one line), before anything is built."""

    def place(self, s, d_mean: float) -> Placement:
        """The loaded geometry of structure ``s``: ``height_nm`` (from the substrate's top to the sample's),
        ``area_nm2`` (the box across periodic sides, the footprint across open ones), ``base_nm``,
        ``plate_z0_nm`` (the sample's top), ``top_z0_nm`` and ``top_layer`` (centres within 3/4 of a mean
        diameter ``d_mean`` of the top surface)."""
        substrate = s.groups.get("substrate", np.zeros(s.n_particles, bool))
        if not substrate.any():
            # (a data file's scene names datafile.substrate itself when its choice selects no particle)
            raise SpecError("substrate.layers", 0, "the compression needs a fixed substrate (layers >= 1)")
        top = float(np.max(s.positions[:, 2] + s.diameters / 2))
        base = float(np.max(s.positions[substrate, 2] + s.diameters[substrate] / 2))
        top_group = (s.positions[:, 2] >= top - 0.75 * d_mean) & ~substrate
        r = s.diameters / 2
        extent = [float(s.box_lengths[k]) if s.periodic[k] else float(np.max(s.positions[:, k] + r) -
                                                                        np.min(s.positions[:, k] - r)) for k in (0, 1)]
        return Placement(top - base, extent[0] * extent[1], base, top, float(np.mean(s.positions[top_group, 2])),
                         top_group, {})

    def held_text(self, driven: int) -> str:
        """How the sample is held and moved, for the reports (``driven``: the driven particles' count)."""
        return (f"substrate fixed, top layer ({driven} particles) {'pushed down' if self.sense > 0 else 'pulled up'}"
                + (", glued to the wall (x, y and rotations held)" if self.glued else ", its x, y and rotations free"))

    def supports(self, sample) -> Supports:
        """The linear solvers' boundary conditions of a :class:`opalflow.bpm.deck.LoadedSample`: the substrate
        held still, the top layer moved in z by -sense x height per unit strain (and held in its other five
        degrees of freedom when glued)."""
        fixed, top = sample.structure.groups["substrate"], sample.top_layer
        n = len(fixed)
        held = np.zeros((n, 6), bool)
        held[fixed] = True
        driven = top & ~fixed
        held[driven, slice(None) if self.glued else 2] = True
        drive = np.zeros((n, 6))
        drive[driven, 2] = -self.sense * sample.height_nm
        return Supports(held=held, drive=drive, loaded=driven, anchored=fixed | (top if self.glued else False),
                        sense=self.sense, area_nm2=sample.area_nm2, gauge_nm=sample.height_nm)

    def blocks(self, sample, v: float, substrate_type: int, top_layer_z: float, plate_args: str) -> dict[str, str]:
        """The deck's ``groups`` and ``plate`` blocks (and ``affine_start`` where the loading has one) for
        a wall speed ``v`` (m/s = nm/ns)."""
        wall_vz = num(-self.sense * v)
        top, base = sample.plate_z0_nm, sample.base_nm
        out = {"groups": render("groups_glued", substrate_type=num(substrate_type), top_layer_z=num(top_layer_z)),
               "plate": render("plate_glued", wall_vz=wall_vz, plate_speed=num(v),
                               direction="down" if self.sense > 0 else "up"),
               "affine_start": render("affine_start", top_vz=wall_vz, base=num(base), top=num(top))}
        return out

    def strain_expression(self) -> str:
        """The LAMMPS sign of the strain in the loading's sense from the wall's displacement ``plate_dz``."""
        return "-" if self.sense > 0 else ""


class PlateCompression(Loading):
    """A rigid plate (``fix wall/gran/region``, the contact law against diamond) moving down onto the
    top of the sample (Dosta et al.'s test)."""

    name, sense, glued, title = "plate", 1, False, "uniaxial compression by a plate"

    def blocks(self, sample, v, substrate_type, top_layer_z, plate_args) -> dict[str, str]:
        return {"groups": render("groups", substrate_type=num(substrate_type), top_layer_z=num(top_layer_z)),
                "plate": render("plate", plate_speed=num(v), plate_z0=num(sample.plate_z0_nm),
                                plate_contact=plate_args)}


class GluedCompression(Loading):
    """The top particle layer glued to a wall moving down (displacement-controlled compression)."""

    name, sense, glued, title = "glued", 1, True, "uniaxial compression, top layer glued to the wall"


class UniaxialTension(Loading):
    """The top particle layer glued to a wall moving up: uniaxial tension (Roy and Hossain's direct
    tension test, the tensile strength of eq. 10.4)."""

    name, sense, glued, title = "tension", -1, True, "uniaxial tension, top layer pulled"


class ThreePointBending(Loading):
    """Three-point bending of a beam along x (depth h along z, width b along y): simply supported on the
    bottom particles at its two ends (the pin at low x held, the roller at high x free along the span, both
    free to turn), loaded by a nose, the top particles at mid-span, moved down in z (free sideways, not
    turning: by symmetry they would not).

    The stress and strain are the flexural ones of ASTM D790 (simple beam theory): sigma_f = 3 F L / (2 b h^2)
    and epsilon_f = 6 delta h / L^2, so that their ratio is the flexural modulus E_f = F L^3 / (4 b h^3 delta)
    (Euler-Bernoulli: delta = F L^3 / (48 E I), I = b h^3 / 12).  They are force over an area and displacement
    over a length like every other loading's: ``area_nm2`` = 2 b h^2 / (3 L), ``height_nm`` = L^2 / (6 h).
    A beam has ends: open sides and no substrate."""

    name, sense, glued, title, affine, substrate = "bending", 1, False, "three-point bending", False, False
    support_force = "v_substrate_fz"
    z_boundary = "m"            # (the beam sags below where it began)

    def check(self, spec):
        sides = getattr(getattr(spec, "boundary", None), "sides", "open")
        if sides != "open":
            raise SpecError("compression.loading", self.name, "needs boundary.sides = \"open\" (a beam has ends)")

    def place(self, s, d_mean) -> Placement:
        if s.periodic[0]:
            raise SpecError("compression.loading", self.name, "needs boundary.sides = \"open\" (a beam has ends)")
        if s.groups.get("substrate", np.zeros(s.n_particles, bool)).any():
            raise SpecError("compression.loading", self.name, "needs a sample without a substrate (a lattice: "
                            "the bending loading leaves it out; other scenes stand on one)")
        x, r = s.positions, s.diameters / 2
        half = 0.5 * d_mean
        lo, hi = x.min(axis=0), x.max(axis=0)
        bottom = x[:, 2] < lo[2] + half
        pin, roller = bottom & (x[:, 0] < lo[0] + half), bottom & (x[:, 0] > hi[0] - half)
        span = float(np.mean(x[roller, 0]) - np.mean(x[pin, 0]))
        mid = 0.5 * float(np.mean(x[roller, 0]) + np.mean(x[pin, 0]))
        nose = (np.abs(x[:, 0] - mid) < half) & (x[:, 2] > hi[2] - half)
        depth = float(np.max(x[:, 2] + r) - np.min(x[:, 2] - r))
        width = float(s.box_lengths[1]) if s.periodic[1] else float(np.max(x[:, 1] + r) - np.min(x[:, 1] - r))
        top = float(np.max(x[:, 2] + r))
        return Placement(
            height_nm=span**2 / (6 * depth), area_nm2=2 * width * depth**2 / (3 * span),
            base_nm=float(np.min(x[:, 2] - r)), plate_z0_nm=top, top_z0_nm=float(np.mean(x[nose, 2])), top_layer=nose,
            marks={"span_nm": span, "depth_nm": depth, "width_nm": width, "pin": pin, "roller": roller,
                   "pin_x": float(lo[0] + half), "roller_x": float(hi[0] - half),
                   "bottom_z": float(lo[2] + half), "nose_lo": mid - half, "nose_hi": mid + half,
                   "nose_z": float(hi[2] - half)})

    def held_text(self, driven):
        return (f"simply supported on its bottom end particles (pin and roller, free to turn), {driven} nose particles "
                "at mid-span pushed down (free sideways); flexural stress and strain (ASTM D790)")

    def supports(self, sample):
        m, nose = sample.marks, sample.top_layer
        n = len(nose)
        held = np.zeros((n, 6), bool)
        held[m["pin"], :3] = True              # both supports turn freely
        held[m["roller"], 1:3] = True
        held[nose, 2:] = True
        drive = np.zeros((n, 6))
        drive[nose, 2] = -sample.height_nm
        return Supports(held=held, drive=drive, loaded=nose, anchored=m["pin"] | m["roller"], sense=1,
                        area_nm2=sample.area_nm2, gauge_nm=sample.height_nm)

    def blocks(self, sample, v, substrate_type, top_layer_z, plate_args) -> dict[str, str]:
        m = sample.marks
        return {"groups": render("groups_bending", **{k: num(m[k]) for k in ("pin_x", "roller_x", "bottom_z",
                                                                            "nose_lo", "nose_hi", "nose_z")}),
                "plate": render("plate_bending", wall_vz=num(-v), plate_speed=num(v))}


#: ``compression.loading`` -> loading
LOADINGS: dict[str, Loading] = {"plate": PlateCompression(), "glued": GluedCompression(), "tension": UniaxialTension(),
                                "bending": ThreePointBending()}
