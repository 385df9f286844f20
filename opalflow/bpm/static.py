"""Static elastic response of a bonded-particle sample: one linear solve instead of a dynamic run.

Below the first broken bond the sample is a linear elastic frame with stiffness K (the bonds linearised
from LAMMPS's BondBPMRotational, :mod:`opalflow.bpm.stiffness`; contacts carry no load at the reference
state).  The compression test of the dynamic pipeline becomes, with the same sample and groups:

- the substrate (``substrate`` group, not integrated in LAMMPS) is fixed: all 6 dofs zero;
- the top particle layer (centres within 3/4 d of the top surface, as the dynamic run's ``top`` group)
  is pushed down by delta = strain x H along z; its x, y and rotations are free (a frictionless plate);
- the sides are periodic (bonds across the boundary, as built) or open;
- everything else is free: K_ff u_f = -K_fp u_p.

The stress is the top layer's reaction force over the area, the strain delta / H: E is the dynamic
run's ``youngs_modulus_specimen_GPa`` at zero loading rate.  Particle stresses are eq. 21 of Dosta et al.
with the bond forces of the solution.

Solvers (measured in bench/bench_static.py):

- ``amg``: K assembled as a sparse matrix (12 x 12 per bond), smoothed-aggregation AMG (pyamg) with the
  six rigid-body modes as near-null space, as the preconditioner of conjugate gradients;
- ``cg``: matrix-free conjugate gradients with a 6 x 6 block-Jacobi preconditioner (numpy);
- ``cg-jax``: the same, the operator jit-compiled by JAX (runs on a GPU where JAX has one).
"""
from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass, field

import numpy as np

from opalflow.bpm.spec import STATIC_SOLVERS as SOLVERS
from opalflow.bpm.stiffness import BondNetwork
from opalflow.spec import InputError


class LooseParticlesError(InputError):
    """Particles with no bond path to the substrate: the stiffness matrix is singular."""


@dataclass
class StaticResult:
    """The solution of one loading: displacements and rotations (N, 3), the reaction, the solve's cost."""

    u: np.ndarray
    theta: np.ndarray
    strain: float
    stress_MPa: float
    modulus_MPa: float
    iterations: int
    residual: float
    seconds: float
    setup_seconds: float
    peak_memory_MiB: float
    solver: str
    history: list[float] = field(default_factory=list)
    loose: int = 0


def bond_blocks(net: BondNetwork) -> np.ndarray:
    """The (M, 12, 12) stiffness block of each bond, dofs (u_i, theta_i, u_j, theta_j) (module
    opalflow.bpm.stiffness gives the forces this matrix reproduces)."""
    n, L = net.n, net.L
    nn = n[:, :, None] * n[:, None, :]
    P = np.eye(3)[None] - nn
    N = np.zeros((len(L), 3, 3))
    N[:, 0, 1], N[:, 0, 2], N[:, 1, 2] = -n[:, 2], n[:, 1], -n[:, 0]
    N[:, 1, 0], N[:, 2, 0], N[:, 2, 1] = n[:, 2], -n[:, 1], n[:, 0]
    A = net.a_r[:, None, None] * nn + net.a_s[:, None, None] * P
    C = (0.5 * net.a_s * L)[:, None, None] * N
    R = (0.25 * net.a_s * L**2)[:, None, None] * P
    B = net.bend[:, None, None] * P + net.twist[:, None, None] * nn
    rows = [[A, C, -A, C], [-C, R + B, C, R - B], [-A, -C, A, -C], [-C, R - B, C, R + B]]
    return np.concatenate([np.concatenate(r, axis=2) for r in rows], axis=1)


def assemble(net: BondNetwork):
    """K as a scipy CSR matrix (6 N x 6 N)."""
    import scipy.sparse as sp

    blocks = bond_blocks(net)
    dof = lambda p: (6 * p[:, None] + np.arange(6)[None]).reshape(-1, 6)  # noqa: E731
    idx = np.concatenate([dof(net.i), dof(net.j)], axis=1)               # (M, 12)
    rows = np.broadcast_to(idx[:, :, None], blocks.shape).ravel()
    cols = np.broadcast_to(idx[:, None, :], blocks.shape).ravel()
    size = 6 * net.n_particles
    return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(size, size))


def loose_particles(net: BondNetwork, anchored: np.ndarray) -> np.ndarray:
    """Particles with no bond path to an ``anchored`` one (a floating particle or cluster)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = net.n_particles
    graph = sp.coo_matrix((np.ones(len(net.i)), (net.i, net.j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    held = np.unique(label[anchored])
    return ~np.isin(label, held)


def rigid_body_modes(positions: np.ndarray) -> np.ndarray:
    """The six rigid-body modes (6 N, 6): three translations, three rotations about the centroid."""
    x = positions - positions.mean(axis=0)
    modes = np.zeros((len(x), 6, 6))
    for k in range(3):
        modes[:, k, k] = 1.0
        w = np.eye(3)[k]
        modes[:, :3, 3 + k] = np.cross(w, x)
        modes[:, 3 + k, 3 + k] = 1.0
    return modes.reshape(-1, 6)


def solve_compression(net: BondNetwork, positions: np.ndarray, fixed: np.ndarray, top: np.ndarray,
                      height: float, area: float, *, strain: float = 1e-4, solver: str = "amg",
                      rtol: float = 1e-8, maxiter: int = 20000, drop_loose: bool = False, say=print) -> StaticResult:
    """Uniaxial compression by a prescribed top-layer displacement (see the module docstring).

    ``fixed``: the substrate; ``top``: the top layer (both boolean over particles).  The strain is
    small and the answer linear in it; the stress is reported for ``strain``.  Particles with no bond path
    to the substrate make K singular: refused, or with ``drop_loose`` held still (they carry nothing).
    """
    if solver not in SOLVERS:
        raise InputError(f"compression.solver = {solver!r}: must be one of {', '.join(SOLVERS)}")
    loose = loose_particles(net, fixed)
    if loose.any() and not drop_loose:
        raise LooseParticlesError(f"structure: {int(loose.sum())} particles have no bond path to the substrate "
                                  "(a floating particle or cluster makes the static problem singular); "
                                  "compression.drop_loose = true leaves them out")
    if loose.any():
        say(f"static solve: {int(loose.sum())} loose particles (no bond path to the substrate) left out")
    t0 = time.perf_counter()
    n = net.n_particles
    prescribed = np.zeros((n, 6), bool)
    prescribed[fixed | loose] = True
    prescribed[top & ~fixed & ~loose, 2] = True
    x_p = np.zeros((n, 6))
    delta = strain * height
    x_p[top & ~fixed & ~loose, 2] = -delta
    free = ~prescribed.ravel()
    rhs = -net.matvec(x_p.ravel())[free]
    history: list[float] = []
    b_norm = float(np.linalg.norm(rhs))
    start = time.perf_counter()

    def progress(k: int, r: float) -> None:
        history.append(r)
        if k % 100 == 0 and k:
            rate = k / (time.perf_counter() - start)
            # CG's residual falls about geometrically: iterations left from the recent rate of decrease
            left = ""
            if len(history) > 50 and history[-50] > r > 0:
                per_it = math.log(history[-50] / r) / 50
                left = f", ~{max(0.0, math.log(r / rtol) / per_it / rate):.0f} s left"
            say(f"static solve: iteration {k}, relative residual {r:.2e} (target {rtol:g}), {rate:.1f} it/s{left}")

    run = {"amg": _solve_amg, "cg": _solve_cg, "cg-jax": _solve_cg_jax}[solver]
    args = (net, free, rhs, positions) if solver == "amg" else (net, free, rhs)
    x_f, iterations, residual, setup = run(*args, rtol, maxiter, progress)
    x = x_p.ravel().copy()
    x[free] = x_f
    x = x.reshape(n, 6)
    reaction = net.matvec(x.ravel()).reshape(n, 6)           # K x: the force the supports apply
    force_top = -float(np.sum(reaction[top & ~fixed & ~loose, 2]))    # compressive, > 0
    stress = force_top / area
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    true_res = float(np.linalg.norm(net.matvec(x.ravel())[free])) / max(b_norm, 1e-300)
    return StaticResult(u=x[:, :3], theta=x[:, 3:], strain=strain, stress_MPa=stress, modulus_MPa=stress / strain,
                        iterations=iterations, residual=true_res if residual is None else max(residual, true_res),
                        seconds=seconds, setup_seconds=setup, peak_memory_MiB=peak, solver=solver, history=history,
                        loose=int(loose.sum()))


def _solve_amg(net, free, rhs, positions, rtol, maxiter, progress):
    import pyamg

    t = time.perf_counter()
    K = assemble(net)[free][:, free].tocsr()
    B = rigid_body_modes(positions)[free]
    ml = pyamg.smoothed_aggregation_solver(K, B=B, strength=("symmetric", {"theta": 0.0}), max_coarse=500,
                                           smooth=("jacobi", {"omega": 4.0 / 3.0}))
    setup = time.perf_counter() - t
    residuals: list[float] = []
    b_norm = float(np.linalg.norm(rhs))

    def callback(xk):
        r = float(np.linalg.norm(rhs - K @ xk)) / b_norm
        residuals.append(r)
        progress(len(residuals), r)

    x = ml.solve(rhs, tol=rtol, accel="cg", maxiter=maxiter, callback=callback)
    return x, len(residuals), residuals[-1] if residuals else None, setup


def pcg(matvec, precondition, b, rtol: float, maxiter: int, progress, dot=np.dot):
    """Preconditioned conjugate gradients (Hestenes-Stiefel; Saad, Iterative Methods, alg. 9.1) from x = 0,
    until |r| <= rtol |b|; ``progress(k, |r| / |b|)`` after every iteration.  Returns (x, iterations)."""
    x = b * 0.0
    r = b
    z = precondition(r)
    p = z
    rz = dot(r, z)
    b_norm = float(np.sqrt(dot(b, b)))
    k = 0
    for k in range(1, maxiter + 1):
        Ap = matvec(p)
        alpha = rz / dot(p, Ap)
        x = x + alpha * p
        r = r - alpha * Ap
        res = float(np.sqrt(dot(r, r))) / b_norm
        progress(k, res)
        if res <= rtol:
            break
        z = precondition(r)
        rz_new = dot(r, z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, k


def _block_jacobi(net: BondNetwork, free: np.ndarray) -> np.ndarray:
    """Inverses of the 6 x 6 diagonal blocks of K on the free dofs (prescribed ones: identity)."""
    n = net.n_particles
    blocks = np.zeros((n, 6, 6))
    bb = bond_blocks(net)
    np.add.at(blocks, net.i, bb[:, :6, :6])
    np.add.at(blocks, net.j, bb[:, 6:, 6:])
    mask = free.reshape(n, 6)
    blocks = np.where(mask[:, :, None] & mask[:, None, :], blocks, 0.0)
    blocks[:, np.arange(6), np.arange(6)] += ~mask
    return np.linalg.inv(blocks)


def _solve_cg(net, free, rhs, rtol, maxiter, progress):
    """Matrix-free PCG in numpy with the 6 x 6 block-Jacobi preconditioner."""
    t = time.perf_counter()
    n = net.n_particles
    inv = _block_jacobi(net, free)
    full = np.zeros(6 * n)

    def matvec(v):
        full[free] = v
        return net.matvec(full)[free]

    def precondition(v):
        full[free] = v
        return np.einsum("nij,nj->ni", inv, full.reshape(n, 6)).ravel()[free]

    setup = time.perf_counter() - t
    x, iterations = pcg(matvec, precondition, rhs, rtol, maxiter, progress)
    return x, iterations, None, setup


def _solve_cg_jax(net, free, rhs, rtol, maxiter, progress):
    """The same PCG with the operator and preconditioner jit-compiled by JAX (float64; a GPU where JAX
    has one)."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    t = time.perf_counter()
    n = net.n_particles
    inv = jnp.asarray(_block_jacobi(net, free))
    i, j, nv, L = jnp.asarray(net.i), jnp.asarray(net.j), jnp.asarray(net.n), jnp.asarray(net.L)
    a_r, a_s = jnp.asarray(net.a_r)[:, None], jnp.asarray(net.a_s)[:, None]
    bend, twist = jnp.asarray(net.bend)[:, None], jnp.asarray(net.twist)[:, None]
    half = 0.5 * a_s * L[:, None]
    free_idx = jnp.asarray(np.flatnonzero(free))
    seg = jax.ops.segment_sum

    def full(v):
        return jnp.zeros(6 * n).at[free_idx].set(v).reshape(n, 6)

    @jax.jit
    def matvec(v):
        x = full(v)
        u, th = x[:, :3], x[:, 3:]
        du, st, dt = u[i] - u[j], th[i] + th[j], th[i] - th[j]
        F = (a_r - a_s) * jnp.sum(nv * du, 1, keepdims=True) * nv + a_s * du + half * jnp.cross(nv, st)
        Ts = half * jnp.cross(nv, du) - 0.5 * half * L[:, None] * (st - jnp.sum(nv * st, 1, keepdims=True) * nv)
        n_dt = jnp.sum(nv * dt, 1, keepdims=True) * nv
        Bd = bend * (dt - n_dt) + twist * n_dt
        f = seg(F, j, n) - seg(F, i, n)
        tau = seg(Ts - Bd, i, n) + seg(Ts + Bd, j, n)
        return -jnp.concatenate([f, tau], 1).ravel()[free_idx]

    @jax.jit
    def precondition(v):
        return jnp.einsum("nij,nj->ni", inv, full(v)).ravel()[free_idx]

    b = jnp.asarray(rhs)
    matvec(b).block_until_ready()
    precondition(b).block_until_ready()
    setup = time.perf_counter() - t
    x, iterations = pcg(matvec, precondition, b, rtol, maxiter, progress, dot=jnp.dot)
    return np.asarray(x), iterations, None, setup
