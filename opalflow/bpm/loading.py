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

import numpy as np

from opalflow.lammps.syntax import num, render
from opalflow.materials import ContactProperties, linear_contact_stiffness


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


class Loading:
    """How the top of the sample is moved.  ``sense`` +1: the top moves down (compression), -1: up
    (tension); ``glued``: the top particle layer moves with the wall in all six degrees of freedom (held
    in x, y and rotation), else only its z is pushed (a frictionless plate, in the static solvers)."""

    name = ""
    sense = 1
    glued = True
    title = ""

    def blocks(self, v: float, substrate_type: int, top_layer_z: float, top: float, base: float,
               plate_args: str) -> dict[str, str]:
        """The deck's ``groups`` and ``plate`` blocks (and ``affine_start`` where the loading has one) for
        a wall speed ``v`` (m/s = nm/ns)."""
        wall_vz = num(-self.sense * v)
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

    def blocks(self, v, substrate_type, top_layer_z, top, base, plate_args):
        return {"groups": render("groups", substrate_type=num(substrate_type), top_layer_z=num(top_layer_z)),
                "plate": render("plate", plate_speed=num(v), plate_z0=num(top), plate_contact=plate_args)}


class GluedCompression(Loading):
    """The top particle layer glued to a wall moving down (displacement-controlled compression)."""

    name, sense, glued, title = "glued", 1, True, "uniaxial compression, top layer glued to the wall"


class UniaxialTension(Loading):
    """The top particle layer glued to a wall moving up: uniaxial tension (Roy and Hossain's direct
    tension test, the tensile strength of eq. 10.4)."""

    name, sense, glued, title = "tension", -1, True, "uniaxial tension, top layer pulled"


#: ``compression.loading`` -> loading
LOADINGS: dict[str, Loading] = {"plate": PlateCompression(), "glued": GluedCompression(), "tension": UniaxialTension()}
