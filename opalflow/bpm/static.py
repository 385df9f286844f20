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

Solvers (measured in bench/bench_static.py; the iterative ones stop on CG's energy error, :class:`opalflow.linalg.krylov.Stop`):

- ``auto`` (default): ``direct`` up to DIRECT_MAX_DOFS dofs, ``amg`` up to AMG_MAX_BONDS bonds,
  ``block-amg`` above;
- ``direct``: K factorised by MKL PARDISO (:class:`opalflow.linalg.direct.Factor`), one pair of triangular solves;
- ``amg``: K assembled in 6 x 6 blocks, smoothed-aggregation AMG (pyamg) aggregating particles with the
  six rigid-body modes as near-null space, as the preconditioner of conjugate gradients;
- ``block-amg``: matrix-free CG (the numba bond operator) preconditioned by AMG on the translational part of
  K only (a quarter of its entries) and block Jacobi on the rotations: what fits the paper's sample;
- ``cg``: matrix-free conjugate gradients with a 6 x 6 block-Jacobi preconditioner (the numba operator);
- ``cg-jax``: the same, the operator jit-compiled by JAX (runs on a GPU where JAX has one).
"""
from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass, field, replace

import numpy as np

from opalflow.analysis.elasticity import VOIGT
from opalflow.bpm.loading import Supports
from opalflow.bpm.spec import STATIC_SOLVERS as SOLVERS
from opalflow.bpm.stiffness import BondNetwork, bond_force
from opalflow.jit import njit
from opalflow.linalg.direct import Factor, in_parts, kernel_threads, solver_threads
from opalflow.linalg.krylov import Stop, pcg
from opalflow.linalg.multigrid import amg_preconditioner
from opalflow.spec import InputError


#: ``solver = "auto"``: the direct factor up to this many dofs, the assembled AMG up to AMG_MAX_BONDS bonds,
#: block-amg above (10.8 GiB for the paper's 17.5 M bonds; at 226 k bonds 6.4 s against amg's 12 s);
#: bench/results/static_quickstart.json
DIRECT_MAX_DOFS = 100_000
AMG_MAX_BONDS = 200_000
#: :func:`block_layout` by numpy's sort up to this many bonds (the direct solver's sizes), numba's kernel above
LAYOUT_SORT_MAX_BONDS = 200_000
#: CG's energy stop (:class:`opalflow.linalg.krylov.Stop`) in static solves: E to 1e-7 of the exact (quickstart at d = 30 nm,
#: block-amg: 49 iterations and E within 3e-8 of the factor's, where the residual rule 1e-6 takes 70)
ENERGY_TOL = 1e-7


def auto_solver(n_particles: int, n_bonds: int) -> str:
    """``solver = "auto"``: the fastest design that fits at the network's size (measured, see above)."""
    if 6 * n_particles <= DIRECT_MAX_DOFS:
        return "direct"
    return "amg" if n_bonds <= AMG_MAX_BONDS else "block-amg"


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
    Kii, Kjj, Kij, Kji = pair_blocks(net)
    return np.concatenate([np.concatenate([Kii, Kij], axis=2), np.concatenate([Kji, Kjj], axis=2)], axis=1)


def assemble(net: BondNetwork):
    """K as a scipy CSR matrix (6 N x 6 N)."""
    return block_matrix(net)[0].tocsr()


def clusters(net: BondNetwork) -> np.ndarray:
    """The bonded cluster of each particle (connected components of the bond graph), labels 0, 1, ..."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = net.n_particles
    return connected_components(sp.coo_matrix((np.ones(len(net.i)), (net.i, net.j)), shape=(n, n)),
                                directed=False)[1]


def loose_particles(net: BondNetwork, anchored: np.ndarray) -> np.ndarray:
    """Particles with no bond path to an ``anchored`` one (a floating particle or cluster)."""
    label = clusters(net)
    return ~np.isin(label, np.unique(label[anchored]))


def loose_message(count: int) -> str:
    return (f"structure: {count} particles have no bond path to the substrate (a floating particle or cluster "
            "makes the static problem singular); compression.drop_loose = true leaves them out")


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


def solve_compression(net: BondNetwork, positions: np.ndarray, supports: Supports, *, strain: float = 1e-4,
                      solver: str = "auto", rtol: float = 1e-6, energy_tol: float = ENERGY_TOL, maxiter: int = 20000,
                      drop_loose: bool = False, say=print) -> StaticResult:
    """The sample under its loading's ``supports`` (:meth:`opalflow.bpm.loading.Loading.supports`: for the
    uniaxial tests the substrate held, the top layer moved in z and free sideways and in rotation, or glued:
    held in its other five degrees of freedom; strain and stress positive in the loading's sense).  The
    strain is small and the answer linear in it; the stress is reported for ``strain``.  E is taken from the
    elastic energy W of the solution, E = 2 W / (A H e^2) (Clapeyron: W = 1/2 F delta at equilibrium, A and H
    the loading's area and gauge length), which converges quadratically in the solution's error where the
    driven particles' reaction force converges linearly; CG stops (:class:`opalflow.linalg.krylov.Stop`) at relative residual
    ``rtol`` or when the estimated energy error is below ``energy_tol`` of W (0: the residual alone).
    Particles with no bond path to the anchored ones make K singular: refused, or with ``drop_loose`` held
    still (they carry nothing).
    """
    if solver not in SOLVERS:
        raise InputError(f"compression.solver = {solver!r}: must be one of {', '.join(SOLVERS)}")
    if solver == "auto":
        solver = auto_solver(net.n_particles, len(net.L))
    loose = loose_particles(net, supports.anchored)
    if loose.any() and not drop_loose:
        raise LooseParticlesError(loose_message(int(loose.sum())))
    if loose.any():
        say(f"static solve: {int(loose.sum())} loose particles (no bond path to the substrate) left out")
    t0 = time.perf_counter()
    n = net.n_particles
    held = supports.without(loose)
    x_p = strain * held.drive
    free = ~held.held.ravel()
    prepared = Prepared(solver, net, free, positions)
    setup = prepared.setup_seconds
    if solver == "direct":
        say(f"static solve: factorised in {setup:.1f} s ({prepared.threads} threads)")
    K_xp = prepared.matvec(x_p.ravel())
    rhs = np.where(free, -K_xp, 0.0)
    stop = Stop(rtol, maxiter, energy_tol, 0.5 * float(x_p.ravel() @ K_xp))
    history: list[float] = []
    b_norm = float(np.linalg.norm(rhs))
    clock = {"first": 0.0, "said": 0.0}

    def progress(k: int, r: float) -> None:
        """A line at the first iteration (the set-up is done) and then every 10 s at most."""
        history.append(r)
        now = time.perf_counter()
        if k == 1:
            clock["first"] = clock["said"] = now
            say(f"static solve: set-up done after {now - t0:.1f} s; iteration 1, relative residual {r:.2e}")
            return
        if now - clock["said"] < 10 and k % 100:
            return
        clock["said"] = now
        rate = (k - 1) / max(now - clock["first"], 1e-9)
        # CG's residual falls about geometrically: iterations left from the recent rate of decrease
        left = ""
        back = min(200, k // 2)
        if back >= 5 and history[-back] > r > 0:
            per_it = math.log(history[-back] / r) / back
            left = f", ~{max(0.0, math.log(r / rtol) / per_it / rate):.0f} s left"
        energy = f" or energy error {energy_tol:g}" if energy_tol else ""
        say(f"static solve: iteration {k}, relative residual {r:.2e} (target {rtol:g}{energy}), {rate:.2f} it/s"
            f"{left}")

    x_f, iterations = prepared.solve(rhs, stop, progress)
    x = x_p.ravel() + np.where(free, x_f, 0.0)
    reaction = prepared.matvec(x)                 # K x: the force the supports apply, zero elsewhere
    # 2 W / (A H e^2), W = 1/2 x^T K x
    modulus = float(x @ reaction) / (supports.area_nm2 * supports.gauge_nm * strain ** 2)
    x = x.reshape(n, 6)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    true_res = float(np.linalg.norm(reaction[free])) / max(b_norm, 1e-300)
    return StaticResult(u=x[:, :3], theta=x[:, 3:], strain=strain, stress_MPa=modulus * strain, modulus_MPa=modulus,
                        iterations=iterations, residual=true_res,
                        seconds=seconds, setup_seconds=setup, peak_memory_MiB=peak, solver=solver, history=history,
                        loose=int(loose.sum()))


@dataclass
class TensorResult:
    """The 6 x 6 stiffness tensor (GPa, Voigt order xx yy zz yz xz xy) of a sample periodic in x, y, z."""

    C_GPa: np.ndarray
    iterations: list[int]
    residual: float
    seconds: float
    peak_memory_MiB: float
    solver: str
    loose: int = 0


def solve_tensor(net: BondNetwork, positions: np.ndarray, volume: float, *, solver: str = "auto",
                 rtol: float = 1e-8, maxiter: int = 20000, drop_loose: bool = False, say=print) -> TensorResult:
    """The stiffness tensor of a network periodic in all three directions, from six loadings.

    A unit macroscopic strain E (Voigt column k) stretches every bond by E R_b through the periodic
    images (R_b the bond vector, minimum image); the particles then relax: K w = g(E), g the forces of the
    affine stretch, with one particle's translations held (the three translations are the only
    zero-energy modes of a periodic network).  The stress is the bond virial
    sigma = 1/V sum_b R_b (x) F_b (symmetrised), column k of C.  Loose particles (not in the largest
    bonded cluster) are refused, or held still with ``drop_loose``.
    """
    if solver not in SOLVERS:
        raise InputError(f"compression.solver = {solver!r}: must be one of {', '.join(SOLVERS)}")
    if solver == "auto":
        solver = auto_solver(net.n_particles, len(net.L))
    t0 = time.perf_counter()
    n = net.n_particles
    label = clusters(net)
    loose = label != np.argmax(np.bincount(label))
    if loose.any() and not drop_loose:
        raise LooseParticlesError(f"structure: {int(loose.sum())} particles are not in the largest bonded "
                                  "cluster (the static problem is singular); compression.drop_loose = true "
                                  "leaves them out")
    prescribed = np.zeros((n, 6), bool)
    prescribed[loose] = True
    prescribed[int(np.flatnonzero(~loose)[0]), :3] = True
    free = ~prescribed.ravel()
    R = net.n * net.L[:, None]
    zero = np.zeros((n, 3))
    C = np.zeros((6, 6))
    iterations, worst = [], 0.0
    prepared = Prepared(solver, net, free, positions)      # one set-up (matrix, AMG or factor), six loadings
    for k, (a, b) in enumerate(VOIGT):
        E = np.zeros((3, 3))
        E[a, b] = E[b, a] = 1.0 if a == b else 0.5
        stretch = R @ E
        f, tau = net.forces(zero, zero, stretch)
        rhs = np.where(free, np.hstack([f, tau]).ravel(), 0.0)
        say(f"static tensor: loading {k + 1} of 6 ({'xx yy zz yz xz xy'.split()[k]})")
        x_f, its = prepared.solve(rhs, Stop(rtol, maxiter), lambda i, r: None)
        x = np.where(free, x_f, 0.0).reshape(n, 6)
        f2, tau2 = net.forces(x[:, :3], x[:, 3:], stretch)
        worst = max(worst, float(np.linalg.norm(np.hstack([f2, tau2]).ravel()[free])) / max(np.linalg.norm(rhs), 1e-300))
        F = net.bond_forces(x[:, :3], x[:, 3:], stretch)
        sigma = R.T @ F / volume
        sigma = 0.5 * (sigma + sigma.T)
        C[:, k] = [sigma[p, q] for p, q in VOIGT]
        iterations.append(its)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return TensorResult(C_GPa=C / 1e3, iterations=iterations, residual=worst, seconds=time.perf_counter() - t0,
                        peak_memory_MiB=peak, solver=solver, loose=int(loose.sum()))


class Prepared:
    """``solver`` set up once for the network with free dofs ``free`` (bool (6 N,)): the assembled matrix,
    the AMG hierarchy or the factor, reused by every loading of the sample (the stiffness tensor's six).
    ``solve(b, stop, progress)`` -> (x, iterations) for ``b`` full, zero on prescribed dofs; both run
    under the BLAS threads that suit the solver (:func:`solver_threads`), opalflow's own kernels (the bond
    operator, the V-cycle's residuals) on :func:`kernel_threads` (taken before the limit).  ``matvec(x)``: K x
    on all dofs (the load vector of prescribed displacements, the reaction), from the direct solver's
    assembled K, else the bond operator (:meth:`BondNetwork.matvec`)."""

    def __init__(self, solver: str, net: BondNetwork, free: np.ndarray, positions: np.ndarray):
        from threadpoolctl import threadpool_limits

        t = time.perf_counter()
        self.threads, kernel = solver_threads(solver), kernel_threads()
        prepare = {"direct": _prepare_direct, "amg": _prepare_amg, "block-amg": _prepare_block_amg,
                   "cg": _prepare_cg, "cg-jax": _prepare_cg_jax}[solver]
        with threadpool_limits(limits=self.threads):
            self._solve, self.matvec = prepare(net, free, positions, kernel)
        self.setup_seconds = time.perf_counter() - t

    def solve(self, b: np.ndarray, stop: Stop, progress) -> tuple[np.ndarray, int]:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=self.threads):
            return self._solve(b, stop, progress)


def _prepare_direct(net, free, positions, threads=1):
    """K assembled and factorised on its free dofs (:class:`opalflow.linalg.direct.Factor`); each solve one pair
    of triangular solves: no iterations, a residual at round-off (checked by the caller).  K's own products
    serve for the load vector and the reaction: a small sample's static solve calls no numba kernel (numba's
    import and first kernel load, 0.5 s, were a third of the whole command at d = 60 nm)."""
    K = block_matrix(net)[0]
    factor = Factor(K, free)
    return (lambda b, stop, progress: (factor.solve(b), 1)), (lambda x: K @ x)


def _prepare_amg(net, free, positions, threads=1):
    """K assembled (:func:`particle_amg`'s), one V-cycle of its AMG per CG iteration."""
    K, vcycle = particle_amg(net, free, positions, threads)
    return (lambda b, stop, progress: pcg(lambda v: K @ v, vcycle, b, stop, progress, threads=threads)), net.matvec


def particle_amg(net: BondNetwork, free: np.ndarray, positions: np.ndarray, threads: int = 1):
    """(K, V-cycle): K on all dofs in 6 x 6 blocks, prescribed dofs decoupled (:func:`block_matrix`), and
    smoothed-aggregation AMG that aggregates particles (the blocks), the six rigid-body modes (zero on
    prescribed dofs) as near-null space (:func:`opalflow.linalg.multigrid.amg_preconditioner`)."""
    K = block_matrix(net, free)[0]
    K.sum_duplicates()
    B = np.where(free[:, None], rigid_body_modes(positions), 0.0)
    return K, amg_preconditioner(K, B, threads)


def _bond_parts(net: BondNetwork, sel: slice):
    """A = a_r n n^T + a_s P, C = a_s L / 2 [n]x, R = a_s L^2 / 4 P and B = kb P + kt n n^T of the bonds in
    ``sel`` (each (m, 3, 3)): the pieces of the 12 x 12 bond matrix (K_uu's A alone: :func:`_translation_blocks`,
    the rotational diagonal R + B alone: :func:`_rotation_diagonal`)."""
    n, L = net.n[sel], net.L[sel]
    nn = n[:, :, None] * n[:, None, :]
    P = np.eye(3)[None] - nn
    a_s = net.a_s[sel][:, None, None]
    R = (0.25 * L**2)[:, None, None] * a_s * P
    B = net.bend[sel][:, None, None] * P + net.twist[sel][:, None, None] * nn
    A = net.a_r[sel][:, None, None] * nn + a_s * P
    N = np.zeros((len(L), 3, 3))
    N[:, 0, 1], N[:, 0, 2], N[:, 1, 2] = -n[:, 2], n[:, 1], -n[:, 0]
    N[:, 1, 0], N[:, 2, 0], N[:, 2, 1] = n[:, 2], -n[:, 1], n[:, 0]
    C = 0.5 * a_s * L[:, None, None] * N
    return A, C, R, B


def diagonal_blocks(net: BondNetwork, chunk: int = 1_000_000) -> np.ndarray:
    """The diagonal blocks of K, (N, 6, 6): K_ii and K_jj of :func:`pair_blocks` summed over each particle's
    bonds, in chunks of bonds to bound the memory."""
    out = np.zeros((net.n_particles, 6, 6))
    for start in range(0, len(net.L), chunk):
        sel = slice(start, start + chunk)
        Kii, Kjj = pair_blocks(net, sel)[:2]
        _add_diagonal(out, net.i[sel], net.j[sel], Kii, Kjj)
    return out


def rotation_diagonal(net: BondNetwork) -> np.ndarray:
    """The rotational 3 x 3 parts of K's diagonal blocks, (N, 3, 3): each bond's R + B of :func:`_bond_parts`
    to both its particles (:func:`_rotation_diagonal`, one pass: 0.3 s at the paper's 17.5 M bonds where the
    chunks of numpy blocks took 8 s; the same blocks as :func:`diagonal_blocks`', tests/test_stiffness.py)."""
    out = np.zeros((net.n_particles, 3, 3))
    _rotation_diagonal(net.i, net.j, net.n, net.L, net.a_s, net.bend, net.twist, out)
    return out


@njit(cache=True, nogil=True)
def _rotation_diagonal(i, j, nv, L, a_s, bend, twist, diag):
    """diag[p] += R + B = (a_s L^2 / 4 + kb) P + kt n n^T for both particles p of each bond."""
    for b in range(len(i)):
        p, q = i[b], j[b]
        s = 0.25 * L[b] * L[b] * a_s[b] + bend[b]
        for r in range(3):
            for c in range(3):
                nn = nv[b, r] * nv[b, c]
                v = s * ((1.0 if r == c else 0.0) - nn) + twist[b] * nn
                diag[p, r, c] += v
                diag[q, r, c] += v


def _add_diagonal(out: np.ndarray, i: np.ndarray, j: np.ndarray, Kii: np.ndarray, Kjj: np.ndarray) -> None:
    """Add each bond's K_ii to particle i's diagonal block and K_jj to j's (``out`` (N, k, k))."""
    n, k = out.shape[0], out.shape[1]
    for a in range(k):
        for b in range(k):
            out[:, a, b] += np.bincount(i, Kii[:, a, b], n) + np.bincount(j, Kjj[:, a, b], n)


def _jacobi_inverse(blocks: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Inverses of diagonal blocks on the free dofs (prescribed ones: identity), (N, k, k)."""
    k = blocks.shape[1]
    mask = free.reshape(-1, k)
    blocks = np.where(mask[:, :, None] & mask[:, None, :], blocks, 0.0)
    blocks[:, np.arange(k), np.arange(k)] += ~mask
    return np.linalg.inv(blocks)


def block_layout(net: BondNetwork):
    """Where the blocks of K lie in a block sparse row (BSR) matrix of one block per particle pair:
    (indptr, indices, pos), ``pos`` the storage slot of each particle's diagonal block (first N), each bond's
    (i, j) block (next M) and its (j, i) block (last M), rows and columns in order (a canonical matrix; two
    bonds between one pair in bond order).  Up to LAYOUT_SORT_MAX_BONDS bonds numpy's stable sort of the
    entries (0.01 s at d = 60 nm: a small sample's direct solve then calls no numba kernel, whose import and
    first load cost 0.5 s, :func:`_prepare_direct`); above, :func:`_layout`'s counting sort by row and
    insertion sort of each row's few columns (0.8 s at the paper's 17.5 M bonds where the sort took 11.7).
    The two give the same arrays (tests/test_stiffness.py)."""
    n = net.n_particles
    if len(net.i) > LAYOUT_SORT_MAX_BONDS:
        return _layout(n, net.i, net.j)
    diag = np.arange(n, dtype=np.int64)
    rows = np.concatenate([diag, net.i, net.j])
    cols = np.concatenate([diag, net.j, net.i])
    order = np.argsort(rows * n + cols, kind="stable")
    pos = np.empty(len(order), np.int64)
    pos[order] = np.arange(len(order))
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
    return indptr, cols[order].astype(np.int32), pos


@njit(cache=True, nogil=True)
def _layout(n, i, j):
    m = len(i)
    indptr = np.zeros(n + 1, np.int64)
    for b in range(m):
        indptr[i[b] + 1] += 1
        indptr[j[b] + 1] += 1
    for r in range(n):
        indptr[r + 1] += indptr[r] + 1            # (+1: the diagonal block)
    cols = np.empty(n + 2 * m, np.int32)
    entry = np.empty(n + 2 * m, np.int64)
    fill = indptr[:-1].copy()
    for r in range(n):
        cols[fill[r]], entry[fill[r]] = r, r
        fill[r] += 1
    for b in range(m):
        for row, col, e in ((i[b], j[b], n + b), (j[b], i[b], n + m + b)):
            cols[fill[row]], entry[fill[row]] = col, e
            fill[row] += 1
    pos = np.empty(n + 2 * m, np.int64)
    for r in range(n):
        for s in range(indptr[r] + 1, indptr[r + 1]):      # insertion sort by column (stable)
            c, e, k = cols[s], entry[s], s
            while k > indptr[r] and cols[k - 1] > c:
                cols[k], entry[k] = cols[k - 1], entry[k - 1]
                k -= 1
            cols[k], entry[k] = c, e
        for s in range(indptr[r], indptr[r + 1]):
            pos[entry[s]] = s
    return indptr, cols, pos


@njit(cache=True, nogil=True)
def _translation_blocks(i, j, nv, a_r, a_s, fu, pos, data, diag):
    """K_uu's blocks straight into their slots (``pos`` of :func:`block_layout`): each bond's A = a_r n n^T +
    a_s P (:func:`_bond_parts`) to both diagonal blocks, -A (masked by ``fu``) off the diagonal.  One pass
    (0.3 s at 1.8 M bonds where the chunks of numpy blocks took 1.6)."""
    n, m = diag.shape[0], len(i)
    for b in range(m):
        p, q = i[b], j[b]
        for r in range(3):
            for c in range(3):
                nn = nv[b, r] * nv[b, c]
                v = a_r[b] * nn + a_s[b] * ((1.0 if r == c else 0.0) - nn)
                diag[p, r, c] += v
                diag[q, r, c] += v
                data[pos[n + b], r, c] = -v * fu[p, r] * fu[q, c]
                data[pos[n + m + b], r, c] = -v * fu[q, r] * fu[p, c]


def pair_blocks(net: BondNetwork, sel=slice(None)):
    """The blocks of the bonds in ``sel``: (K_ii, K_jj, K_ij, K_ji), each (m, 6, 6), the blocks of
    :func:`bond_blocks`."""
    A, C, R, B = _bond_parts(net, sel)
    RB, RmB = R + B, R - B
    two = lambda a, b, c, d: np.concatenate([np.concatenate([a, b], 2), np.concatenate([c, d], 2)], 1)  # noqa: E731
    return two(A, C, -C, RB), two(A, -C, C, RB), two(-A, C, C, RmB), two(-A, -C, -C, RmB)


def block_matrix(net: BondNetwork, free=None, *, part: str = "all", dtype=np.float64, chunk: int = 1_000_000,
                 sum_duplicates: bool = True):
    """K as a BSR matrix of 6 x 6 blocks (``part`` "translation": K_uu, 3 x 3 blocks, what the block-amg
    preconditioner needs), written straight into its slots (:func:`block_layout`; no
    coordinate list: the paper-scale memory is the blocks alone).  ``free`` (N, size) bool: the prescribed
    dofs are decoupled, their diagonal kept (K x = b with b zero there gives x zero there: the boundary
    conditions without slicing, the block structure intact for AMG and the factor).  ``sum_duplicates`` false
    keeps two elements between one pair in two blocks, where ``pos`` says (for edits in place)."""
    import scipy.sparse as sp

    n, m, size = net.n_particles, len(net.L), 6 if part == "all" else 3
    indptr, cols, pos = block_layout(net)
    data = np.zeros((n + 2 * m, size, size), dtype)
    diag = np.zeros((n, size, size))
    fu = None if free is None else free.reshape(n, size).astype(float)
    if part == "translation":          # (block-amg's K_uu, the paper's sample: one numba pass)
        _translation_blocks(net.i, net.j, net.n, net.a_r, net.a_s, np.ones((n, 3)) if fu is None else fu, pos,
                            data, diag)
    else:
        for start in range(0, m, chunk):
            sel = slice(start, min(start + chunk, m))
            i, j = net.i[sel], net.j[sel]
            Kii, Kjj, Kij, Kji = pair_blocks(net, sel)
            _add_diagonal(diag, i, j, Kii, Kjj)
            if fu is not None:
                Kij = Kij * fu[i][:, :, None] * fu[j][:, None, :]
                Kji = Kji * fu[j][:, :, None] * fu[i][:, None, :]
            data[pos[n + sel.start:n + sel.stop]] = Kij
            data[pos[n + m + sel.start:n + m + sel.stop]] = Kji
    if fu is not None:
        kept = diag[:, np.arange(size), np.arange(size)].copy()
        diag *= fu[:, :, None] * fu[:, None, :]
        # (a particle without bonds has nothing to keep: 1 there)
        diag[:, np.arange(size), np.arange(size)] += np.where(fu > 0, 0.0, np.where(kept != 0, kept, 1.0))
    data[pos[:n]] = diag
    K = sp.bsr_matrix((data, cols, indptr), shape=(size * n, size * n))
    if sum_duplicates:
        K.sum_duplicates()      # two bonds between one pair (periodic images of a small box, a bond and its contact)
    return K, pos


def _operator(net: BondNetwork, free: np.ndarray, use_jax: bool, threads: int = 1, chunk: int = 1 << 21):
    """v -> P K P v on full vectors (P: zero on prescribed dofs): :meth:`BondNetwork.matvec` (numba, one pass
    over the bonds: 28 ns a bond at 226 k bonds against JAX's 220 on this CPU; on ``threads`` threads) or
    jit-compiled JAX (float64, the GPU path).
    The JAX operator runs over the bonds ``chunk`` at a time (``lax.scan``; padding bonds have zero
    stiffness), so its temporaries stay small on the paper's 17.5 million bonds."""
    mask = free.astype(float)
    if not use_jax:
        return lambda v: mask * net.matvec(mask * v, threads), np.dot, np.asarray
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    n, m = net.n_particles, len(net.L)
    chunk = max(1, min(chunk, m))
    pad = (-m) % chunk

    def chunked(a, fill=0):
        a = np.concatenate([a, np.full((pad, *a.shape[1:]), fill, a.dtype)])
        return jnp.asarray(a.reshape(-1, chunk, *a.shape[1:]))

    unit = np.zeros((pad, 3))
    unit[:, 2] = 1.0
    bonds = (chunked(net.i), chunked(net.j), jnp.asarray(np.concatenate([net.n, unit]).reshape(-1, chunk, 3)),
             chunked(net.L, 1.0), chunked(net.a_r), chunked(net.a_s), chunked(net.bend), chunked(net.twist))
    jmask = jnp.asarray(mask)
    seg = jax.ops.segment_sum

    @jax.jit
    def matvec(v):
        x = (jmask * v).reshape(n, 6)
        u, th = x[:, :3], x[:, 3:]

        def step(acc, b):
            i, j, nv, L, a_r, a_s, bend, twist = b
            du, st, dt = u[i] - u[j], th[i] + th[j], th[i] - th[j]
            F = bond_force(jnp, nv, L, a_r, a_s, du, st)
            half, bend, twist = 0.5 * a_s[:, None] * L[:, None], bend[:, None], twist[:, None]
            Ts = half * jnp.cross(nv, du) - 0.5 * half * L[:, None] * (st - jnp.sum(nv * st, 1, keepdims=True) * nv)
            n_dt = jnp.sum(nv * dt, 1, keepdims=True) * nv
            Bd = bend * (dt - n_dt) + twist * n_dt
            f, tau = acc
            return (f + seg(F, j, n) - seg(F, i, n), tau + seg(Ts - Bd, i, n) + seg(Ts + Bd, j, n)), None

        (f, tau), _ = jax.lax.scan(step, (jnp.zeros((n, 3)), jnp.zeros((n, 3))), bonds)
        return -jmask * jnp.concatenate([f, tau], 1).ravel()

    return matvec, jnp.dot, jnp.asarray


def _prepare_cg(net, free, positions, threads=1, use_jax=False):
    """Matrix-free PCG with the 6 x 6 block-Jacobi preconditioner (the numba operator, or JAX's)."""
    n = net.n_particles
    matvec, dot, array = _operator(net, free, use_jax, threads)
    inv = array(_jacobi_inverse(diagonal_blocks(net), free))
    mask = array(free.astype(float))

    def precondition(v):          # numpy or JAX arrays alike: a batched 6 x 6 product
        return mask * (inv @ v.reshape(n, 6, 1)).ravel()

    if use_jax:
        import jax

        precondition = jax.jit(precondition)
    probe = array(np.zeros(free.size))
    matvec(probe)                 # compiled here (JAX): the set-up, not the first iteration
    precondition(probe)

    def solve(b, stop, progress):
        x, iterations = pcg(matvec, precondition, array(b), stop, progress, dot=dot, threads=threads)
        return np.asarray(x), iterations
    return solve, net.matvec


def _prepare_cg_jax(net, free, positions, threads=1):
    """The block-Jacobi PCG with the operator jit-compiled by JAX (float64; a GPU where JAX has one)."""
    return _prepare_cg(net, free, positions, use_jax=True)


def _prepare_block_amg(net, free, positions, threads=1):
    """Matrix-free PCG (the numba operator) preconditioned by :func:`block_amg_preconditioner`, both on
    ``threads`` threads."""
    matvec, dot, array = _operator(net, free, False, threads)
    precondition = block_amg_preconditioner(net, free, positions, threads)
    matvec(np.zeros(free.size))          # compiled here (or loaded from numba's cache): the set-up
    precondition(np.zeros(free.size))

    def solve(b, stop, progress):
        return pcg(matvec, precondition, np.asarray(b), stop, progress, threads=threads)
    return solve, net.matvec


def intact(net: BondNetwork, alive: np.ndarray | None) -> BondNetwork:
    """``net`` with the bonds ``alive`` holds false at zero stiffness (a copy of its coefficients where any is;
    ``net`` itself where none is, or ``alive`` is None)."""
    if alive is None or alive.all():
        return net
    return replace(net, a_r=net.a_r * alive, a_s=net.a_s * alive, bend=net.bend * alive,
                               twist=net.twist * alive)


def block_amg_preconditioner(net: BondNetwork, free: np.ndarray, positions: np.ndarray, threads: int = 1,
                             alive: np.ndarray | None = None):
    """v -> z: a symmetric block Gauss-Seidel sweep over the rotations, the translations and the rotations again,
    zero on prescribed dofs: the rotations by 3 x 3 block Jacobi (D_tt), the translations by one V-cycle of
    smoothed-aggregation AMG on K_uu (assembled as 3 x 3 blocks in float32, translations and rigid rotations as
    near-null space: the long waves that make K ill-conditioned are translational, and K_uu is a quarter of K,
    so the paper's sample fits in memory), coupled through K's products (the bond operator, on ``threads``
    threads):

        z_t = D_tt^-1 r_t;  z_u = V(r_u - K_ut z_t);  z_t += D_tt^-1 (r_t - K_tu z_u - K_tt z_t)

    (Saad, Iterative Methods, sec. 4.1: block SGS with the blocks in the order t, u, t; symmetric, as CG
    needs, for a symmetric V(.)).  The two products cost two bond passes a call; against V-cycle and block
    Jacobi side by side (the translation-rotation coupling left out): d = 30 nm static solve 65 -> 38
    iterations, the same time on one thread; the quasi-static re-solves there (paper's rule, 105 events)
    904 -> 464 iterations, events 195 -> 175 s.  ``alive`` (M,) bool: the bonds intact, read at every call (the
    quasi-static re-solves break bonds in it; the V-cycle and the diagonal stay those of the network at the
    start)."""
    n = net.n_particles
    mask = free.reshape(n, 6)
    start = intact(net, alive)
    Kuu = block_matrix(start, mask[:, :3], part="translation", dtype=np.float32)[0]
    Kuu.sum_duplicates()
    B = rigid_body_modes(positions).reshape(n, 6, 6)[:, :3, :].reshape(3 * n, 6).astype(Kuu.dtype)
    vcycle = amg_preconditioner(Kuu, B, threads)
    inv_rot = _jacobi_inverse(rotation_diagonal(start), mask[:, 3:].ravel())
    maskf = free.astype(float).reshape(n, 6)
    at = np.linspace(0, n, threads + 1).astype(np.int64)

    def K(z: np.ndarray, block: str) -> np.ndarray:
        return net.matvec(z.ravel(), threads, alive, block).reshape(n, 6)

    def each(kernel, *args) -> None:
        in_parts(lambda k: kernel(*args, at[k], at[k + 1]), threads)

    def precondition(r):
        r = np.asarray(r).reshape(n, 6)
        z, load = np.empty((n, 6)), np.empty(3 * n, np.float32)
        each(_rotations_first, inv_rot, r, maskf, z)
        each(_translations_load, r, K(z, "ut"), load)
        each(_translations_set, vcycle(load), maskf, z)
        each(_rotations_again, inv_rot, r, K(z, "t"), maskf, z)
        return z.ravel()
    return precondition


# block-amg's steps particle by particle (:func:`block_amg_preconditioner`; numpy's einsum, slices and masks took
# ~260 of a call's 1 339 ms at the paper's sample, now ~80 of 920), each over particles ``first`` .. ``last`` - 1


@njit(cache=True, nogil=True)
def _rotations_first(inv_rot, r, mask, z, first, last):
    """z_u = 0, z_t = D_tt^-1 r_t on the free dofs."""
    for p in range(first, last):
        for a in range(3):
            z[p, a] = 0.0
            acc = 0.0
            for c in range(3):
                acc += inv_rot[p, a, c] * r[p, 3 + c]
            z[p, 3 + a] = mask[p, 3 + a] * acc


@njit(cache=True, nogil=True)
def _translations_load(r, Kz, load, first, last):
    """The V-cycle's right-hand side r_u - (K z)_u, in its single precision."""
    for p in range(first, last):
        for a in range(3):
            load[3 * p + a] = r[p, a] - Kz[p, a]


@njit(cache=True, nogil=True)
def _translations_set(zu, mask, z, first, last):
    """z_u = the V-cycle's result on the free dofs."""
    for p in range(first, last):
        for a in range(3):
            z[p, a] = mask[p, a] * zu[3 * p + a]


@njit(cache=True, nogil=True)
def _rotations_again(inv_rot, r, Kz, mask, z, first, last):
    """z_t += D_tt^-1 (r_t - (K z)_t) on the free dofs."""
    for p in range(first, last):
        for a in range(3):
            acc = 0.0
            for c in range(3):
                acc += inv_rot[p, a, c] * (r[p, 3 + c] - Kz[p, 3 + c])
            z[p, 3 + a] = mask[p, 3 + a] * (z[p, 3 + a] + acc)
