"""Geometrically nonlinear quasi-static fracture of a bonded-particle network: LAMMPS's own ``bpm/rotational``
forces at finite displacement and rotation, equilibrium by Newton at each load step, bonds broken one
event at a time (``compression.geometry = "nonlinear"`` of the quasi-static method).

The bond law is BondBPMRotational::elastic_forces (src/BPM/bond_bpm_rotational.cpp, LAMMPS 22 Jul 2025; after
Wang, Acta Geotechnica 4:117, 2009, and Mora and Wang 2009) term by term, for all bonds at once: with i the lower
atom id, r = x_i - x_j, r0 the bond vector at rest (lab frame), q_i, q_j the orientations and rb = q_j^-1 r q_j the
bond vector in j's frame,

- ``Fr = Kr (|r| - |r0|)`` along rb, ``Fs = Ks |r| gamma s`` (gamma = angle(r0, rb), s = rb x (rb x r0) / |.|),
  ``Ts = Ks |r|^2 gamma t / 2`` (t = r0 x rb / |.|);
- the relative rotation q21 = mq^-1 (q_j^-1 q_i) mq, mq the rotation of z onto rb (Wang's X'Y'Z' angles): twist
  psi, bend theta and its plane phi give ``Tb = Kb theta (-sin phi, cos phi, 0)``, ``Tt = Kt psi z``,
  ``Fsp = -Ks |r| theta / 2 (cos phi, sin phi, 0)``, ``Tsp = Ks |r|^2 theta / 4 (sin phi, -cos phi, 0)``, rotated
  by mq and added to Fs and Ts;
- force1on2 = q_j (Fr rb / |r| + Fs), torque on j = q_j (Ts + Tt + Tb), on i = q_j (Ts - Tt - Tb); f_i -= force1on2,
  f_j += force1on2; the breaking index B = Fr / Fcr + |Fs| / Fcs + |Tb| / Tcb + |Tt| / Tct (``smooth no``).

Kr, Ks are per unit length (``normalize yes``: the network's a_r, a_s), Kb, Kt its bend and twist
(:mod:`opalflow.bpm.stiffness` is the same law to first order; ``tests/test_nonlinear.py`` checks the two agree
for small motions and that the forces balance).

The solve: unknowns the displacements u and rotation vectors phi (q = exp(phi), the orientations at rest the
identity, as the data file gives them) of the free particles; the residual the force and torque on each. Newton with
the exact tangent (the bonds' by central differences, each bond's 12 x 12 block from 24 evaluations of its loads in
one numba kernel, :func:`_elastic`; the contacts' by complex steps) and a sparse LU (SuperLU on the tangent's
symmetric pattern, :data:`LU_OPTIONS`), a backtracking line search on |F|, and pseudo-transient continuation where
Newton stalls (:meth:`_Network.solve`); each step predicted by the secant of the last two equilibria (the linear
network's unit solution at the start and after an event).  The strain grows by ``step`` (the linear method's first
event strain / ``steps_to_first``), each equilibrium checked for B >= 1; the first crossing is located by bisection
to ``locate_rtol`` of the strain, the bond of the largest B breaks (with ``tolerance``: every bond within it of the
largest), particles that lose their path to the supports are held still (with contacts they float: below), and the
network is solved again at that strain (the stress after the event); so on until the stress falls below
``stop_fraction`` of the peak or the strain reaches ``strain_max``.

Contacts (``contacts.enabled``, the dynamic deck's own): LAMMPS's Hertz-Mindlin contacts with Coulomb friction
between spheres no intact bond joins (:class:`opalflow.bpm.contacts.GranularContacts`), their slip histories
carried from one accepted equilibrium to the next, found as the spheres move: the candidates of a load step are the
pairs near contact where it starts, renewed where a pair overlaps outside them, at an equilibrium, after each
continuation step and every :data:`FOLLOW_STEPS` FIRE steps (:meth:`_Network.follow`).  A cluster that a break
cuts off the supports floats: free, it touches and is pressed as any sphere is, as in LAMMPS's dynamics (held still
without contacts it carried nothing: measured, the restructured 0.12 seed 2 slab's third break cut 529 spheres off
and its stress fell to 31 % of the stress before the break, LAMMPS's to 92 %); its motions that nothing resists (a
sphere's spin about its one contact's normal) are held in Newton's tangent by :meth:`_Network.float_springs`.

Where no equilibrium is found: a load step whose Newton iterations stall gets ``ptc_in_step`` continuation steps,
and is taken where the least unbalanced state they passed is within 10x Newton's tolerance (the stalls of clusters
that hang by a few bonds sat at 1.2-9x it), else it is halved; the step grows back by 1.5 after an easy step (<= 3
iterations) and after one taken out of balance (shorter steps find no equilibrium there either). After an event, and
where a step shorter than 1/64 of the first finds none, ``ptc_after_event`` continuation steps, then up to
``fire_steps`` steps of damped dynamics (:meth:`_Network.relax`, the network settling as LAMMPS's dynamics settles
it). Where those end out of balance, the least unbalanced state they passed is taken if its largest force is within
``out_of_balance`` of the forces' scale (the first step's largest reaction): the loading goes on from it, its
residual the force that still moves the spheres, as LAMMPS's dynamics moves them while the wall moves, and the next
steps go to the continuation and the dynamics at once, growing (one that settles nowhere halved), until they settle
(a step held below 1/64 of the first, each out of balance, crawled: measured, the restructured 0.06 seed 10 slab
after its first break, ~27 s a step for 2 900 s with B 0.83 -> 0.91; so, to its second break and the end in 259 s).
``FractureResult.unbalanced`` lists each such state's largest force over the scale; the run's summary counts them.
Beyond that the run stops: with no stress after an event (a snap-through) or with no event in a load step
(bench/results/aerogel_strength_validation.md: the method against LAMMPS's dynamics on ten slabs).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from scipy.sparse import diags as sp_diags

from opalflow.bpm.contacts import GranularContacts
from opalflow.bpm.loading import Supports
from opalflow.bpm.quasistatic import Event, FractureResult, Strengths
from opalflow.bpm.static import block_matrix, loose_particles
from opalflow.bpm.stiffness import BondNetwork
from opalflow.linalg.direct import Factor
from opalflow.jit import njit
from opalflow.spec import InputError

SQRT_HALF = math.sqrt(0.5)
#: a continuation step may raise |F| this much (the way out of an unstable state goes uphill first: measured, a
#: continuation that had to lower |F| at every step stalled where one allowed 10x found the equilibrium)
GROWTH = 10.0
#: FIRE's first and longest time step (the masses the tangent's diagonal: a lone dof's period 2 pi) and its
#: first mixing (Bitzek et al. 2006's alpha_start)
FIRE_DT, FIRE_DT_MAX, FIRE_ALPHA = 0.1, 0.5, 0.1
#: the springs that hold a floating cluster's unresisted motions in Newton's tangent, over the dofs' stiffness
FLOAT_SPRING = 1e-6
#: SuperLU's options for the tangent: minimum degree on its symmetric pattern with diagonal pivots preferred (the
#: bonds' tangent is symmetric in pattern and near it in value: measured on a 2 000-sphere slab's, 2.5x less
#: fill and 2x faster than the default column ordering, the same residual)
LU_OPTIONS = {"permc_spec": "MMD_AT_PLUS_A", "diag_pivot_thresh": 0.1, "options": {"SymmetricMode": True}}
#: FIRE steps between two checks for pairs that came to overlap outside the contact candidates
FOLLOW_STEPS = 50


@dataclasses.dataclass
class BondLoads:
    """Each bond's loads (LAMMPS's elastic_forces): the force on j (``force1on2``, lab frame), the torques on
    j and on i, and the four magnitudes of the breaking index: the signed normal force Fr, |Fs|, |Tb|, |Tt|."""

    force: np.ndarray
    torque_j: np.ndarray
    torque_i: np.ndarray
    Fr: np.ndarray
    Fs: np.ndarray
    Tb: np.ndarray
    Tt: np.ndarray


def bond_loads(net: BondNetwork, u: np.ndarray, phi: np.ndarray) -> BondLoads:
    """The loads of the bonds of ``net`` at displacements ``u`` (N, 3) from rest and rotation vectors ``phi``
    (N, 3; the orientations at rest the identity) (the module docstring, term by term; :func:`_elastic`): the bond
    vector r = r0 + u_i - u_j, r0 = L n at rest (the nearest image across a periodic side, as the network has it)."""
    i, j = net.i, net.j
    out = np.empty((len(i), 13))
    _elastic(net.L[:, None] * net.n, net.L, net.a_r, net.a_s, net.bend, net.twist, np.hstack([u[i], phi[i]]),
             np.hstack([u[j], phi[j]]), 0.0, out, np.empty((0, 12, 12)))
    return BondLoads(*out[:, :9].reshape(-1, 3, 3).transpose(1, 0, 2), *out[:, 9:].T)


@njit(cache=True, nogil=True, inline="always")
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    """The quaternion product a b."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3, a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1, a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@njit(cache=True, nogil=True, inline="always")
def _qrot(w, x, y, z, v0, v1, v2):
    """v rotated by the unit quaternion (w, x, y, z)."""
    t0, t1, t2 = 2.0 * (y * v2 - z * v1), 2.0 * (z * v0 - x * v2), 2.0 * (x * v1 - y * v0)
    return (v0 + w * t0 + y * t2 - z * t1, v1 + w * t1 + z * t0 - x * t2, v2 + w * t2 + x * t1 - y * t0)


@njit(cache=True, nogil=True, inline="always")
def _quat(p0, p1, p2):
    """The unit quaternion of the rotation vector p: |p| about p / |p|."""
    angle = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    k = math.sin(0.5 * angle) / angle if angle > 1e-4 else 0.5 - angle * angle / 48.0    # (its series near 0)
    return math.cos(0.5 * angle), k * p0, k * p1, k * p2


@njit(cache=True, nogil=True, inline="always")
def _unit(v0, v1, v2):
    """v / |v|; zero stays zero (LAMMPS's norm3 of a zero vector: a 0/0 there, reached only by a bond exactly at
    rest, where the term it scales is zero)."""
    n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    return (v0 / n, v1 / n, v2 / n) if n > 0 else (0.0, 0.0, 0.0)


@njit(cache=True, nogil=True, inline="always")
def _bond_loads(r0, L, a_r, a_s, bend, twist, b, x, res):
    """Bond b's loads into ``res`` (13: :func:`_elastic`'s row) at ``x`` (i's 6 dofs, then j's)."""
    jw, jx, jy, jz = _quat(x[9], x[10], x[11])
    iw, ix, iy, iz = _quat(x[3], x[4], x[5])
    p0, p1, p2 = r0[b, 0], r0[b, 1], r0[b, 2]
    r_0, r_1, r_2 = p0 + x[0] - x[6], p1 + x[1] - x[7], p2 + x[2] - x[8]
    r_mag = math.sqrt(r_0 * r_0 + r_1 * r_1 + r_2 * r_2)
    rb0, rb1, rb2 = _qrot(jw, -jx, -jy, -jz, r_0, r_1, r_2)
    Fr = a_r[b] * (r_mag - L[b])
    c0, c1, c2 = rb1 * p2 - rb2 * p1, rb2 * p0 - rb0 * p2, rb0 * p1 - rb1 * p0          # rb x r0
    gamma = math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), p0 * rb0 + p1 * rb1 + p2 * rb2)
    s0, s1, s2 = _unit(rb1 * c2 - rb2 * c1, rb2 * c0 - rb0 * c2, rb0 * c1 - rb1 * c0)   # rb x (rb x r0)
    t0, t1, t2 = _unit(-c0, -c1, -c2)                                                   # r0 x rb
    fs = a_s[b] * r_mag * gamma
    ts = 0.5 * a_s[b] * r_mag * r_mag * gamma
    # mq: the rotation of z onto rb (Wang and Mora's X'Y'Z' representation)
    m0 = SQRT_HALF * math.sqrt(max(r_mag + rb2, 0.0) / r_mag)
    rxy = math.sqrt(rb0 * rb0 + rb1 * rb1)
    k = -SQRT_HALF / rxy * math.sqrt(max(r_mag - rb2, 0.0) / r_mag) if rxy != 0.0 else 0.0
    m1, m2 = k * rb1, -k * rb0
    # q21 = mq^-1 (qj^-1 qi) mq
    a = _qmul(jw, -jx, -jy, -jz, iw, ix, iy, iz)
    a = _qmul(a[0], a[1], a[2], a[3], m0, m1, m2, 0.0)
    w, x, y, z = _qmul(m0, -m1, -m2, 0.0, a[0], a[1], a[2], a[3])
    out_plane, in_plane = w * w + z * z, x * x + y * y
    sign = 1.0 if z > 0 else (-1.0 if z < 0 else 0.0)
    psi = 2.0 * math.atan2(abs(z), w) * sign                                # 2 acos(w / |(w, z)|)
    theta = 2.0 * math.atan2(math.sqrt(in_plane), math.sqrt(out_plane))     # acos(w^2 - x^2 - y^2 + z^2)
    if in_plane == 0.0:
        cos_phi, sin_phi = 0.0, 0.0
    elif out_plane == 0.0:
        cos_phi, sin_phi = y / math.sqrt(in_plane), -x / math.sqrt(in_plane)
    else:
        both = math.sqrt(out_plane * in_plane)
        cos_phi, sin_phi = (x * z + w * y) / both, (y * z - w * x) / both
    e = a_s[b] * r_mag * theta
    Fsp = _qrot(m0, m1, m2, 0.0, -0.5 * e * cos_phi, -0.5 * e * sin_phi, 0.0)
    Tsp = _qrot(m0, m1, m2, 0.0, 0.25 * e * r_mag * sin_phi, -0.25 * e * r_mag * cos_phi, 0.0)
    Tb = _qrot(m0, m1, m2, 0.0, -bend[b] * theta * sin_phi, bend[b] * theta * cos_phi, 0.0)
    Tt = _qrot(m0, m1, m2, 0.0, 0.0, 0.0, twist[b] * psi)
    Fs = (fs * s0 + Fsp[0], fs * s1 + Fsp[1], fs * s2 + Fsp[2])
    Ts = (ts * t0 + Tsp[0], ts * t1 + Tsp[1], ts * t2 + Tsp[2])
    g = Fr / r_mag
    f = _qrot(jw, jx, jy, jz, g * rb0 + Fs[0], g * rb1 + Fs[1], g * rb2 + Fs[2])
    tj = _qrot(jw, jx, jy, jz, Ts[0] + Tt[0] + Tb[0], Ts[1] + Tt[1] + Tb[1], Ts[2] + Tt[2] + Tb[2])
    ti = _qrot(jw, jx, jy, jz, Ts[0] - Tt[0] - Tb[0], Ts[1] - Tt[1] - Tb[1], Ts[2] - Tt[2] - Tb[2])
    for k3 in range(3):
        res[k3], res[3 + k3], res[6 + k3] = f[k3], tj[k3], ti[k3]
    res[9] = Fr
    res[10] = math.sqrt(Fs[0] * Fs[0] + Fs[1] * Fs[1] + Fs[2] * Fs[2])
    res[11] = math.sqrt(Tb[0] * Tb[0] + Tb[1] * Tb[1] + Tb[2] * Tb[2])
    res[12] = math.sqrt(Tt[0] * Tt[0] + Tt[1] * Tt[1] + Tt[2] * Tt[2])


@njit(cache=True, nogil=True)
def _elastic(r0, L, a_r, a_s, bend, twist, zi, zj, h, out, blocks):
    """Bond b (rest vector r0 = L n, stiffnesses a_r, a_s, bend, twist) with its particles at displacements and
    rotation vectors ``zi``, ``zj`` (M, 6): with ``h`` = 0, row b of ``out`` (M, 13) its loads: the force on j (3,
    lab frame), the torques on j and on i (3 each), Fr, |Fs|, |Tb|, |Tt|; with ``h`` > 0, ``blocks[b]`` (M, 12, 12)
    the derivative of its internal force on i and on j (:func:`internal_force`'s signs) in i's and j's 12 dofs by
    central differences of step h (24 evaluations a bond).  LAMMPS's BondBPMRotational::elastic_forces term by term
    (the module docstring), one bond at a time (numpy's gathers over ~80 short arrays cost 10-20x more); the angles
    LAMMPS takes as acos of cosines are taken as atan2 (the same angles without acos's loss of precision near 0:
    sqrt(machine epsilon) in the angle, which a difference quotient of the forces would see)."""
    x, res = np.empty(12), np.empty(13)
    for b in range(len(L)):
        for k in range(6):
            x[k], x[6 + k] = zi[b, k], zj[b, k]
        if h == 0.0:
            _bond_loads(r0, L, a_r, a_s, bend, twist, b, x, res)
            out[b, :] = res
            continue
        for d in range(12):
            at = x[d]
            for sign in (1.0, -1.0):
                x[d] = at + sign * h
                _bond_loads(r0, L, a_r, a_s, bend, twist, b, x, res)
                c = sign / (2.0 * h)
                for k in range(3):
                    blocks[b, k, d] += c * res[k]                # on i: force1on2, minus the torque on i
                    blocks[b, 3 + k, d] -= c * res[6 + k]
                    blocks[b, 6 + k, d] -= c * res[k]            # on j: minus force1on2, minus the torque on j
                    blocks[b, 9 + k, d] -= c * res[3 + k]
            x[d] = at


def internal_force(net: BondNetwork, loads: BondLoads) -> np.ndarray:
    """(N, 6): minus the bonds' force and torque on each particle (the load that holds it there: K x for small
    motions, as the linear network's)."""
    g = np.zeros((net.n_particles, 6))
    for k in range(3):
        g[:, k] = np.bincount(net.i, loads.force[:, k], net.n_particles) - np.bincount(
            net.j, loads.force[:, k], net.n_particles)
        g[:, 3 + k] = -np.bincount(net.i, loads.torque_i[:, k], net.n_particles) - np.bincount(
            net.j, loads.torque_j[:, k], net.n_particles)
    return g


def breaking_index(loads: BondLoads, c: Strengths) -> np.ndarray:
    """LAMMPS's B of each bond (clipped at 0) and which of its two sums is the larger (0: normal + bending,
    1: shear + twist, as :data:`opalflow.bpm.quasistatic.CHECKS` names them for "lammps")."""
    normal = loads.Fr / c.fr_c + loads.Tb / c.tb_c
    shear = loads.Fs / c.fs_c + loads.Tt / c.tt_c
    return np.maximum(normal + shear, 0.0), (shear > normal).astype(int)


class _Network:
    """The damaged network under its supports: the intact bonds, the particles held (supports; loose ones without
    contacts), those floating (loose ones with contacts), the preconditioner of the linear stiffness of what is
    intact and held by the supports."""

    def __init__(self, net: BondNetwork, supports: Supports, alive, strengths: Strengths,
                 contacts: GranularContacts | None = None):
        self.full, self.supports, self.all_strengths, self.contacts = net, supports, strengths, contacts
        self.best: tuple[float, np.ndarray | None] = (math.inf, None)
        self.set_alive(alive)

    def set_alive(self, alive: np.ndarray) -> None:
        self.alive = alive.copy()
        self.net = self.full.part(np.flatnonzero(alive))
        self.strengths = self.all_strengths.part(np.flatnonzero(alive))     # the intact bonds', in their order
        self.loose = loose_particles(self.net, self.supports.anchored)
        self.held = self.supports.without(self.loose)
        bonded_free = ~self.held.held.ravel()
        # with contacts, a cluster cut off the supports floats: free, pressed on by its contacts (LAMMPS's)
        self.floating = np.repeat(self.loose, 6) if self.contacts is not None else np.zeros(bonded_free.size, bool)
        self.free = bonded_free | self.floating
        if self.contacts is not None:
            self.contacts.set_bonded(self.net.i, self.net.j)
            self.contacts.loose = np.zeros_like(self.loose)
        K = block_matrix(self.net, bonded_free)[0]
        self.factor = Factor(K, bonded_free)
        self.factorizations = getattr(self, "factorizations", 0) + 1
        self.pattern()
        drive = self.held.drive.ravel()
        # the linear network's displacements at unit strain: the first predictor
        self.unit = drive - np.where(bonded_free, self.factor.solve(np.where(bonded_free, self.net.matvec(drive),
                                                                             0.0)), 0.0)

    def loads(self, z: np.ndarray) -> BondLoads:
        X = z.reshape(-1, 6)
        return bond_loads(self.net, X[:, :3], X[:, 3:])

    def internal(self, z: np.ndarray) -> np.ndarray:
        """(N, 6): the bonds' (and the contacts') internal force at z."""
        g = internal_force(self.net, self.loads(z))
        return g if self.contacts is None else g + self.contacts.internal(z)

    def residual(self, z: np.ndarray) -> np.ndarray:
        return np.where(self.free, self.internal(z).ravel(), 0.0)

    def prescribed(self, z: np.ndarray, strain: float) -> np.ndarray:
        return np.where(self.free, z, self.held.drive.ravel() * strain)

    def pattern(self) -> None:
        """The layout of the bonds' part of the tangent, fixed while the bonds and the free dofs are: each free x
        free entry of the bonds' 12 x 12 blocks (``on``) and the prescribed dofs' diagonal, their slot in one CSR
        pattern (``slot``; :meth:`jacobian` sums each block entry into its slot by a bincount)."""
        i, j, size = self.net.i, self.net.j, 6 * self.net.n_particles
        dof = np.hstack([i[:, None] * 6 + np.arange(6), j[:, None] * 6 + np.arange(6)])        # (bond, 12)
        rows, cols = np.repeat(dof[:, :, None], 12, axis=2), np.repeat(dof[:, None, :], 12, axis=1)
        self.on = (self.free[rows] & self.free[cols]).ravel()
        held = np.flatnonzero(~self.free)
        keys = np.r_[rows.ravel()[self.on], held] * size + np.r_[cols.ravel()[self.on], held]
        unique, self.slot = np.unique(keys, return_inverse=True)
        self.indices = unique % size
        self.indptr = np.searchsorted(unique // size, np.arange(size + 1))
        self.ones = np.ones(len(held))                          # the prescribed dofs' diagonal

    def jacobian(self, z: np.ndarray):
        """The tangent dF/dz of the residual (free dofs only; a prescribed dof's row and column the identity): each
        bond's 12 x 12 block by central differences of its loads in its two particles' 12 dofs (:func:`_elastic`;
        forward ones were off by 4 % along the near-rigid motion of a cluster that hangs by a few bonds, where
        Newton's step is large: central, 0.2 %), summed into :meth:`pattern`; the contacts' by complex steps
        (:meth:`opalflow.bpm.contacts.GranularContacts.tangent`)."""
        import scipy.sparse as sp

        net, X = self.net, z.reshape(-1, 6)
        h = 1e-7 * max(1.0, float(np.max(np.abs(z))))          # the difference step
        blocks = np.zeros((len(net.L), 12, 12))
        _elastic(net.L[:, None] * net.n, net.L, net.a_r, net.a_s, net.bend, net.twist, X[net.i], X[net.j], h,
                 np.empty((0, 13)), blocks)
        size = 6 * net.n_particles
        data = np.bincount(self.slot, np.concatenate([blocks.ravel()[self.on], self.ones]), len(self.indices))
        J = sp.csr_matrix((data, self.indices, self.indptr), shape=(size, size))
        if self.contacts is not None:
            keep = sp.diags(self.free.astype(float))
            J = J + keep @ self.contacts.tangent(z) @ keep
        if self.floating.any():
            J = J + sp.diags(self.float_springs(J.diagonal()))
        return J.tocsc()

    def float_springs(self, diagonal: np.ndarray) -> np.ndarray:
        """Springs that hold a floating cluster's motions which nothing else resists (a sphere's spin about its
        one contact's normal: the contacts have no twisting resistance; a cluster's motion with no contact at all)
        where they are, for Newton's tangent alone (the residual has none, so an equilibrium is one): each of its
        dofs :data:`FLOAT_SPRING` x (its own diagonal + the median of the free dofs' of its kind, translation or
        rotation)."""
        d = np.abs(diagonal).reshape(-1, 2, 3)
        free = self.free.reshape(-1, 2, 3)
        typical = [np.median(d[:, k][free[:, k]]) if free[:, k].any() else 0.0 for k in range(2)]
        spring = FLOAT_SPRING * (d + np.array(typical)[None, :, None])
        return np.where(self.floating, spring.ravel(), 0.0)

    def solve(self, z0: np.ndarray, strain: float, f_tol: float, maxiter: int,
              ptc_max: int) -> tuple[np.ndarray, int] | None:
        """Equilibrium at ``strain`` from ``z0`` (its prescribed dofs set): Newton with the tangent of
        :meth:`jacobian` and a backtracking line search on |F|, the tangent's factors kept for chord steps while
        each more than halves |F|; where Newton stalls (no equilibrium near: a sphere slides on another, a branch
        snaps through), up to ``ptc_max`` steps of pseudo-transient continuation (Kelley and Keyes, SIAM J. Numer.
        Anal. 35:508, 1998): (J + D / tau) dz = -F, D the tangent's diagonal, the pseudo time step tau cut by 4
        while a step would raise |F| more than :data:`GROWTH`-fold, doubled after a step that lowers |F| and
        halved after one that raises it (a damped motion towards a stable equilibrium, uphill where it leaves an
        unstable one).  (z, iterations), None where neither converged."""
        from scipy.sparse.linalg import splu

        z = self.prescribed(z0, strain)
        self.refresh(z)
        F = self.residual(z)
        norm, it, found = np.linalg.norm(F), 0, 0
        ptc, shift, lu = False, 1.0, None
        while True:
            if self.keep(z, F) <= f_tol:
                if self.settled(z, found):
                    return z, it
                found += 1
                F, lu = self.residual(z), None
                norm = np.linalg.norm(F)
                continue
            if it >= maxiter + (ptc_max if ptc else 0):
                return None
            it += 1
            if lu is not None and not ptc:
                # a chord step: the last tangent's factors, kept while they more than halve |F| each step
                dz = np.where(self.free, -lu.solve(F), 0.0)
                F_try = self.residual(z + dz)
                n_try = np.linalg.norm(F_try)
                if np.isfinite(n_try) and n_try < 0.5 * norm:
                    z, F, norm = z + dz, F_try, n_try
                    continue
            J = self.jacobian(z)
            if ptc:
                # the pseudo time step: a step is taken unless |F| grows more than GROWTH-fold (then shortened:
                # a larger shift), lengthened after a step that lowers |F| and shortened after one that raises it
                D = sp_diags(np.abs(J.diagonal()) + 1e-30)
                for _ in range(30):
                    try:
                        dz = np.where(self.free, -splu((J + shift * D).tocsc(), **LU_OPTIONS).solve(F), 0.0)
                    except RuntimeError:
                        dz = None
                    if dz is not None:
                        F_new = self.residual(z + dz)
                        n_new = np.linalg.norm(F_new)
                        if np.isfinite(n_new) and n_new < GROWTH * norm:
                            break
                    shift *= 4.0
                else:
                    return None
                shift = shift / 2.0 if n_new < norm else 2.0 * shift
                z = z + dz
                F = self.follow(z, F_new)
                norm = n_new if F is F_new else np.linalg.norm(F)
                continue
            try:
                lu = splu(J, **LU_OPTIONS)
            except RuntimeError:                 # a singular tangent (a mechanism)
                return None
            dz = np.where(self.free, -lu.solve(F), 0.0)
            t = 1.0
            while t > 1e-2:
                z_try = z + t * dz
                F_try = self.residual(z_try)
                n_try = np.linalg.norm(F_try)
                if np.isfinite(n_try) and n_try < norm:
                    break
                t *= 0.5
            if t <= 1e-2 or t < 0.25 and it > 5:               # stalled: continue by pseudo-time
                ptc = True
                continue
            z, F, norm = z_try, F_try, n_try

    def relax(self, z0: np.ndarray, strain: float, f_tol: float, steps: int) -> tuple[np.ndarray, int] | None:
        """Equilibrium at ``strain`` from ``z0`` by damped dynamics where :meth:`solve` finds none: FIRE (Bitzek et
        al., Phys. Rev. Lett. 97:170201, 2006; LAMMPS's ``min_style fire``) with the residual as the force, each
        dof's mass its tangent's diagonal (one time step fits translations and rotations), up to ``steps`` steps,
        Newton from the best state every 1 000.  The way LAMMPS's dynamics goes where a cluster that hangs by a
        few bonds snaps over (measured: the restructured 0.06 seed 2 slab at strain 0.0817, where Newton and the
        continuation stalled, in 122 steps, 0.5 s).  (z, steps), None where it found none."""
        z = self.prescribed(z0, strain)
        self.refresh(z)
        mass = np.abs(self.jacobian(z).diagonal())
        root = np.sqrt(np.where(self.free & (mass > 0), mass, 1.0))
        v, dt, alpha, calm = np.zeros_like(z), FIRE_DT, FIRE_ALPHA, 0
        F = self.residual(z)
        best, z_best, found = np.inf, z, 0
        for k in range(steps):
            worst = float(np.max(np.abs(F)))
            if not math.isfinite(worst):
                return None
            if worst <= f_tol:
                if self.settled(z, found):
                    return z, k
                found += 1
                F = self.residual(z)
                continue
            if worst < best:
                best, z_best = worst, z
                self.keep(z, F, worst)
            if k % 1000 == 999:
                got = self.solve(z_best, strain, f_tol, 20, 0)
                if got is not None:
                    return got[0], k + got[1]
            f = np.where(self.free, -F / root, 0.0)            # in mass-weighted coordinates
            if f @ v > 0:                                       # going downhill: straighten, then speed up
                calm += 1
                v = (1 - alpha) * v + alpha * np.linalg.norm(v) * f / max(np.linalg.norm(f), 1e-300)
                if calm > 5:
                    dt, alpha = min(1.1 * dt, FIRE_DT_MAX), 0.99 * alpha
            else:                                               # uphill: stop, shorten the step
                calm, alpha, dt = 0, FIRE_ALPHA, 0.5 * dt
                v = np.zeros_like(z)
            v = v + dt * f
            z = z + np.where(self.free, dt * v / root, 0.0)
            F = self.residual(z)
            if k % FOLLOW_STEPS == 0:
                F = self.follow(z, F)
        return None

    def follow(self, z: np.ndarray, F: np.ndarray) -> np.ndarray:
        """F, or where a pair overlaps at z outside the contact candidates the residual with them renewed from z:
        spheres that move far in the continuation or the dynamics come to touch spheres that were not near where
        the solve started (measured: the restructured 0.12 seed 1 slab at strain 0.0745, where the least
        unbalanced state the continuation and the dynamics passed, its contacts found again, was out of balance by
        79x the forces' scale, twelve spheres pushed into others they had not been checked against)."""
        if self.contacts is None or not self.contacts.missed(z):
            return F
        self.refresh(z)
        return self.residual(z)

    def keep(self, z: np.ndarray, F: np.ndarray, worst: float | None = None) -> float:
        """max |F| at z (``worst`` where the caller has it), z kept as ``best`` if it is the least that
        :meth:`solve` and :meth:`relax` passed through since ``best`` was last reset (the driver takes it where
        neither converges: :func:`solve_nonlinear_fracture`'s ``out_of_balance``)."""
        worst = float(np.max(np.abs(F))) if worst is None else worst
        if worst < self.best[0]:
            self.best = (worst, z)
        return worst

    def settled(self, z: np.ndarray, found: int) -> bool:
        """Whether an equilibrium z is one: no pair overlaps outside the step's contact candidates (or ``found``,
        the times they were renewed, has reached 5); where one does, the candidates are renewed from z (the
        caller solves on with them)."""
        if self.contacts is None or found >= 5 or not self.contacts.missed(z):
            return True
        self.refresh(z)
        return False

    def stress(self, z: np.ndarray) -> float:
        return self.held.stress(self.internal(z))

    def refresh(self, z: np.ndarray) -> None:
        """The contact candidates of a step from z (nothing without contacts)."""
        if self.contacts is not None:
            self.contacts.find(z)

    def commit(self, z: np.ndarray) -> int:
        """z accepted: the contacts' slip histories from here; the number of pairs touching (0 without contacts)."""
        if self.contacts is None:
            return 0
        self.refresh(z)
        return self.contacts.commit(z)


def solve_nonlinear_fracture(net: BondNetwork, strengths: Strengths, supports: Supports, *,
                             strain_max: float, first_strain: float, stop_fraction: float = 0.5,
                             events_max: int = 100_000, tolerance: float = 0.0, steps_to_first: int = 8,
                             locate_rtol: float = 1e-3, f_rtol: float = 1e-5, maxiter: int = 50,
                             ptc_in_step: int = 100, ptc_after_event: int = 200, fire_steps: int = 2_000,
                             out_of_balance: float = 1e-2,
                             contacts: GranularContacts | None = None, say=print) -> FractureResult:
    """Events of the nonlinear network (the module docstring) as :class:`opalflow.bpm.quasistatic.FractureResult`
    (``modulus_MPa`` the first step's secant; ``resolver`` "newton").  ``first_strain``: the linear
    method's first event (sets the step); ``f_rtol``: Newton's residual over the first step's largest force
    (1e-5: at 1e-6 the solves stalled near clusters that hang by a few bonds, at 1.2-9x that tolerance; at 1e-5
    they converge there with the stress 0.3 and 2.4 % below LAMMPS's: restructured 0.12 seed 1 at strain 0.0528,
    0.06 seed 2 at 0.078);
    ``out_of_balance``: the largest force, over the first step's largest reaction, of a state taken where no
    equilibrium is found after an event or a step however short (the module docstring);
    ``contacts``: Hertz-Mindlin contacts with friction (:class:`opalflow.bpm.contacts.GranularContacts`) or none."""
    if strengths.rule != "lammps":
        raise InputError("bonds.breaking", strengths.rule, 'must be "lammps" with compression.geometry = '
                         '"nonlinear" (LAMMPS\'s bpm/rotational rule, the one its bond law carries)')
    from threadpoolctl import threadpool_limits

    # BLAS under one thread: its idle threads spin after numpy's dot products (a norm of the residual cost 3.6 ms
    # with two runs on two cores: measured), on the cores the other run needs
    with threadpool_limits(limits=1):
        t0 = time.perf_counter()
        nw = _Network(net, supports, np.ones(len(net.L), bool), strengths, contacts)
        run = _Loading(nw, t0, time.perf_counter() - t0, strain_max=strain_max, maxiter=maxiter,
                       ptc_in_step=ptc_in_step, ptc_after_event=ptc_after_event, fire_steps=fire_steps,
                       out_of_balance=out_of_balance, say=say)
        run.step = first_strain / steps_to_first if math.isfinite(first_strain) and first_strain > 0 \
            else strain_max / 50
        run.base_step = run.step
        return run.events_until(f_rtol, events_max, tolerance, locate_rtol, stop_fraction)


class _Loading:
    """:func:`solve_nonlinear_fracture`'s load steps and events on one network: the state reached (``z`` at
    ``strain``, the secant of the last two equilibria), the step, the events and the peak."""

    def __init__(self, nw: _Network, t0: float, setup: float, *, strain_max: float, maxiter: int,
                 ptc_in_step: int, ptc_after_event: int, fire_steps: int, out_of_balance: float, say):
        self.nw, self.t0, self.setup, self.strain_max, self.say = nw, t0, setup, strain_max, say
        self.maxiter, self.ptc_in_step, self.ptc_after_event = maxiter, ptc_in_step, ptc_after_event
        self.fire_steps, self.out_of_balance = fire_steps, out_of_balance
        self.z, self.strain, self.secant = np.zeros(nw.supports.drive.size), 0.0, None
        self.step = self.base_step = math.nan
        self.scale, self.f_tol = None, math.inf
        self.events: list[Event] = []
        self.peak, self.peak_alive, self.peak_x, self.modulus = 0.0, None, None, float("nan")
        self.stopped = f"strain_max {strain_max:g} reached"
        self.unbalanced: list[float] = []       # max |F| / the forces' scale of each state taken out of balance
        self.flowing = False                    # the last state settle's, out of balance: the next straight to settle

    def out_of_balance_state(self, got, limit):
        """got, or where it is None the least unbalanced state the solves passed if its max |F| is within
        ``limit`` (iterations -1): the motion goes on in the next load steps, the residual left the force that
        moves the spheres, as in LAMMPS's dynamics, where they move while the wall does.  Its residual is taken
        again with the contact candidates found from it (the solves' were found where they started: a state of
        small residual that overlapped pairs outside them was taken once, at 160x the stress of its neighbours)."""
        nw = self.nw
        if got is None and nw.best[1] is not None:
            z_best = nw.best[1]
            nw.refresh(z_best)
            worst = float(np.max(np.abs(nw.residual(z_best))))
            if worst <= limit:
                self.unbalanced.append(worst / self.scale)
                return z_best, -1
        return got

    def equilibrium(self, z_from, e_from, e_to, accept=True):
        """Equilibrium at e_to from the one at e_from, predicted by the secant of the last two (the linear
        network's unit solution where there is none); with ``accept``, a state within 10x Newton's tolerance where
        none is found (the stalls of clusters that hang by a few bonds sit at 1.2-9x it: measured)."""
        nw = self.nw
        slope = nw.unit if self.secant is None else self.secant
        nw.best = (math.inf, None)
        got = nw.solve(z_from + slope * (e_to - e_from), e_to, self.f_tol, self.maxiter, self.ptc_in_step)
        return self.out_of_balance_state(got, 10.0 * self.f_tol) if accept else got

    def settle(self, z_guess, e):
        """Equilibrium at e after an event or where load steps however short find none: longer continuation, then
        dynamics (a longer run of it did not settle a slab after its first break: measured, the restructured 0.03
        seed 1 slab still moving at 40-100x the tolerance after 20 000 steps), else a state out of balance."""
        nw = self.nw
        nw.best = (math.inf, None)
        return self.out_of_balance_state(nw.solve(z_guess, e, self.f_tol, self.maxiter, self.ptc_after_event)
                                         or nw.relax(z_guess, e, self.f_tol, self.fire_steps),
                                         self.out_of_balance * self.scale)

    def events_until(self, f_rtol, events_max, tolerance, locate_rtol, stop_fraction) -> FractureResult:
        """Load steps until ``strain_max``, ``events_max`` events, a fall below ``stop_fraction`` of the peak or a
        state no step finds; each crossing of B = 1 located to ``locate_rtol`` and broken as an event."""
        nw = self.nw
        while self.strain < self.strain_max and len(self.events) < events_max:
            target = min(self.strain + self.step, self.strain_max)
            if self.scale is None:  # the first step's reactions (the forces' scale) set Newton's tolerance
                trial = nw.internal(nw.prescribed(self.z + nw.unit * (target - self.strain), target))
                self.scale = float(np.max(np.abs(np.where(nw.free, 0.0, trial.ravel()))))
                self.f_tol = f_rtol * self.scale
            got = self.load_step(target)
            if got == "stop":
                break
            if got is None:
                self.step *= 0.5
                continue
            B, _ = breaking_index(nw.loads(got[0]), nw.strengths)
            if math.isnan(self.modulus):
                self.modulus = nw.stress(got[0]) / target
            if B.max(initial=0.0) < 1.0:
                self.accept(got, target, B)
                continue
            self.locate(got[0], target, locate_rtol)
            if not self.event(tolerance, stop_fraction):
                break
        return FractureResult(self.modulus, self.events, nw.alive, self.stopped, time.perf_counter() - self.t0,
                              self.setup, "newton", nw.factorizations, peak_alive=self.peak_alive,
                              peak_x=self.peak_x, end_x=self.z.reshape(-1, 6), loose=int(nw.loose.sum()),
                              unbalanced=self.unbalanced)

    def load_step(self, target):
        """The state at ``target``: (z, Newton iterations; -1 out of balance), None where the step should be
        halved, "stop" where no equilibrium is found however short the step."""
        nw = self.nw
        got = None if self.flowing else self.equilibrium(self.z, self.strain, target)
        if got is None and (self.flowing or self.step < self.base_step / 64):
            # no equilibrium near, however short the step (a sphere slips off another, a branch buckles): the
            # motion followed by continuation as after an event
            got = self.settle(self.z + (nw.unit if self.secant is None else self.secant) * (target - self.strain),
                              target)
            if got is None and self.step < self.base_step / 64:
                self.stopped = f"no equilibrium found at strain {target:.5g} (an instability the steps do not follow)"
                return "stop"
            self.flowing = got is not None and got[1] < 0       # (a longer step that settles nowhere: halved)
        return got

    def accept(self, got, target, B) -> None:
        """The load step to ``target`` taken: no bond at its limit."""
        nw = self.nw
        z_new, iterations = got
        self.secant = (z_new - self.z) / (target - self.strain) if iterations >= 0 else None
        self.z, self.strain = z_new, target
        nw.commit(self.z)
        if iterations <= 3:         # an easy step, or one out of balance: back towards the first step's size
            self.step = min(1.5 * self.step, self.base_step)
        self.say(f"quasi-static (nonlinear): strain {self.strain:.4f} of {self.strain_max:g}, stress "
                 f"{nw.stress(self.z):.4g} MPa, max B {B.max(initial=0.0):.3f}, "
                 + (f"{iterations} Newton iterations, " if iterations >= 0 else
                    f"out of balance by {self.unbalanced[-1]:.2g} of the forces' scale, ")
                 + f"{time.perf_counter() - self.t0:.0f} s")

    def locate(self, z_new, target, locate_rtol) -> None:
        """The first crossing of B = 1 between the state reached and ``target``, by bisection: the state there."""
        lo, hi, z_lo, z_hi = self.strain, target, self.z, z_new
        while hi - lo > locate_rtol * hi:
            mid = 0.5 * (lo + hi)
            got = self.equilibrium(z_lo, lo, mid, accept=False)
            if got is None:
                break
            B_mid, _ = breaking_index(self.nw.loads(got[0]), self.nw.strengths)
            if B_mid.max(initial=0.0) >= 1.0:
                hi, z_hi = mid, got[0]
            else:
                lo, z_lo = mid, got[0]
        self.z, self.strain = z_hi, hi

    def event(self, tolerance, stop_fraction) -> bool:
        """Break the bonds at their limit (within ``tolerance`` of the largest B) and settle; False where the run
        stops (a snap-through, or the stress below ``stop_fraction`` of the peak)."""
        nw = self.nw
        touching = nw.commit(self.z)
        stress = nw.stress(self.z)
        B, which = breaking_index(nw.loads(self.z), nw.strengths)
        k = B >= (1.0 - tolerance) * B.max()
        ids = np.flatnonzero(nw.alive)[k]
        if stress > self.peak:
            self.peak, self.peak_alive, self.peak_x = stress, nw.alive.copy(), self.z.reshape(-1, 6).copy()
        alive = nw.alive.copy()
        alive[ids] = False
        nw.set_alive(alive)
        got = self.settle(self.z, self.strain)
        if got is None:         # no equilibrium near the last one: the network snaps through (dynamic): none after
            self.events.append(Event(self.strain, stress, math.nan, [int(b) for b in ids], 0, False,
                                     [int(c) for c in which[k]], touching))
            self.stopped = f"no equilibrium after the event at strain {self.strain:.5g} (snap-through)"
            return False
        self.z, self.secant = got[0], None
        touching = nw.commit(self.z)
        after = nw.stress(self.z)
        self.events.append(Event(self.strain, stress, after, [int(b) for b in ids], max(got[1], 0), False,
                                 [int(c) for c in which[k]], touching))
        self.say(f"quasi-static (nonlinear): event {len(self.events)}, {int((~nw.alive).sum())} bonds broken, strain "
                 f"{self.strain:.5f}, stress {stress:.4g} -> {after:.4g} MPa (peak {self.peak:.4g})")
        if after < stop_fraction * self.peak:
            self.stopped = f"stress fell below {stop_fraction:g} of the peak"
            return False
        return True
