"""Conjugate gradients with a stop on the residual or on the estimated energy error.

The solver of :mod:`opalflow.bpm.static` (the static method) and :mod:`opalflow.bpm.quasistatic` (the
quasi-static method's iterative re-solves); nothing here knows a bond network: operators and preconditioners
are functions of a vector.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Stop:
    """When conjugate gradients stop: at relative residual ``rtol``, or (``energy_tol`` > 0) when the
    estimated energy error has fallen below ``energy_tol`` of the energy, after at most ``maxiter`` iterations.

    The energy criterion (Strakos and Tichy, ETNA 13:56, 2002; Meurant, The Lanczos and Conjugate Gradient
    Algorithms, 2006, ch. 5): CG minimises J(x) = 1/2 x^T K x - b^T x over growing Krylov spaces, and step k
    lowers it by exactly 1/2 alpha_k r_k^T z_k, so the energy W_k = ``energy0`` + J(x_k) of the loaded sample
    (``energy0``: the energy of the prescribed displacements alone) is known at every step and falls to its
    minimum W*, with W_k - W* = 1/2 |x_k - x*|_K^2.  The error left is estimated from the decreases
    (:func:`_energy_error`; their rate over the last fifth of the iterations, at least ``window`` steps: a
    slowly converging CG's decreases swing from step to step).  A modulus taken from the energy (E = 2 W / (A H e^2),
    Clapeyron) has relative error (W_k - W*) / W*: quadratic in the error of x, where the reaction force's
    is linear, so E to 1e-8 needs a residual of ~1e-4 instead of ~1e-8."""

    rtol: float = 1e-6
    maxiter: int = 20000
    energy_tol: float = 0.0
    energy0: float = 0.0
    window: int = 10

def pcg(matvec, precondition, b, stop: Stop, progress, dot=np.dot):
    """Preconditioned conjugate gradients (Hestenes-Stiefel; Saad, Iterative Methods, alg. 9.1) from x = 0,
    until ``stop`` (:class:`Stop`) says; ``progress(k, |r| / |b|)`` after every iteration.  Returns
    (x, iterations)."""
    x = b * 0.0
    r = b
    z = precondition(r)
    p = z
    rz = dot(r, z)
    b_norm = float(np.sqrt(dot(b, b)))
    k = 0
    if b_norm == 0.0:            # nothing to relax (an affine strain of a perfect lattice): x = 0
        return x, 0
    energy, drops = stop.energy0, []
    for k in range(1, stop.maxiter + 1):
        Ap = matvec(p)
        alpha = rz / dot(p, Ap)
        x = x + alpha * p
        r = r - alpha * Ap
        res = float(np.sqrt(dot(r, r))) / b_norm
        progress(k, res)
        drops.append(0.5 * float(alpha * rz))
        energy -= drops[-1]
        if res <= stop.rtol or (stop.energy_tol > 0
                                and _energy_error(drops, max(stop.window, k // 5)) <= stop.energy_tol * energy):
            break
        z = precondition(r)
        rz_new = dot(r, z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, k

def _energy_error(drops: list[float], window: int) -> float:
    """The energy still to lose after the last step: the last decrease continued geometrically at the mean
    rate q of the last ``window`` steps (sum of q^j, j >= 1), and at least the decrease over the last three
    steps (the error three steps ago by Strakos and Tichy's delayed estimate: guards a plateau that the
    rate misreads); infinite before the window is full or while the decreases do not fall."""
    if len(drops) <= window or drops[-1] <= 0 or drops[-1 - window] <= 0:
        return math.inf
    q = (drops[-1] / drops[-1 - window]) ** (1.0 / window)
    return max(drops[-1] * q / (1.0 - q), math.fsum(drops[-3:])) if q < 1 else math.inf
