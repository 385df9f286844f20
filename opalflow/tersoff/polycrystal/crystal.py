"""The single crystal a polycrystal is made of: lattice constant, relaxed elastic constants, stability.

Computed by the fit's exact model (:class:`opalflow.tersoff.model.DiamondModel`: automatic
derivatives of the diamond crystal's energy, C44 with the internal relaxation), so a
``.tersoff`` file is judged before anything runs.  A set is refused when the diamond crystal is
not a stable minimum (Born 1940, cubic: C11 - C12 > 0, C11 + 2 C12 > 0, C44 > 0), when it does
not bind (Ec >= 0), or when the 64-atom sample's Hessian has a negative eigenvalue (a soft
phonon at the sample's wave vectors): the polycrystal would have nothing to relax to.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from opalflow.spec import SpecError
from opalflow.tersoff.parameters import Properties, TersoffParameters


@dataclass(frozen=True)
class Crystal(Properties):
    """The diamond single crystal at its zero-pressure lattice constant ``a0_A``: Table 1's properties (C44 relaxed,
    C44^0 without the internal relaxation) and the residual dE/da (eV/A per atom):
    :meth:`opalflow.tersoff.model.DiamondModel.evaluate` at a0."""

    dE_da_eV_per_A: float

    @property
    def constants(self) -> tuple[float, float, float]:
        """(C11, C12, C44) in GPa: the cubic stiffness of each grain."""
        return self.C11_GPa, self.C12_GPa, self.C44_GPa


@lru_cache(maxsize=8)
def _crystal(values: tuple, element: str) -> Crystal | None:
    from opalflow.tersoff.model import DiamondModel, neighbor_radius
    p = TersoffParameters.from_values(values, element)
    model = DiamondModel(a=5.431, neighbor_radius_over_a=neighbor_radius(p.cutoff(), 5.431))
    try:
        a0 = model.lattice_constant(p.values())
    except RuntimeError:
        return None
    return Crystal(a0_A=a0, **model.evaluate(p, a0)) if np.isfinite(a0) else None


def single_crystal(params: TersoffParameters, potential: str, where: str = "tersoff.potential") -> Crystal:
    """The diamond crystal of ``params``; SpecError if it has no lattice constant or is unstable."""
    c = _crystal(tuple(float(v) for v in params.values()), params.element)
    if c is None:
        raise SpecError(where, potential, "fails the stability check: no zero-pressure diamond lattice constant")
    c11, c12, c44 = c.constants
    if not (c11 - c12 > 0 and c11 + 2 * c12 > 0 and c44 > 0 and c.Ec_eV < 0):
        raise SpecError(where, potential, f"fails the stability check: C11 = {c11:.1f}, C12 = {c12:.1f}, "
                        f"C44 = {c44:.1f} GPa, Ec = {c.Ec_eV:.3f} eV (needs C11 - C12 > 0, C11 + 2 C12 > 0, "
                        "C44 > 0 (Born) and Ec < 0)")
    return c


def check_sample_hessian(samples, potential: str, where: str = "tersoff.potential") -> None:
    """Refuse a set whose unstrained 64-atom sample is not a minimum (negative Hessian eigenvalue)."""
    pinv = samples.hessian_pinv()
    lam = np.linalg.eigvalsh(0.5 * (pinv + pinv.T))
    if lam.min() < -1e-8 * abs(lam).max():
        raise SpecError(where, potential, "fails the stability check: the 64-atom sample's Hessian has a "
                        "negative eigenvalue (a soft phonon; the sample would not relax to the crystal)")


def longitudinal_speed_nm_ps(crystal: Crystal) -> float:
    """Voigt estimate of the longitudinal (plate) wave speed, the fastest the polycrystal carries (nm/ps)."""
    c11, c12, c44 = crystal.constants
    bulk = (c11 + 2 * c12) / 3.0
    shear = (c11 - c12 + 3 * c44) / 5.0
    density = 8 * 28.0855 * 1.66053907e-27 / (crystal.a0_A * 1e-10) ** 3
    return float(np.sqrt((bulk + 4 * shear / 3) * 1e9 / density)) * 1e-3


def quasi_static_rate(crystal: Crystal, strain_step: float, length_nm: float) -> float:
    """Largest strain rate (1/ns) at which a strain step lasts one longitudinal transit of ``length_nm``.

    Quasi-static loading needs the loading time of each step to exceed the time a wave needs to
    cross the sample (otherwise the far side does not know the near side moved): strain_step /
    rate >= length / c_L.
    """
    return strain_step * longitudinal_speed_nm_ps(crystal) / length_nm * 1e3
