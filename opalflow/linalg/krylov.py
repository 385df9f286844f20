"""Conjugate gradients with a stop on the residual or on the estimated energy error.

The solver of :mod:`opalflow.bpm.static` (the static method) and :mod:`opalflow.bpm.quasistatic` (the
quasi-static method's iterative re-solves); nothing here knows a bond network: operators and preconditioners
are functions of a vector.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opalflow.jit import njit
from opalflow.linalg.direct import in_parts


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

def pcg(matvec, precondition, b, stop: Stop, progress, dot=np.dot, threads: int = 1):
    """Preconditioned conjugate gradients (Hestenes-Stiefel; Saad, Iterative Methods, alg. 9.1) from x = 0,
    until ``stop`` (:class:`Stop`) says; ``progress(k, |r| / |b|)`` after every iteration.  Returns
    (x, iterations).  On numpy vectors of :data:`VECTOR_MIN` entries or more the updates and dot products are
    :class:`_Vectors`' fused passes on ``threads`` threads (smaller ones and other arrays, JAX's: ``dot`` and
    array expressions)."""
    fused = (_Vectors(len(b), threads) if isinstance(b, np.ndarray) and b.dtype == np.float64
             and len(b) >= VECTOR_MIN else None)
    dot = fused.dot if fused else dot
    x = b * 0.0
    r = b.copy() if fused else b
    z = precondition(r)
    p = z.copy() if fused else z
    rz = dot(r, z)
    b_norm = float(np.sqrt(dot(b, b)))
    k = 0
    if b_norm == 0.0:            # nothing to relax (an affine strain of a perfect lattice): x = 0
        return x, 0
    energy, drops = stop.energy0, []
    for k in range(1, stop.maxiter + 1):
        Ap = matvec(p)
        alpha = rz / dot(p, Ap)
        if fused:
            rr = fused.step(x, r, p, Ap, alpha)
        else:
            x = x + alpha * p
            r = r - alpha * Ap
            rr = dot(r, r)
        res = float(np.sqrt(rr)) / b_norm
        progress(k, res)
        drops.append(0.5 * float(alpha * rz))
        energy -= drops[-1]
        if res <= stop.rtol or (stop.energy_tol > 0
                                and _energy_error(drops, max(stop.window, k // 5)) <= stop.energy_tol * energy):
            break
        z = precondition(r)
        rz_new = dot(r, z)
        if fused:
            fused.direction(p, z, rz_new / rz)
        else:
            p = z + (rz_new / rz) * p
        rz = rz_new
    return x, k


#: :func:`pcg` fuses its vector work from this many unknowns (:class:`_Vectors`) ...
VECTOR_MIN = 200_000
#: ... in this many shares (a fixed number: the same sums, and digits, on any number of threads)
VECTOR_SHARES = 8


class _Vectors:
    """CG's vector work on numpy vectors of length ``n``, fused (numba: each update one pass, where numpy's
    expressions make two temporaries and read them back) and by :data:`VECTOR_SHARES` shares on ``threads``
    threads, the shares' partial sums added in order: x += alpha p and r -= alpha Ap with r . r in one pass
    (:meth:`step`), p = z + beta p in place (:meth:`direction`), dot products (:meth:`dot`).  Measured at the
    paper's sample (9.7 M unknowns, two threads; bench/results/paper_scale.json ``kernels``): an iteration's
    vector work 123 ms by numpy's expressions and BLAS's dot on one thread, 39 ms fused."""

    def __init__(self, n: int, threads: int):
        self.at = np.linspace(0, n, VECTOR_SHARES + 1).astype(np.int64)
        self.threads = threads

    def _sum(self, kernel, *args) -> float:
        sums = np.zeros(VECTOR_SHARES)

        def share(k: int) -> None:
            sums[k] = kernel(*args, self.at[k], self.at[k + 1])
        in_parts(share, VECTOR_SHARES, self.threads)
        return float(sums.sum())

    def dot(self, a: np.ndarray, b: np.ndarray) -> float:
        return self._sum(_dot, a, b)

    def step(self, x, r, p, Ap, alpha: float) -> float:
        return self._sum(_step, x, r, p, Ap, float(alpha))

    def direction(self, p, z, beta: float) -> None:
        self._sum(_direction, p, z, float(beta))


@njit(cache=True, nogil=True)
def _dot(a, b, first, last):
    s = 0.0
    for k in range(first, last):
        s += a[k] * b[k]
    return s


@njit(cache=True, nogil=True)
def _step(x, r, p, Ap, alpha, first, last):
    s = 0.0
    for k in range(first, last):
        x[k] += alpha * p[k]
        r[k] -= alpha * Ap[k]
        s += r[k] * r[k]
    return s


@njit(cache=True, nogil=True)
def _direction(p, z, beta, first, last):
    for k in range(first, last):
        p[k] = z[k] + beta * p[k]
    return 0.0


def _energy_error(drops: list[float], window: int) -> float:
    """The energy still to lose after the last step: the last decrease continued geometrically at the mean
    rate q of the last ``window`` steps (sum of q^j, j >= 1), and at least the decrease over the last three
    steps (the error three steps ago by Strakos and Tichy's delayed estimate: guards a plateau that the
    rate misreads); infinite before the window is full or while the decreases do not fall."""
    if len(drops) <= window or drops[-1] <= 0 or drops[-1 - window] <= 0:
        return math.inf
    q = (drops[-1] / drops[-1 - window]) ** (1.0 / window)
    return max(drops[-1] * q / (1.0 - q), math.fsum(drops[-3:])) if q < 1 else math.inf
