"""Materials: properties from ``data/materials.toml`` (with their sources)."""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import lru_cache

from opalflow.resources import DATA, resource


@lru_cache(maxsize=1)
def load_materials() -> dict[str, dict]:
    return tomllib.loads(resource(DATA, "materials.toml").read_text())


def material_names() -> tuple[str, ...]:
    return tuple(load_materials())


#: properties a workflow may override per material (``[materials.<name>]``)
OVERRIDABLE = ("density_kg_m3", "bond_youngs_modulus_GPa", "bond_poisson_ratio", "bond_strength_MPa")


@dataclass(frozen=True)
class MaterialContact:
    """A material's contact properties (Hertz-Mindlin, Dosta et al. eqs. 5-10): E (GPa), nu, restitution,
    friction."""

    youngs_modulus_GPa: float
    poisson_ratio: float
    restitution: float
    friction: float


@dataclass(frozen=True)
class Material:
    """A material of ``data/materials.toml``: density (kg/m^3), the bond's E (GPa), nu and strength (MPa) of the
    bonded-particle model (Dosta et al. Table 1; none for the plate's diamond), its source and its contact."""

    density_kg_m3: float
    bond_youngs_modulus_GPa: float | None = None
    bond_poisson_ratio: float | None = None
    bond_strength_MPa: float | None = None
    source: str = "workflow"
    contact: MaterialContact | None = None


def material(name: str, overrides: dict | None = None) -> Material:
    """Properties of a material, with a workflow's ``[materials.<name>]`` overrides applied."""
    try:
        base = load_materials()[name]
    except KeyError:
        raise KeyError(f"unknown material {name!r}; known: {', '.join(material_names())}") from None
    raw = {**base, **(overrides or {}).get(name, {})}
    contact = raw.pop("contact", None)
    return Material(**raw, contact=MaterialContact(**contact) if contact is not None else None)


@dataclass
class BondCoefficients:
    """Coefficients of one ``bond_style bpm/rotational normalize yes`` bond type (nano units).

    Mapping from the paper's ideally elastic bond (Dosta et al. eq. 11) with bond
    radius r_b, area A = pi r_b^2, second moments I = pi r_b^4 / 4, J = 2 I and
    G = E / (2 (1 + nu)):

    ======  ============  =========================================================
    kr      E A           normal force kr (r - r0) / r0 (normalize yes), pN
    ks      G A           shear force ks xi_t / r0 (eq. 11), pN
    kt      G J / L0      twisting torque per radian, pN nm
    kb      E I / L0      bending torque per radian, pN nm
    fr_c    sigma A       critical normal force
    fs_c    tau A         critical shear force (tau = sigma, as the paper assumes)
    tb_c    sigma I / r_b critical bending torque (the M R / I term of eq. 16)
    tt_c    tau J / r_b   critical twisting torque (the M R / J term of eq. 17)
    ======  ============  =========================================================

    LAMMPS breaks a bond when B = max(0, f_r/fr_c + |f_s|/fs_c + |tau_b|/tb_c +
    |tau_t|/tt_c) >= 1: one sum of all four ratios, with the signed normal force
    (compression lowers B).  The paper breaks a bond when either the normal stress
    (eq. 16, |F_n|: compression too) or the shear stress (eq. 17) reaches the
    strength.  With the mapping above LAMMPS's B is the sum of the two ratios of
    eqs. 16 and 17 for a bond in tension, so a bond loaded in tension and shear
    breaks earlier than in the paper (by up to a factor 2 in load when both ratios
    are equal), and a bond in pure compression never breaks by its normal force
    (the paper's code, MUSEN, counts F_n signed as well; the quasi-static method
    applies either rule: ``bonds.breaking``, :mod:`opalflow.bpm.quasistatic`).
    Bonds that break fade out with w = 1 - B^4 (``smooth yes``) instead of the
    paper's 1 ns of stiffness decaying by 1 % per 1e-11 s; both avoid a jump in
    force, LAMMPS's within the step the bond breaks.

    Damping (gamma_n, gamma_s, gamma_r, gamma_t) is the fraction ``zeta`` of
    critical damping of each two-particle mode, c = 2 zeta sqrt(m_red k).  LAMMPS
    applies the normal and sliding coefficients as force per relative velocity, the
    twisting one as 0.5 gamma_t per relative angular velocity and the rolling one as
    0.5 gamma_r r per relative angular velocity (BondBPMRotational::damping_forces),
    so gamma_t = 2 c_t and gamma_r = 2 c_r / L0.

    A contact bond (``moments=False``; PFC's contact bond, Roy and Hossain Fig. 10.8: glue of vanishing
    radius at the contact point that transmits a force and no moment, and breaks when the force exceeds
    its strength) is ``bond_style bpm/spring``: the central spring kr (``normalize yes``) that breaks at
    the strain eps_c = fr_c / kr where its force reaches fr_c, with the normal damping gn
    (:meth:`spring_values`); ks = kt = kb = 0.  Why a central spring and not bpm/rotational with zero
    bending and twisting stiffness: (1) with no moment at the contact the spheres rotate freely, and a
    sphere's moment balance R n_k x F_s,k summed over its bonds = 0 forces the shear force of a sphere
    with one bond to vanish and leaves at most one shear component for a sphere with two: in the
    DLCA networks (mean coordination 2.0) the contact bond's shear spring carries next to nothing in
    equilibrium, which the central spring reproduces; (2) measured: bpm/rotational with kb = kt = 0
    blew up every aerogel compression at about 5 % strain with contacts on or off and at 0.3 of the
    time step (the folding network turns its spheres far from their bond directions, where LAMMPS's
    shear from the angle between bond and body-fixed reference vector loses its direction), and
    bpm/spring costs about 1/25 of it per bond.  What the central spring lacks: the shear stiffness and
    shear strength at spheres with three or more bonds (loops, 1 % of the spheres here).
    """

    kr: float
    ks: float
    kt: float
    kb: float
    fr_c: float
    fs_c: float
    tb_c: float
    tt_c: float
    gn: float
    gs: float
    gr: float
    gt: float

    def spring_values(self) -> list[float]:
        """``bond_style bpm/spring`` coefficients of the contact bond: k (= kr, ``normalize yes``), the
        critical strain fr_c / kr, gamma (= gn)."""
        return [self.kr, self.fr_c / self.kr, self.gn]

    def values(self) -> list[float]:
        """In the order BondBPMRotational::coeff() reads them: kr ks kt kb Fr_c Fs_c
        Tt_c Tb_c gamma_n gamma_s gamma_roll gamma_twist (twist before bend)."""
        return [self.kr, self.ks, self.kt, self.kb, self.fr_c, self.fs_c, self.tt_c, self.tb_c,
                self.gn, self.gs, self.gr, self.gt]


def bond_coefficients(material_name: str, bond_radius: float, length: float, mass: float,
                      inertia: float, damping_ratio: float, overrides: dict | None = None,
                      moments: bool = True) -> BondCoefficients:
    """bpm/rotational coefficients for a bond of ``material_name`` (see BondCoefficients); ``moments``
    False gives the contact bond (a central spring: ``BondCoefficients.spring_values``).

    bond_radius and length in nm, mass in ag, inertia (of one particle) in ag nm^2.
    """
    m = material(material_name, overrides)
    E = m.bond_youngs_modulus_GPa * 1.0e3          # MPa = pN/nm^2
    nu = m.bond_poisson_ratio
    sigma = m.bond_strength_MPa
    G = E / (2.0 * (1.0 + nu))
    A = math.pi * bond_radius**2
    I = math.pi * bond_radius**4 / 4.0
    J = 2.0 * I
    kr, ks, kt, kb = E * A, G * A, G * J / length, E * I / length
    if not moments:
        ks = kt = kb = 0.0
    m_red, i_red = mass / 2.0, inertia / 2.0
    z = damping_ratio
    return BondCoefficients(
        kr=kr, ks=ks, kt=kt, kb=kb,
        fr_c=sigma * A, fs_c=sigma * A, tb_c=sigma * I / bond_radius, tt_c=sigma * J / bond_radius,
        gn=2 * z * math.sqrt(m_red * kr / length), gs=2 * z * math.sqrt(m_red * ks / length),
        gr=2 * (2 * z * math.sqrt(i_red * kb)) / length, gt=2 * (2 * z * math.sqrt(i_red * kt)),
    )


@dataclass
class ContactProperties:
    """Contact of one material: Hertz-Mindlin (pair_style granular hertz/material, mindlin) or linear
    (hooke, linear_history) with normal stiffness ``stiffness`` (pN/nm)."""

    youngs_modulus_MPa: float
    poisson_ratio: float
    restitution: float
    friction: float
    model: str = "hertz"
    stiffness: float = 0.0

    @property
    def tangential_ratio(self) -> float:
        """k_t / k_n = 2 (1 - nu) / (2 - nu): Mindlin's ratio for equal spheres, used by the linear model
        too, so that the two models differ only in the normal force law."""
        return 2 * (1 - self.poisson_ratio) / (2 - self.poisson_ratio)


def linear_contact_stiffness(contact: ContactProperties, radius: float) -> float:
    """Normal stiffness (pN/nm) of a linear contact between spheres of that radius (nm): two balls of
    PFC stiffness k_n = 4 R E in series (Roy and Hossain eq. 10.3), K = 2 R E."""
    return 2 * radius * contact.youngs_modulus_MPa


def contact_properties(material_name: str) -> ContactProperties:
    c = material(material_name).contact
    return ContactProperties(c.youngs_modulus_GPa * 1.0e3, c.poisson_ratio, c.restitution, c.friction)
