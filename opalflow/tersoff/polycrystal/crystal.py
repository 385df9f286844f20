"""The single crystal a polycrystal is made of: lattice constant, relaxed elastic constants, stability.

Computed by the fit's exact model (:class:`opalflow.tersoff.model.DiamondModel`: automatic
derivatives of the diamond crystal's energy, C44 with the internal relaxation), so a
``.tersoff`` file is judged before anything runs.  A set is refused when the diamond crystal is
not a stable minimum (Born 1940, cubic: C11 - C12 > 0, C11 + 2 C12 > 0, C44 > 0), when it does
not bind (Ec >= 0), or when the 64-atom sample's Hessian has a negative eigenvalue (a soft
phonon at the sample's wave vectors): the polycrystal would have nothing to relax to.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from opalflow.spec import SpecError
from opalflow.tersoff.parameters import TersoffParameters


@lru_cache(maxsize=8)
def _constants(values: tuple, element: str) -> dict:
    from opalflow.tersoff.model import DiamondModel, neighbor_radius
    p = TersoffParameters.from_values(values, element)
    model = DiamondModel(a=5.431, neighbor_radius_over_a=neighbor_radius(p.cutoff(), 5.431))
    try:
        a0 = model.lattice_constant(p.values())
    except RuntimeError:
        return {"a0_A": None}
    return {"a0_A": a0, **model.evaluate(p, a0)}


def single_crystal(params: TersoffParameters, potential: str, where: str = "tersoff.potential") -> dict:
    """a0 (A), Ec (eV) and the elastic constants (GPa) of the diamond crystal; SpecError if unstable."""
    c = _constants(tuple(float(v) for v in params.values()), params.element)
    if c["a0_A"] is None or not np.isfinite(c["a0_A"]):
        raise SpecError(where, potential, "fails the stability check: no zero-pressure diamond lattice constant")
    c11, c12, c44 = c["C11_GPa"], c["C12_GPa"], c["C44_GPa"]
    if not (c11 - c12 > 0 and c11 + 2 * c12 > 0 and c44 > 0 and c["Ec_eV"] < 0):
        raise SpecError(where, potential, f"fails the stability check: C11 = {c11:.1f}, C12 = {c12:.1f}, "
                        f"C44 = {c44:.1f} GPa, Ec = {c['Ec_eV']:.3f} eV (needs C11 - C12 > 0, C11 + 2 C12 > 0, "
                        "C44 > 0 (Born) and Ec < 0)")
    return c


def check_sample_hessian(samples, potential: str, where: str = "tersoff.potential") -> None:
    """Refuse a set whose unstrained 64-atom sample is not a minimum (negative Hessian eigenvalue)."""
    pinv = samples.hessian_pinv()
    lam = np.linalg.eigvalsh(0.5 * (pinv + pinv.T))
    if lam.min() < -1e-8 * abs(lam).max():
        raise SpecError(where, potential, "fails the stability check: the 64-atom sample's Hessian has a "
                        "negative eigenvalue (a soft phonon; the sample would not relax to the crystal)")


def longitudinal_speed_nm_ps(crystal: dict) -> float:
    """Voigt estimate of the longitudinal (plate) wave speed, the fastest the polycrystal carries (nm/ps)."""
    bulk = (crystal["C11_GPa"] + 2 * crystal["C12_GPa"]) / 3.0
    shear = (crystal["C11_GPa"] - crystal["C12_GPa"] + 3 * crystal["C44_GPa"]) / 5.0
    density = 8 * 28.0855 * 1.66053907e-27 / (crystal["a0_A"] * 1e-10) ** 3
    return float(np.sqrt((bulk + 4 * shear / 3) * 1e9 / density)) * 1e-3


def quasi_static_rate(crystal: dict, strain_step: float, length_nm: float) -> float:
    """Largest strain rate (1/ns) at which a strain step lasts one longitudinal transit of ``length_nm``.

    Quasi-static loading needs the loading time of each step to exceed the time a wave needs to
    cross the sample (otherwise the far side does not know the near side moved): strain_step /
    rate >= length / c_L.
    """
    return strain_step * longitudinal_speed_nm_ps(crystal) / length_nm * 1e3
