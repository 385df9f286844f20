"""Isotropic averages of an anisotropic stiffness tensor (Voigt order xx yy zz yz xz xy, engineering shear).

Voigt (uniform strain, 1928) and Reuss (uniform stress, 1929) bounds of the bulk and shear moduli of a
6 x 6 tensor C and its compliance S = C^-1, their Hill mean (Hill, Proc. Phys. Soc. A 65, 349, 1952):

    9 K_V = (C11 + C22 + C33) + 2 (C12 + C23 + C13)
    15 G_V = (C11 + C22 + C33) - (C12 + C23 + C13) + 3 (C44 + C55 + C66)
    1 / K_R = (S11 + S22 + S33) + 2 (S12 + S23 + S13)
    15 / G_R = 4 (S11 + S22 + S33) - 4 (S12 + S23 + S13) + 3 (S44 + S55 + S66)

the isotropic E = 9 K G / (3 K + G) and nu = (3 K - 2 G) / (2 (3 K + G)) of each, and the universal
anisotropy index A^U = 5 G_V / G_R + K_V / K_R - 6 >= 0, zero only for an isotropic tensor (Ranganathan and
Ostoja-Starzewski, Phys. Rev. Lett. 101, 055504, 2008).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the Voigt order of a symmetric tensor's index pairs: xx yy zz yz xz xy
VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


def _young_poisson(K: float, G: float) -> tuple[float, float]:
    return 9 * K * G / (3 * K + G), (3 * K - 2 * G) / (2 * (3 * K + G))


@dataclass
class Moduli:
    """The isotropic bulk, shear and Young's moduli (the unit of the tensor) and Poisson ratio of one average."""

    K: float
    G: float
    E: float
    nu: float


@dataclass
class IsotropicAverage:
    """The Voigt, Reuss and Hill averages of a stiffness tensor and its universal anisotropy index A^U."""

    voigt: Moduli
    reuss: Moduli
    hill: Moduli
    anisotropy_index: float


def isotropic_average(C: np.ndarray) -> IsotropicAverage:
    """Voigt, Reuss and Hill K, G, E, nu of the 6 x 6 tensor C (any unit; E, K, G in it) and A^U."""
    C = np.asarray(C, float)
    S = np.linalg.inv(C)
    tr, off, shear = np.trace(C[:3, :3]), C[0, 1] + C[1, 2] + C[0, 2], np.trace(C[3:, 3:])
    K_V, G_V = (tr + 2 * off) / 9, (tr - off + 3 * shear) / 15
    str_, soff, sshear = np.trace(S[:3, :3]), S[0, 1] + S[1, 2] + S[0, 2], np.trace(S[3:, 3:])
    K_R, G_R = 1 / (str_ + 2 * soff), 15 / (4 * str_ - 4 * soff + 3 * sshear)
    voigt, reuss, hill = (Moduli(float(K), float(G), *(float(x) for x in _young_poisson(K, G)))
                          for K, G in ((K_V, G_V), (K_R, G_R), ((K_V + K_R) / 2, (G_V + G_R) / 2)))
    return IsotropicAverage(voigt, reuss, hill, float(5 * G_V / G_R + K_V / K_R - 6))
