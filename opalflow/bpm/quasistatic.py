"""Quasi-static fracture of a bonded-particle network: event-driven breaking on the linear network
(sequentially linear analysis: Rots et al., Eng. Fract. Mech. 75:5155, 2008; Eliáš, Frantík and
Vořechovský, Eng. Fract. Mech. 77:2187, 2010), with LAMMPS's own breaking rule.

The breaking rule, from BondBPMRotational::elastic_forces and ::compute (src/BPM/bond_bpm_rotational.cpp,
LAMMPS 22 Jul 2025): a bond breaks when

    B = Fr / Fcr + |Fs| / Fcs + |Tb| / Tcb + |Tt| / Tct >= 1,

with Fr = Kr (r - r0) the signed normal force (tension positive: compression lowers B, a bond in pure
compression never breaks), Fs the shear force (from the bond's tilt, ``Ks r gamma s``, plus the part from
the relative rotation, ``Fsp``), Tb = Kb theta the bending and Tt = Kt psi the twisting torque of the
relative rotation; the shear torque Ts does not count, and B is clipped at 0.  Linearised
(:mod:`opalflow.bpm.stiffness`): Fr = a_r n.(u_i - u_j), Fs = P F (the bond force's part normal to the
bond), Tb = kb P (theta_i - theta_j), Tt = kt n.(theta_i - theta_j).  ``smooth yes`` scales the forces by
1 - B^4 before the bond breaks (it carries nothing at B = 1); the linear method cannot follow that and
breaks bonds at full load, as ``smooth no`` (``bonds.smooth = false``) and as the paper's bonds do.

The paper's own rule (Dosta et al. eqs. 16-17, ``bonds.breaking``; LAMMPS has no such bond style, so only
this method can apply it) checks the normal and the shear stress of the bond's section apart, each the sum of
a force's and a moment's part: a bond breaks when

    max(|Fr| / Fcr + |Tb| / Tcb, |Fs| / Fcs + |Tt| / Tct) >= 1                          (``"dosta"``),

|Fr| as printed (a compressed bond breaks too), or with the normal force signed (``"musen"``: MUSEN's code
today, the paper's equations as the paper's own code computes them since Release 1.70.0, 2021-02-26; its GPU
kernel ``CUDA_CalcSBForce_E_kernel`` of Models/SolidBonds/BondModelElastic/ModelSBElastic.cu, its "standard
breakage criteria": the normal force's length turned negative in compression, then maxStress1 + maxStress2 >=
NormalStrength or maxTorque1 + maxTorque2 >= TangentialStrength; Potyondy and Cundall's parallel bond, Int. J.
Rock Mech. 41:1329, 2004, eqs. 6-7, is the same).  Which code produced the paper's numbers the paper does not say;
two more rules follow MUSEN's history (:func:`bond_checks`): ``"musen_2020"``, its first public commit
(655e066, 2020-07-23, before the paper's publication), whose force and moment terms cancel where the equations
add them, and ``"musen_crit2"``, its second criterion since 1.70.0, each of the four terms alone.  With the
critical values of :class:`opalflow.materials.BondCoefficients` (Fcr = sigma A, Tcb = sigma I / r_b, ...) the
two sums are the normal and the shear stress of eqs. 16-17 over the strengths; LAMMPS's B is their sum, so
LAMMPS breaks a bond loaded both ways at up to half the paper's load.  Each rule is positively homogeneous
in the strain, so the events below hold for all of them.

Under a prescribed strain e of the top layer the linear network's B of every bond is e B_1 (B_1 at unit
strain; Fr is linear in e and the magnitudes grow with e > 0), so the next bond to break is the one with
the largest B_1, at e = 1 / max B_1.  An event breaks it (and, with ``tolerance`` > 0, every bond with B_1
within that fraction of the largest), the network is solved again, and so on: the sequence of (strain,
stress) before and after each event is the saw-tooth whose envelope is the stress-strain curve at zero
loading rate; its maximum is the strength.  Particles that lose their last bond path to the supports
are held still (they carry nothing).

Re-solves (measured in bench/bench_quasistatic.py, kept: ``auto``):

- ``direct``: K_ff factorised once (sparse Cholesky, :class:`opalflow.linalg.direct.Factor`); each broken bond
  removes its 12 x 12 block, a rank <= 6 change, applied by the Sherman-Morrison-Woodbury formula on the old
  factor; the factor is renewed when the updates have cost as much time as it did, and when particles come
  loose;
- ``amg``: the smoothed-aggregation AMG of the intact network (particles aggregated, six dofs each, as the
  static solver's ``amg``) as the preconditioner of CG on the damaged one (:class:`IterativeResolver`: the
  numba bond operator, no matrix kept for it), warm-started from the last solution, to an absolute residual
  of ``rtol`` |b| (``compression.resolve_rtol``, 1e-6: quickstart at d = 40 nm, first 60 events, 8.4
  iterations an event; strength within 2e-5 of the factor's at d = 60 nm; 1e-9 took 21 an event; 1e-5 keeps
  the factor's strength within 0.7 %, bench/results/quasistatic_tolerance.json); fits samples the factor
  does not;
- ``block-amg``: the same CG with the static solver's block-amg preconditioner of the intact one: nothing
  assembled but K_uu in float32, what fits the paper's sample; a symmetric block Gauss-Seidel sweep
  (rotations, translations, rotations) whose two bond-operator products carry the coupling of translations
  and rotations that a broken bond's load mostly is (without them, V-cycle and block Jacobi side by side:
  ~3x the iterations of ``amg``, 31 an event at d = 40 nm; with them, the paper's sample at d = 30 nm, its
  rule, 105 events: 904 -> 464 CG iterations);
- the local step (``compression.local_rtol`` > 0, any re-solve): an event first settles by a solve over
  the particles within :data:`LOCAL_HOPS` bonds of its broken ones, the rest held (:class:`LocalSettle`),
  and is re-solved globally only once the residual left passes ``local_rtol`` |b|;
- ``auto``: ``direct`` up to DIRECT_MAX_DOFS free degrees of freedom (the static solver's bound; the
  factor's fill grows fast in 3D), ``amg`` up to RESOLVE_AMG_MAX_BONDS bonds, ``block-amg`` above (what fits).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from opalflow.bpm.contacts import Contacts, joined
from opalflow.bpm.loading import Supports
from opalflow.bpm.spec import BREAKING_RULES, RESOLVERS
from opalflow.bpm.static import (DIRECT_MAX_DOFS, block_amg_preconditioner, block_matrix, bond_blocks, intact,
                                  particle_amg)
from opalflow.bpm.stiffness import PARTS_MIN_BONDS, BondNetwork
from opalflow.jit import njit
from opalflow.linalg.direct import Factor, in_parts, kernel_threads
from opalflow.linalg.krylov import Stop, pcg
from opalflow.spec import InputError


#: ``auto`` takes ``amg`` up to this many bonds, ~9 GiB (a bound of memory, where the static solver's
#: AMG_MAX_BONDS is one of speed): a run with its 6 x 6 hierarchy (and the reversed copies the V-cycle kept
#: then) peaked at 4.15 GiB at 1.81 M bonds (the paper's sample at d = 30 nm); at the paper's own 17.5 M bonds its
#: K alone is 9.8 GiB (15.9 GiB while assembled), with the hierarchy past 15: ``block-amg`` above
RESOLVE_AMG_MAX_BONDS = 4_000_000


@dataclass
class Strengths:
    """Each bond's critical normal and shear force and bending and twisting torque (pN, pN nm), and the
    breaking rule that weighs them (one of :data:`opalflow.bpm.spec.BREAKING_RULES`, module docstring).  With
    ``index`` (M,) the four arrays are tables and bond b's values are at ``index[b]`` (a bond's strengths are
    its type's: the paper's 17.5 M bonds hold a table of a few rows and the types they have, not four arrays
    of 0.13 GiB each)."""

    fr_c: np.ndarray
    fs_c: np.ndarray
    tb_c: np.ndarray
    tt_c: np.ndarray
    rule: str = "lammps"
    index: np.ndarray | None = None

    def part(self, bonds: np.ndarray) -> "Strengths":
        """The strengths of ``bonds`` alone, one row a bond."""
        at = bonds if self.index is None else self.index[bonds]
        return Strengths(self.fr_c[at], self.fs_c[at], self.tb_c[at], self.tt_c[at], self.rule)


def breaking_index(net: BondNetwork, x: np.ndarray, c: Strengths) -> np.ndarray:
    """The breaking index of every bond (LAMMPS's B, not clipped, or the paper's, by ``c.rule``) for
    displacements and rotations x (N, 6) (module docstring): the bond forces from the numba operator
    (:meth:`BondNetwork.bond_forces`), the rest in one numba pass (:func:`_bond_checks`; at 1.8 M bonds
    0.08 s where numpy's gathers and norms took 0.7, once an event): LAMMPS's B is the sum of its two checks,
    every other rule's index the largest of its checks (folded in the pass: no table of every bond's checks)."""
    return _checks_of(net, x, c, 1 if c.rule == "lammps" else 2)[0]


#: the checks of each breaking rule (:func:`bond_checks`, rows in this order; a broken bond's check is the largest
#: at its event), as results.h5 numbers them
CHECKS = {"lammps": ("normal + bending", "shear + twist"),
          "dosta": ("normal + bending", "shear + twist"),
          "musen": ("normal + bending", "shear + twist"),
          "musen_2020": ("bending - normal", "twist - shear"),
          "musen_crit2": ("normal", "bending", "shear", "twist")}
if set(CHECKS) != set(BREAKING_RULES):        # (one list of rules: the spec's; a rule needs its checks here)
    raise ImportError(f"opalflow.bpm.quasistatic.CHECKS lacks or adds rules: {set(CHECKS) ^ set(BREAKING_RULES)}")
#: each rule's number in the numba pass
_RULE_CODE = {rule: k for k, rule in enumerate(CHECKS)}
_DOSTA, _MUSEN_2020, _MUSEN_CRIT2 = _RULE_CODE["dosta"], _RULE_CODE["musen_2020"], _RULE_CODE["musen_crit2"]


def bond_checks(net: BondNetwork, x: np.ndarray, c: Strengths) -> np.ndarray:
    """The checks of every bond for x (N, 6), one row each (:data:`CHECKS` names them), each a load over its
    strength, with the four ratios r_n = Fr / Fcr (Fr signed, tension positive), r_b = |Tb| / Tcb,
    r_s = |Fs| / Fcs and r_t = |Tt| / Tct (Dosta et al. eqs. 16-17; Fcr = sigma A, Tcb = sigma I / r_b,
    Fcs = tau A, Tct = tau J / r_b: :class:`opalflow.materials.BondCoefficients`):

    - ``"lammps"``, ``"musen"``: r_n + r_b and r_s + r_t (LAMMPS's B is their sum, MUSEN's ``CONSIDER_BREAKAGE 1``
      of today their larger);
    - ``"dosta"``: |r_n| + r_b and r_s + r_t (the paper's eqs. 16-17 as printed);
    - ``"musen_2020"``: |r_b - |r_n|| for a bond in tension (0 in compression) and |r_t - r_s|: MUSEN's first
      public code, 655e066 (2020-07-23), Models/SolidBonds/BondModelElastic/ModelSBElastic.cpp (CPU) and
      ModelSBElastic.cu (GPU, ``CUDA_CalcSBForce_E_kernel``), the same in both: ``dMaxStress = -|F_n| / A +
      |M_b| d / (2 I)``, ``dMaxTorque = -|F_t| / A + |M_t| d / (4 I)``, broken when ``|dMaxStress| >= sigma``
      for a bond with ``dStrainTotal > 0`` (``COMPRESSIVE_BREAK`` 0, its default) or ``|dMaxTorque| >= tau``
      (d = 2 r_b, I = pi r_b^4 / 4: d / (2 I) = r_b / I, d / (4 I) = r_b / J); the terms cancel where the paper's
      equations add them.  Unchanged up to Release 1.70.0 (1547403, 2021-02-26), which brought the additive rule;
    - ``"musen_crit2"``: r_n, r_b for a bond in tension (0 in compression), r_s, r_t: MUSEN's
      ``CONSIDER_BREAKAGE 2`` (since 1547403; today's ModelSBElastic.cpp and .cu, "alternative breakage
      criteria": ``maxStress1 >= sigma || maxStress2 >= sigma && dStrainTotal > 0 || maxTorque1 >= tau ||
      maxTorque2 >= tau``, maxStress1 the signed normal stress).

    Every check is positively homogeneous in x, as the events of :func:`solve_fracture` need."""
    return _checks_of(net, x, c, 0)


def _checks_of(net: BondNetwork, x: np.ndarray, c: Strengths, fold: int) -> np.ndarray:
    """:func:`_bond_checks` for x (N, 6): every check (``fold`` 0), or one row, their sum (1) or their largest (2);
    the bond forces and the checks on the process's threads, each a share of the bonds (from
    :data:`opalflow.bpm.stiffness.PARTS_MIN_BONDS`; each bond's checks its own: the same digits)."""
    m = len(net.L)
    threads = kernel_threads() if m >= PARTS_MIN_BONDS else 1
    F = net.bond_forces(x[:, :3], x[:, 3:], threads=threads)
    checks = np.empty((1 if fold else len(CHECKS[c.rule]), m))
    theta = np.ascontiguousarray(x[:, 3:])
    at = np.linspace(0, m, threads + 1).astype(np.int64)

    def share(k: int) -> None:
        b = slice(at[k], at[k + 1])
        strengths = (c.fr_c, c.fs_c, c.tb_c, c.tt_c, c.index[b]) if c.index is not None else (
            c.fr_c[b], c.fs_c[b], c.tb_c[b], c.tt_c[b], np.zeros(0, np.int32))
        _bond_checks(net.i[b], net.j[b], net.n[b], net.bend[b], net.twist[b], F[b], theta, *strengths,
                     _RULE_CODE[c.rule], fold, checks[:, b])
    in_parts(share, threads)
    return checks


@njit(cache=True, nogil=True)
def _bond_checks(i, j, n, bend, twist, F, theta, fr_c, fs_c, tb_c, tt_c, index, rule, fold, out):
    by_type = index.shape[0] > 0
    got = np.empty(4)
    for b in range(out.shape[1]):
        p, q = i[b], j[b]
        k = index[b] if by_type else b
        fr = n[b, 0] * F[b, 0] + n[b, 1] * F[b, 1] + n[b, 2] * F[b, 2]
        d0, d1, d2 = theta[p, 0] - theta[q, 0], theta[p, 1] - theta[q, 1], theta[p, 2] - theta[q, 2]
        tw = n[b, 0] * d0 + n[b, 1] * d1 + n[b, 2] * d2
        fs = math.sqrt((F[b, 0] - fr * n[b, 0]) ** 2 + (F[b, 1] - fr * n[b, 1]) ** 2 + (F[b, 2] - fr * n[b, 2]) ** 2)
        bt = math.sqrt((d0 - tw * n[b, 0]) ** 2 + (d1 - tw * n[b, 1]) ** 2 + (d2 - tw * n[b, 2]) ** 2)
        r_n, r_b = fr / fr_c[k], bend[b] * bt / tb_c[k]
        r_s, r_t = fs / fs_c[k], twist[b] * abs(tw) / tt_c[k]
        count = 2
        if rule == _DOSTA:
            got[0], got[1] = abs(r_n) + r_b, r_s + r_t
        elif rule == _MUSEN_2020:
            got[0], got[1] = abs(r_b - r_n) if fr > 0.0 else 0.0, abs(r_t - r_s)
        elif rule == _MUSEN_CRIT2:
            got[0], got[1], got[2], got[3] = r_n, r_b if fr > 0.0 else 0.0, r_s, r_t
            count = 4
        else:                                           # lammps, musen
            got[0], got[1] = r_n + r_b, r_s + r_t
        if fold == 0:
            for c in range(count):
                out[c, b] = got[c]
        else:       # (a loop: a slice's sum or max costs ~30 ns a bond in numba, 0.5 s a pass at d = 15 nm)
            v = got[0]
            for c in range(1, count):
                v = v + got[c] if fold == 1 else max(v, got[c])
            out[0, b] = v


class StiffnessMatrix:
    """K of the intact bonds as a 6 x 6 block sparse (BSR) matrix, (N + 2 M) blocks: each particle's
    diagonal block and each bond's two off-diagonal ones, at known places, so that a broken bond's 12 x 12
    block is subtracted in place (no coordinate list: the paper-scale memory is the blocks alone)."""

    def __init__(self, net: BondNetwork):
        self.net = net
        self.K, self.pos = block_matrix(net, sum_duplicates=False)     # (each element's blocks where pos says)

    def _add(self, data: np.ndarray, bonds: np.ndarray, blocks: np.ndarray, sign: float) -> None:
        n, m = self.net.n_particles, len(self.net.L)
        i, j = self.net.i[bonds], self.net.j[bonds]
        np.add.at(data, self.pos[i], sign * blocks[:, :6, :6])
        np.add.at(data, self.pos[j], sign * blocks[:, 6:, 6:])
        data[self.pos[n + bonds]] += sign * blocks[:, :6, 6:]
        data[self.pos[n + m + bonds]] += sign * blocks[:, 6:, :6]

    def block(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """The 12 dofs (u_i, theta_i, u_j, theta_j) of bond ``b`` and its 12 x 12 block."""
        i, j = int(self.net.i[b]), int(self.net.j[b])
        dofs = np.concatenate([6 * i + np.arange(6), 6 * j + np.arange(6)])
        return dofs, bond_blocks(self.net.part(slice(b, b + 1)))[0]

    def remove(self, bonds: np.ndarray) -> None:
        bonds = np.asarray(bonds, np.int64)
        if len(bonds):
            self._add(self.K.data, bonds, bond_blocks(self.net.part(bonds)), -1.0)

    def restore(self, bonds: np.ndarray) -> None:
        """Put removed bonds (contacts that close) back."""
        bonds = np.asarray(bonds, np.int64)
        if len(bonds):
            self._add(self.K.data, bonds, bond_blocks(self.net.part(bonds)), 1.0)

    def free_part(self, free: np.ndarray):
        """K_ff (CSR) on the free dofs."""
        K = self.K.tocsr()
        K.sum_duplicates()
        return K[free][:, free]


class DirectResolver:
    """Cholesky factor of K_ff with Woodbury updates for the bonds removed (and contacts put back) since
    (module docstring).

    K_ff - U C U^T, U (n x R) the eigenvectors of the removed blocks (<= 6 per bond, 12 entries each, kept
    as index and value rows), C their eigenvalues: x = y + W S^-1 U^T y with y = A^-1 b, W = A^-1 U and
    S = C^-1 - U^T W.  The factor is renewed when the time spent on the update since the last one exceeds
    the factorisation's own (the classic balance), when the columns would pass ``memory_bytes``, and when
    particles come loose (their dofs leave the free set)."""

    name = "direct"

    def __init__(self, km: StiffnessMatrix, free: np.ndarray, memory_bytes: float = 1.5e9):
        self.km, self.memory_bytes = km, memory_bytes
        self.factorizations = 0
        self._factor(free)

    def _factor(self, free: np.ndarray) -> None:
        t = time.perf_counter()
        self.free = free.copy()
        self.index = np.full(free.size, -1)
        nf = int(free.sum())
        self.index[free] = np.arange(nf)
        self.factor = Factor(self.km.free_part(free))
        cap = int(max(6, min(3000, self.memory_bytes / 8 / max(nf, 1))))
        self.W = np.zeros((nf, cap))
        self.Uidx = np.zeros((cap, 12), np.int64)
        self.Uval = np.zeros((cap, 12))
        self.S = np.zeros((cap, cap))
        self.R = 0
        self.last = None                                   # (b, A^-1 b) of the last solve
        self.factorizations += 1
        self.factor_s, self.update_s = time.perf_counter() - t, 0.0

    def _inverse(self, b: np.ndarray) -> np.ndarray:
        return self.factor.solve(b)

    def _columns(self, bonds: np.ndarray):
        """The Woodbury columns of the removed bonds: (index rows, value rows, 1 / eigenvalues)."""
        idx, val, cinv = [], [], []
        for b in bonds:
            dofs, block = self.km.block(b)
            dofs = self.index[dofs]
            keep = dofs >= 0
            w, V = np.linalg.eigh(block[np.ix_(keep, keep)])
            for k in np.flatnonzero(w > 1e-12 * max(float(w.max(initial=0.0)), 1e-300)):
                row_i, row_v = np.zeros(12, np.int64), np.zeros(12)
                row_i[:keep.sum()], row_v[:keep.sum()] = dofs[keep], V[:, k]
                idx.append(row_i)
                val.append(row_v)
                cinv.append(1.0 / w[k])
        return np.array(idx, np.int64).reshape(-1, 12), np.array(val).reshape(-1, 12), np.array(cinv)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return self.km.K @ x

    def remove(self, bonds: np.ndarray, free: np.ndarray) -> None:
        self.km.remove(bonds)
        self._update(bonds, free, 1.0)

    def add(self, bonds: np.ndarray) -> None:
        """Put elements back (contacts that close): the same update with the blocks' sign turned."""
        self.km.restore(bonds)
        self._update(bonds, self.free, -1.0)

    def _update(self, bonds: np.ndarray, free: np.ndarray, sign: float) -> None:
        """K_ff - sign U C U^T for the blocks of ``bonds``: Woodbury columns, or a new factor (class docstring)."""
        t = time.perf_counter()
        if np.any(self.free & ~free) or self.update_s > self.factor_s or self.R + 6 * len(bonds) > len(self.S):
            self._factor(free)       # (at most 6 columns a bond)
            return
        idx, val, cinv = self._columns(bonds)
        k = len(cinv)
        if not k:
            return
        dense = np.zeros((self.W.shape[0], k))
        np.add.at(dense, (idx, np.arange(k)[:, None]), val)
        R = self.R
        W_new = self._inverse(dense)
        self.W[:, R:R + k] = W_new
        self.Uidx[R:R + k], self.Uval[R:R + k] = idx, val
        self.R += k
        cross = self._ut(W_new)                            # U^T W_new, (R + k, k)
        self.S[:R + k, R:R + k] = -cross
        self.S[R:R + k, :R] = -cross[:R].T
        self.S[np.arange(R, R + k), np.arange(R, R + k)] += sign * cinv
        self.update_s += time.perf_counter() - t

    def _ut(self, v: np.ndarray) -> np.ndarray:
        """U^T v for v (n,) or (n, k)."""
        R = self.R
        if v.ndim == 1:
            return np.sum(self.Uval[:R] * v[self.Uidx[:R]], axis=1)
        return np.einsum("ra,rak->rk", self.Uval[:R], v[self.Uidx[:R]])

    def solve(self, b: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, int]:
        """x with K_ff x = b on the free dofs (the full vector; prescribed entries of b are copied)."""
        bf = b[self.free]
        if self.last is None or not np.array_equal(bf, self.last[0]):     # b moves only where a broken bond
            self.last = (bf, self._inverse(bf))                          # touched a support: A^-1 b kept
        y = self.last[1]
        if self.R:
            t = time.perf_counter()
            R = self.R
            y = y + self.W[:, :R] @ np.linalg.solve(self.S[:R, :R], self._ut(y))
            self.update_s += time.perf_counter() - t
        x = b.copy()
        x[self.free] = y
        return x, 1


class IterativeResolver:
    """CG on the damaged network (the numba bond operator over the network with its broken bonds masked out:
    nothing assembled for the product, no copy of the network), warm-started from the last solution and
    preconditioned by the preconditioner ``name`` of the network at the start (:data:`PRECONDITIONERS`),
    prescribed dofs kept by an identity block; stops at an absolute residual of ``rtol`` |b|.  The product and
    the preconditioner's own kernels run on the process's thread budget
    (:func:`opalflow.linalg.direct.kernel_threads`: a study's job, one)."""

    factorizations = 1

    def __init__(self, name: str, net: BondNetwork, alive: np.ndarray, free: np.ndarray, positions: np.ndarray,
                 rtol: float):
        self.name, self.rtol, self.free, self.net = name, rtol, free.copy(), net
        self.alive = alive.copy()           # (the preconditioner's products read it: changed in place)
        self.threads = kernel_threads()
        self._precondition = PRECONDITIONERS[name](net, free, positions, self.threads, self.alive)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return self.net.matvec(x, self.threads, self.alive)

    def remove(self, bonds: np.ndarray, free: np.ndarray) -> None:
        self.alive[bonds] = False
        self.free = free.copy()

    def add(self, bonds: np.ndarray) -> None:
        """Put elements back (contacts that close)."""
        self.alive[bonds] = True

    def solve(self, b: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, int]:
        """CG under one BLAS thread (as the static method's iterative solvers: :func:`opalflow.linalg.direct.solver_threads`):
        BLAS's idle threads spin after numpy's dot products, on the cores the bond operator's threads need."""
        from threadpoolctl import threadpool_limits

        m = self.free.astype(float)

        # the correction d solves K_ff d_f = r0_f with d zero on the prescribed dofs: r0 is zero there, and so are
        # CG's residuals, directions and preconditioned residuals (masked), so its products need no mask on input
        def matvec(v):
            out = self.matvec(v)
            out *= m
            return out

        def precondition(r):
            z = self._precondition(r)
            z *= m
            return z

        x0 = np.where(self.free, x0, b)
        r0 = np.where(self.free, b - self.matvec(m * x0), 0.0)
        scale = float(np.linalg.norm(b))
        if np.linalg.norm(r0) <= self.rtol * scale:
            return x0, 0
        with threadpool_limits(limits=1):
            d, its = pcg(matvec, precondition, r0, Stop(self.rtol * scale / float(np.linalg.norm(r0))),
                         lambda k, r: None, threads=self.threads)
        return x0 + d, its


#: the iterative re-solves' preconditioners (module docstring): (network, free dofs, positions, threads, the bonds
#: intact) -> v -> z
PRECONDITIONERS = {"amg": lambda net, free, positions, threads, alive: particle_amg(intact(net, alive), free,
                                                                                   positions, threads)[1],
                   "block-amg": block_amg_preconditioner}


def _resolver(name: str, net: BondNetwork, alive: np.ndarray, free: np.ndarray, positions: np.ndarray, rtol: float):
    """The re-solver ``name`` for the network with bonds ``alive`` (module docstring)."""
    if name != "direct":
        return IterativeResolver(name, net, alive, free, positions, rtol)
    km = StiffnessMatrix(net)
    km.remove(np.flatnonzero(~alive))
    return DirectResolver(km, free)


#: rounds of the contacts' active set in one solve (:func:`solve_fracture`)
CONTACT_ITERATIONS = 50


#: an event's broken bonds settle first by a local solve over the particles within this many intact bonds of
#: them (:class:`LocalSettle`); measured on the paper's sample at d = 45 nm (amg, event tolerance 0.05,
#: re-solves to 1e-5) against every event re-solved (bench/results/quasistatic_local.json): 2 bonds deep at
#: ``local_rtol`` 1e-4 moves the strength by +11 %, 4 by -1.7 %; at 3e-5, 3 bonds -0.38 %, 4 bonds -0.15 %
LOCAL_HOPS = 4
#: ... and only while the patch has at most this many particles: an event that breaks bonds in many places at
#: once is re-solved globally instead of factorising a patch of its size (the factor's fill grows fast in 3D)
LOCAL_MAX_PARTICLES = 20_000


class LocalSettle:
    """The local step of an event (``compression.local_rtol``): the load a broken bond carried is released
    into the particles within :data:`LOCAL_HOPS` intact bonds of it, the rest held (a Dirichlet patch,
    factorised by :class:`opalflow.linalg.direct.Factor`); the internal force f = K x is kept up to date, so the
    residual left (f on the free dofs: a broken bond's load the patch did not take up, at its rim) is known
    without a product over the whole network.  The caller re-solves globally once it passes the bound.

    A broken bond's load spreads as a force dipole (the displacement falls as 1 / r^2 around it), so the
    patch takes up most of it and leaves a residual of ~1 / r of the load on its rim: ~6x less at 4 bonds
    (d = 45 nm), from a residual that is itself smaller against |b| the finer the sample (a bond carries less
    of the load): the global re-solves come every few events instead of every one."""

    def __init__(self, net: BondNetwork, adjacency: "Adjacency"):
        self.net, self.adjacency = net, adjacency

    def release(self, x: np.ndarray, force: np.ndarray, broken: np.ndarray) -> None:
        """force -= the broken bonds' part of K x (before they leave the network)."""
        parts, sub = _subnetwork(self.net, broken)
        force.reshape(-1, 6)[parts] -= sub.matvec(x.reshape(-1, 6)[parts]).reshape(-1, 6)

    def __call__(self, x: np.ndarray, force: np.ndarray, broken: np.ndarray, alive: np.ndarray,
                 free: np.ndarray) -> np.ndarray | None:
        """x and force (6 N,) in place: the patch around ``broken`` relaxed with everything else held.  Returns
        the bonds whose ends may have moved (the intact ones touching the patch), None (nothing done) where
        the patch would pass :data:`LOCAL_MAX_PARTICLES`."""
        seeds = np.unique(np.concatenate([self.net.i[broken], self.net.j[broken]]))
        patch, bonds = self.adjacency.patch(alive, seeds, LOCAL_HOPS)
        if len(patch) > LOCAL_MAX_PARTICLES:
            return None
        parts, sub = _subnetwork(self.net, bonds)
        movable = free.reshape(-1, 6)[parts] & np.isin(parts, patch)[:, None]
        r = np.where(movable, -force.reshape(-1, 6)[parts], 0.0).ravel()
        d = np.where(movable.ravel(), Factor(block_matrix(sub, movable.ravel())[0]).solve(r), 0.0)
        x.reshape(-1, 6)[parts] += d.reshape(-1, 6)
        force.reshape(-1, 6)[parts] += sub.matvec(d).reshape(-1, 6)
        return bonds


class Adjacency:
    """Each particle's bonds (a CSR list: ``indptr``, ``neighbour``, ``bond``) for searches over the intact ones."""

    def __init__(self, net: BondNetwork):
        n, m = net.n_particles, len(net.L)
        ends = np.concatenate([net.i, net.j])
        order = np.argsort(ends, kind="stable")
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(ends, minlength=n))]).astype(np.int64)
        self.neighbour = np.concatenate([net.j, net.i])[order].astype(np.int32)
        self.bond = (order % m).astype(np.int32)
        self._seen = np.zeros(n, bool)
        self._taken = np.zeros(m, bool)

    def patch(self, alive: np.ndarray, seeds: np.ndarray, hops: int) -> tuple[np.ndarray, np.ndarray]:
        """(the particles within ``hops`` intact bonds of ``seeds``, the intact bonds that touch them)."""
        return _patch(self.indptr, self.neighbour, self.bond, alive, seeds, hops, self._seen, self._taken)

    def still_joined(self, alive: np.ndarray, i: np.ndarray, j: np.ndarray, limit: int = 20_000) -> bool:
        """Whether i[k] still reaches j[k] over intact bonds for every k, each search stopped after ``limit``
        particles (false then: not known).  True means no particle came loose: every path of the network
        before can go round the removed bonds (0.26 ms a bond where the connected components of the whole
        network took 160 ms, the paper's sample at d = 30 nm, 1.8 M bonds, a loaded machine)."""
        return _still_joined(self.indptr, self.neighbour, self.bond, alive, i.astype(np.int64), j.astype(np.int64),
                             limit, self._seen)

    def reached(self, alive: np.ndarray, start: np.ndarray) -> np.ndarray:
        """(N,) bool: the particles an intact bond path joins to one of ``start`` (N,) bool, those included (a
        search from them, where the connected components of a copy of the network's intact bonds held 1.3 GiB
        more at the paper's sample)."""
        return _reached(self.indptr, self.neighbour, self.bond, alive, np.flatnonzero(start))


@njit(cache=True, nogil=True)
def _reached(indptr, neighbour, bond, alive, start):
    seen = np.zeros(len(indptr) - 1, np.bool_)
    stack = np.empty(len(indptr) - 1, np.int64)
    top = 0
    for s in start:
        if not seen[s]:
            seen[s] = True
            stack[top] = s
            top += 1
    while top > 0:
        top -= 1
        p = stack[top]
        for e in range(indptr[p], indptr[p + 1]):
            q = neighbour[e]
            if alive[bond[e]] and not seen[q]:
                seen[q] = True
                stack[top] = q
                top += 1
    return seen


@njit(cache=True, nogil=True)
def _still_joined(indptr, neighbour, bond, alive, i, j, limit, seen):
    for k in range(len(i)):
        found = [i[k]]
        seen[i[k]] = True
        reached = i[k] == j[k]
        head = 0
        while head < len(found) and not reached and len(found) < limit:
            p = found[head]
            head += 1
            for e in range(indptr[p], indptr[p + 1]):
                q = neighbour[e]
                if alive[bond[e]] and not seen[q]:
                    seen[q] = True
                    found.append(q)
                    if q == j[k]:
                        reached = True
                        break
        for p in found:
            seen[p] = False
        if not reached:
            return False
    return True


def _subnetwork(net: BondNetwork, bonds: np.ndarray) -> tuple[np.ndarray, BondNetwork]:
    """(the particles of ``bonds``, sorted; the network of those bonds alone over them, numbered in that order)."""
    parts = np.unique(np.concatenate([net.i[bonds], net.j[bonds]]))
    return parts, BondNetwork(len(parts), np.searchsorted(parts, net.i[bonds]), np.searchsorted(parts, net.j[bonds]),
                              net.n[bonds], net.L[bonds], net.a_r[bonds], net.a_s[bonds], net.bend[bonds],
                              net.twist[bonds])


@njit(cache=True, nogil=True)
def _patch(indptr, neighbour, bond, alive, seeds, hops, seen, taken):
    """(the particles within ``hops`` intact bonds of ``seeds``, the intact bonds that touch them): a
    breadth-first search over the adjacency (indptr, neighbour, bond); ``seen`` and ``taken`` (all false)
    are scratch, left all false."""
    found = [s for s in seeds]
    for s in seeds:
        seen[s] = True
    start = 0
    for _ in range(hops):
        stop = len(found)
        for k in range(start, stop):
            p = found[k]
            for e in range(indptr[p], indptr[p + 1]):
                if alive[bond[e]] and not seen[neighbour[e]]:
                    seen[neighbour[e]] = True
                    found.append(neighbour[e])
        start = stop
    patch = np.array(found)
    out = np.empty(sum([indptr[p + 1] - indptr[p] for p in found]), np.int64)
    count = 0
    for p in patch:
        for e in range(indptr[p], indptr[p + 1]):
            if alive[bond[e]] and not taken[bond[e]]:
                taken[bond[e]] = True
                out[count] = bond[e]
                count += 1
    out = out[:count]
    for p in patch:
        seen[p] = False
    for b in out:
        taken[b] = False
    return patch, out


class Stopped(Exception):
    """The event loop stopped when asked (a scheduler's signal) after ``events`` events, its state saved."""

    def __init__(self, events: int):
        super().__init__(f"stopped after {events} events")
        self.events = events


@dataclass
class Event:
    """One event: the strain and stress at which it happened, the stress just after, the bonds broken."""

    strain: float
    stress_MPa: float
    stress_after_MPa: float
    bonds: list[int]
    iterations: int = 0
    settled: bool = False       # by the local step alone (no global re-solve)
    checks: list[int] = field(default_factory=list)     # each broken bond's check (an index into CHECKS)
    #: contacts pressing after the event (contacts.quasistatic; the nonlinear method's contacts: touching after it,
    #: or at it where no equilibrium follows)
    contacts: int = 0


@dataclass
class SavedState:
    """What a stopped event loop goes on from: its events, the modulus of its first solve (MPa), and the
    displacements ((N, 6)) just before the peak event ``peak_event`` (-1, None: none kept)."""

    events: list[Event]
    modulus_MPa: float
    peak_event: int = -1
    peak_x: np.ndarray | None = None


@dataclass
class FractureResult:
    modulus_MPa: float
    events: list[Event]
    alive: np.ndarray
    stopped: str
    seconds: float
    setup_seconds: float
    resolver: str
    factorizations: int
    peak_alive: np.ndarray | None = None    # the intact bonds just before the peak event
    peak_x: np.ndarray | None = None        # displacements and rotations (N, 6) just before the peak event
    end_x: np.ndarray | None = None         # ... just after the last event
    loose: int = 0
    unbalanced: list[float] = field(default_factory=list)   # the nonlinear method's states out of balance: max|F|/scale

    @property
    def peak(self) -> int:
        return int(np.argmax([e.stress_MPa for e in self.events])) if self.events else -1


def solve_fracture(net: BondNetwork, strengths: Strengths, positions: np.ndarray, supports: Supports, *,
                   strain_max: float = 0.04, stop_fraction: float = 0.5, events_max: int = 100_000,
                   tolerance: float = 0.0, resolver: str = "auto", rtol: float = 1e-6, local_rtol: float = 0.0,
                   state: SavedState | None = None, checkpoint=None, checkpoint_s: float = 5.0,
                   should_stop=lambda: False,
                   contacts: Contacts | None = None, say=print) -> FractureResult:
    """The event loop of the module docstring under the loading's ``supports``
    (:meth:`opalflow.bpm.loading.Loading.supports`, as in :func:`opalflow.bpm.static.solve_compression`).

    With ``local_rtol`` > 0 an event settles by :class:`LocalSettle` alone while the residual it leaves stays
    below ``local_rtol`` |b|; past it (and whenever particles come loose) the network is re-solved globally,
    to ``rtol`` |b|.

    With ``contacts`` (:mod:`opalflow.bpm.contacts`; not with the local step) the touching pairs no intact bond
    joins press on each other (:class:`LoadedNetwork`: the active set of each solve).

    Stops when the next event would lie beyond ``strain_max``, when the stress after an event has fallen
    below ``stop_fraction`` of the peak, when no path carries load, or after ``events_max`` events.
    ``state`` (a :class:`SavedState`, given to ``checkpoint(state)`` every ``checkpoint_s`` seconds, before
    :class:`Stopped` is raised when ``should_stop()`` turns true, and on Ctrl-C): continue a killed run from its
    events (the broken bonds are theirs) and the displacements just before its peak event (for the fracture
    pictures); the result is the same (with an iterative re-solve or the local step it restarts from a global
    re-solve: the same to the re-solve's tolerance, not to the digit).
    """
    if resolver not in RESOLVERS:
        raise InputError(f"compression.resolver = {resolver!r}: must be one of {', '.join(RESOLVERS)}")
    t0 = time.perf_counter()
    n, m = net.n_particles, len(net.L)
    events = list(state.events) if state else []
    alive = _intact(m, events)
    loaded = LoadedNetwork(net, supports, positions, alive, contacts, resolver, rtol)
    settle = LocalSettle(net, loaded.adjacency) if local_rtol > 0 else None
    setup = time.perf_counter() - t0

    x, force, stress_unit, its, b_norm = loaded.solve(loaded.x_p.copy())
    modulus = state.modulus_MPa if state else stress_unit
    peak_stress, peak_alive, peak_x, peak_event = _restored_peak(state, events, m)

    def save():
        if checkpoint:
            checkpoint(SavedState(list(events), modulus, peak_event, peak_x))

    stopped, touched, B, pace = "events_max", None, None, _Pace(checkpoint_s)
    try:
        while len(events) < events_max:
            if stress_unit <= 0 or not loaded.held.loaded.any():
                stopped = "no load path"
                break
            B = _breaking_indices(net, x, strengths, B, alive, touched)
            worst, strain, why = _next_event(B, strain_max)
            if why:
                stopped = why
                break
            stress = strain * stress_unit
            if stress > peak_stress:
                peak_stress, peak_alive, peak_x = stress, alive.copy(), strain * x.reshape(n, 6)
                peak_event = len(events)
            broken = np.flatnonzero(B >= worst / (1.0 + tolerance))
            checks = _checks(net, x, strengths, broken)
            x, force, stress_unit, its, b_norm, touched, settled = _after_break(
                loaded, settle, broken, x, force, b_norm, local_rtol)
            B[broken] = -np.inf
            events.append(Event(strain, stress, strain * stress_unit, broken.tolist(), its, settled, checks,
                                int(loaded.engaged.sum())))
            if pace.tick(should_stop(), save, lambda: say(_progress_line(
                    events, alive, strain_max, peak_stress, time.perf_counter() - t0 - setup))):
                raise Stopped(len(events))
            if events[-1].stress_after_MPa < stop_fraction * peak_stress:
                stopped = f"stress fell below {stop_fraction:g} of the peak"
                break
    except KeyboardInterrupt:
        save()       # the events so far (an event cut short is not among them)
        raise
    return FractureResult(modulus_MPa=modulus, events=events, alive=alive, stopped=stopped,
                          seconds=time.perf_counter() - t0, setup_seconds=setup, resolver=loaded.solver.name,
                          factorizations=loaded.solver.factorizations, peak_alive=peak_alive, peak_x=peak_x,
                          end_x=events[-1].strain * x.reshape(n, 6) if events else None,
                          loose=int(loaded.loose.sum()))


def _next_event(B: np.ndarray, strain_max: float) -> tuple[float, float, str]:
    """The largest breaking index, the strain of the event it makes (its inverse) and why there is none ("": there
    is one)."""
    worst = float(B.max(initial=-np.inf))
    if worst <= 0:
        return worst, math.inf, "no bond loaded towards breaking"
    strain = 1.0 / worst
    return worst, strain, f"the network holds to strain_max = {strain_max:g}" if strain > strain_max else ""


def _after_break(loaded: LoadedNetwork, settle, broken: np.ndarray, x: np.ndarray, force: np.ndarray,
                 b_norm: float, local_rtol: float) -> tuple:
    """The ``broken`` bonds gone: the local step settles the event where it leaves a residual below ``local_rtol``
    |b| (and no particle came loose), else the network is re-solved.  Returns x, force, stress per unit strain,
    iterations, |b|, the bonds the local step touched (None after a re-solve) and whether it settled."""
    if settle:
        settle.release(x, force, broken)
    came_loose = loaded.break_bonds(broken)
    touched = settle(x, force, broken, loaded.alive, loaded.free) if settle and not came_loose else None
    if touched is not None and np.linalg.norm(force[loaded.free]) <= local_rtol * b_norm:
        return x, force, loaded.stress(force), 0, b_norm, touched, True
    x, force, stress_unit, its, b_norm = loaded.solve(x)
    return x, force, stress_unit, its, b_norm, None, False


def _restored_peak(state: SavedState | None, events: list[Event], m: int) -> tuple:
    """Where a resumed run's peak stood: its stress, the bonds intact before it, the displacements just before it
    as the state kept them (``peak_event``: the event they precede; an event cut short by Ctrl-C may have set
    them without being kept: then None) and that event's index (-1: none kept)."""
    peak = int(np.argmax([e.stress_MPa for e in events])) if events else 0
    peak_x = (np.asarray(state.peak_x, float) if state and state.peak_x is not None and state.peak_event == peak
              else None)
    return (events[peak].stress_MPa if events else 0.0, _intact(m, events[:peak]) if events else None, peak_x,
            peak if peak_x is not None else -1)


class _Pace:
    """When an event loop says where it stands (every 10 s) and keeps its state (every ``checkpoint_s`` and
    when it is told to stop)."""

    def __init__(self, checkpoint_s: float):
        self.checkpoint_s = checkpoint_s
        self.said = self.saved = time.perf_counter()

    def tick(self, stop: bool, save, tell) -> bool:
        """After an event: ``tell()`` where it stands, ``save()`` the state when it is time (or ``stop``); returns
        ``stop``."""
        now = time.perf_counter()
        if now - self.said > 10:
            self.said = now
            tell()
        if stop or now - self.saved > self.checkpoint_s:
            self.saved = now
            save()
        return stop


def _breaking_indices(net: BondNetwork, x: np.ndarray, strengths: Strengths, B: np.ndarray | None,
                      alive: np.ndarray, touched: np.ndarray | None) -> np.ndarray:
    """B of each bond at unit strain (:func:`breaking_index`; -inf for the broken ones): of every bond after a
    global re-solve (``touched`` None), else ``B`` with the bonds a local step ``touched`` brought up to date."""
    n = net.n_particles
    if touched is None:
        B = breaking_index(net, x.reshape(n, 6), strengths)
        B[~alive] = -np.inf
        return B
    parts, sub = _subnetwork(net, touched)
    B[touched] = breaking_index(sub, x.reshape(n, 6)[parts], strengths.part(touched))
    return B


def _checks(net: BondNetwork, x: np.ndarray, strengths: Strengths, broken: np.ndarray) -> list[int]:
    """Which check (an index into the rule's :data:`CHECKS`: the largest, the first of equals) breaks each of the
    ``broken`` bonds."""
    ends, pair = _subnetwork(net, broken)
    return bond_checks(pair, x.reshape(net.n_particles, 6)[ends], strengths.part(broken)).argmax(axis=0).tolist()


def _progress_line(events: list[Event], alive: np.ndarray, strain_max: float, peak_stress: float,
                   seconds: float) -> str:
    """The event loop's progress: events, bonds broken, strain and stress reached, the rate and the time left."""
    rate = len(events) / max(seconds, 1e-9)
    reached = max(e.strain for e in events)
    # the rest up to strain_max at the events per strain so far: a lower bound while the events come faster as
    # damage spreads (before the peak), an upper one after (the run stops early)
    left = (strain_max - reached) * len(events) / reached / rate
    return (f"quasi-static: event {len(events)}, {int((~alive).sum())} bonds broken, strain {events[-1].strain:.5f} "
            f"(max {strain_max:g}), stress {events[-1].stress_MPa:.4g} MPa (peak {peak_stress:.4g}), "
            f"{rate:.1f} events/s, ~{left:.0f} s left to strain_max at the events per strain so far")


class LoadedNetwork:
    """The bond network under its loading's supports while bonds break: the particles that came loose held
    still, the re-solver over the intact bonds (with contacts: and the contacts pressing), and the solve
    (:meth:`solve`) with the contacts' active set.  ``alive`` (the intact bonds) is the caller's, changed in
    place by :meth:`break_bonds`.

    The contacts' active set: after every global solve the contacts in tension open and those pressed close,
    and the network is solved again until none changes (at most :data:`CONTACT_ITERATIONS` rounds; each event's
    re-solves count them).  A contact that opens stays open for the rest of that solve: with a sticking
    tangential spring a contact can pull its own pair apart (closed it is in tension, open it is pressed:
    Coulomb's law would give it no force either way), and the rounds would flip it for ever."""

    def __init__(self, net: BondNetwork, supports: Supports, positions: np.ndarray, alive: np.ndarray,
                 contacts: Contacts | None, resolver: str, rtol: float):
        self.net, self.supports, self.contacts, self.alive = net, supports, contacts, alive
        self.n, self.m = net.n_particles, len(net.L)
        self.adjacency = Adjacency(net)
        self.constrain(self.loose_of(alive))
        if resolver == "auto":
            resolver = ("direct" if self.free.sum() <= DIRECT_MAX_DOFS
                        else "amg" if self.m <= RESOLVE_AMG_MAX_BONDS else "block-amg")
        whole = joined(net, contacts.net) if contacts else net
        self.engaged = contacts.usable(alive, self.loose) if contacts else np.zeros(0, bool)
        self.solver = _resolver(resolver, whole, np.concatenate([alive, self.engaged]), self.free, positions, rtol)

    def loose_of(self, alive: np.ndarray) -> np.ndarray:
        """The particles no intact bond path joins to an anchored one (:meth:`Adjacency.reached`)."""
        return ~self.adjacency.reached(alive, self.supports.anchored)

    def constrain(self, loose: np.ndarray) -> None:
        """Hold the ``loose`` particles still: the free dofs and the prescribed displacements at unit strain."""
        self.loose = loose
        self.held = self.supports.without(loose)
        self.free, self.x_p = ~self.held.held.ravel(), self.held.drive.ravel()

    def stress(self, force: np.ndarray) -> float:
        return self.held.stress(force)      # per unit strain, > 0

    def break_bonds(self, broken: np.ndarray) -> bool:
        """Take the ``broken`` bonds out (of ``alive`` and the re-solver); True when particles came loose."""
        self.alive[broken] = False
        came_loose = False
        if not self.adjacency.still_joined(self.alive, self.net.i[broken], self.net.j[broken]):
            new_loose = self.loose_of(self.alive)
            came_loose = bool(np.any(new_loose & ~self.loose))
            if came_loose:
                self.constrain(new_loose)
        self.solver.remove(broken, self.free)
        return came_loose

    def linear_solve(self, x_prev: np.ndarray):
        b = np.where(self.free, -self.solver.matvec(self.x_p), self.x_p)
        x, its = self.solver.solve(b, x_prev)
        force = self.solver.matvec(x)
        return x, force, self.stress(force), its, float(np.linalg.norm(b))

    def solve(self, x_prev: np.ndarray):
        """(x, the internal force K x, the stress per unit strain, CG iterations, |b|): the linear solve, and with
        contacts the active set: those in tension open, those pressed close, solved again until none changes."""
        x, force, stress, its, b_norm = self.linear_solve(x_prev)
        contacts, engaged = self.contacts, self.engaged
        opened = np.zeros(len(engaged), bool)
        for _ in range(CONTACT_ITERATIONS if contacts else 0):
            usable = contacts.usable(self.alive, self.loose)
            stretch = contacts.stretch(x.reshape(self.n, 6))
            tol = 1e-9 * float(np.abs(x).max())          # (a pair that neither presses nor separates stays)
            opening = np.flatnonzero(engaged & ((stretch > tol) | ~usable))
            closing = np.flatnonzero(~engaged & usable & ~opened & (stretch < -tol))
            if not len(opening) and not len(closing):
                break
            engaged[opening], engaged[closing] = False, True
            opened[opening] = True
            self.solver.remove(self.m + opening, self.free)
            self.solver.add(self.m + closing)
            x, force, stress, more, b_norm = self.linear_solve(x)
            its += more
        return x, force, stress, its, b_norm


def _intact(m: int, events: list[Event]) -> np.ndarray:
    """The bonds intact after ``events``."""
    alive = np.ones(m, bool)
    for e in events:
        alive[e.bonds] = False
    return alive


@dataclass
class PeakFacts:
    """What a fracture run came to: E of the first branch, the strength and its strain (nan: no event), the
    events and the bonds broken in all and before the peak."""

    youngs_modulus_GPa: float
    strength_MPa: float
    strain_at_peak: float
    events: int
    broken_bonds: int
    broken_bonds_at_peak: int
    energy_to_peak_kJ_m3: float | None = None


def peak_facts(res: FractureResult) -> PeakFacts:
    """Strength, strain at peak, E of the first branch, the event counts and the energy to the peak: the area
    under the saw-tooth up to the peak (between events the network is linear, stress on a line through the
    origin, so the trapezoids are exact)."""
    if not res.events:
        return PeakFacts(res.modulus_MPa / 1e3, math.nan, math.nan, 0, 0, 0)
    p = res.peak
    strain = [0.0] + [x for e in res.events[:p] for x in (e.strain, e.strain)] + [res.events[p].strain]
    stress = ([0.0] + [x for e in res.events[:p] for x in (e.stress_MPa, e.stress_after_MPa)]
              + [res.events[p].stress_MPa])
    return PeakFacts(res.modulus_MPa / 1e3, res.events[p].stress_MPa, res.events[p].strain, len(res.events),
                     int((~res.alive).sum()), sum(len(e.bonds) for e in res.events[:p]),
                     float(np.trapezoid(stress, strain)) * 1e3)
