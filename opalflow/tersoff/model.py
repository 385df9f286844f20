"""Differentiable Tersoff energy of a homogeneously strained diamond crystal (JAX).

The fit (seed 003, section 3) needs the loss eq. 13 and its gradient with respect to the
potential parameters.  Each property is a second derivative of the energy per atom with
respect to a strain (eqs. 14-16), so the loss gradient is a third derivative; it is taken
by automatic differentiation (JAX, compiled with ``jax.jit``; float64) of the exact energy
below, never by finite differences.

Crystal: the two-atom primitive cell of diamond, atoms at 0 and a/4 (1,1,1) (plus an
internal displacement ``u`` of the second sublattice), deformed by ``F``.  Every lattice
image within ``neighbor_radius`` of an atom in the reference crystal is a candidate
neighbour; the cutoff function f_C removes those beyond R + D exactly as LAMMPS does, so
the energy equals LAMMPS's for any R, D whose cutoff lies inside ``neighbor_radius``.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)   # energies differ in the 1e-6 relative digits: float64
import jax.numpy as jnp  # noqa: E402

from opalflow.tersoff.parameters import COLUMNS, TersoffParameters

EV_PER_A3_GPA = 160.21766208   # 1 eV/Angstrom^3 in GPa
INDEX = {k: i for i, k in enumerate(COLUMNS)}


def diamond_neighbors(radius_over_a: float = 0.62) -> tuple[np.ndarray, np.ndarray]:
    """Reference neighbour vectors (in units of a) of the two sublattices and a sublattice flag.

    Returns ``vec`` (2, K, 3): vectors from atom s (0 at the origin, 1 at (1,1,1)/4) to its K
    neighbours within ``radius_over_a`` (default 0.62 a = 3.37 A at a = 5.431: first shell
    only, second at a/sqrt(2)), and ``flip`` (2, K): +1 where the neighbour is on the other
    sublattice (its vector moves by +u when s = 0, -u when s = 1), 0 on the same one.
    """
    fcc = np.array([[0, .5, .5], [.5, 0, .5], [.5, .5, 0]])
    basis = np.array([[0, 0, 0], [.25, .25, .25]])
    vec, flip = [], []
    for s in range(2):
        vs, fs = [], []
        for n in itertools.product(range(-3, 4), repeat=3):
            for t in range(2):
                v = np.asarray(n) @ fcc + basis[t] - basis[s]
                r = np.linalg.norm(v)
                if 1e-9 < r <= radius_over_a:
                    vs.append(v)
                    fs.append(0.0 if t == s else (1.0 if s == 0 else -1.0))
        order = np.lexsort(np.array(vs).T)
        vec.append(np.array(vs)[order])
        flip.append(np.array(fs)[order])
    return np.array(vec), np.array(flip)


def neighbor_radius(cutoff: float, a: float) -> float:
    """Candidate-neighbour radius (units of a) that reaches past the cutoff R + D by 10 % (strain)."""
    return max(0.5, 1.1 * cutoff / a)


def _cutoff(r, R, D):
    """f_C(r), smooth sine switch between R - D and R + D."""
    inner = 0.5 * (1.0 - jnp.sin(0.5 * np.pi * (r - R) / D))
    return jnp.where(r < R - D, 1.0, jnp.where(r > R + D, 0.0, inner))


def site_energies(x, rv):
    """Tersoff energy of each atom, 1/2 sum_k V_ik (eV), from its bond vectors ``rv`` (..., K, 3).

    ``x``: the 14 parameters in COLUMNS order (m must be 1 or 3, as in LAMMPS); ``rv[..., k, :]``
    is the vector from the atom to its k-th candidate neighbour (Angstrom).  Candidates beyond
    R + D contribute nothing (f_C = 0), so any list holding every atom within the cutoff gives
    LAMMPS's energy.  The leading axes are batch axes (atoms, samples).
    """
    g = {k: x[i] for k, i in INDEX.items()}
    r = jnp.sqrt(jnp.sum(rv ** 2, axis=-1))                               # (..., K)
    fc = _cutoff(r, g["R"], g["D"])
    cos = jnp.einsum("...ji,...ki->...jk", rv, rv) / (r[..., :, None] * r[..., None, :])
    c2, d2 = g["c"] ** 2, g["d"] ** 2
    gth = g["gamma"] * (1.0 + c2 / d2 - c2 / (d2 + (cos - g["costheta0"]) ** 2))
    dr = r[..., :, None] - r[..., None, :]                                # r_ij - r_ik
    arg = jnp.where(g["m"] == 3.0, (g["lambda3"] * dr) ** 3, g["lambda3"] * dr)
    k = r.shape[-1]
    off = 1.0 - np.eye(k)
    zeta = jnp.sum(off * fc[..., None, :] * gth * jnp.exp(arg), axis=-1)   # (..., K)
    n = g["n"]
    bij = (1.0 + (g["beta"] * zeta) ** n) ** (-0.5 / n)
    fr = g["A"] * jnp.exp(-g["lambda1"] * r)
    fa = -g["B"] * jnp.exp(-g["lambda2"] * r)
    return 0.5 * jnp.sum(fc * (fr + bij * fa), axis=-1)


def energy_per_atom(x, a: float, F, u, neighbors: tuple[np.ndarray, np.ndarray]):
    """Tersoff energy per atom (eV) of the diamond crystal with lattice constant ``a`` (A).

    ``x``: the 14 parameters in COLUMNS order; ``F``: 3x3 deformation gradient; ``u``: internal
    displacement (A) of the second sublattice.
    """
    vec0, flip = neighbors
    rv = jnp.einsum("ij,skj->ski", F, a * vec0) + flip[:, :, None] * u    # (2, K, 3)
    return jnp.mean(site_energies(x, rv))


def _strained(s):
    """F for the strain vector s = (e_xx, e_yy, gamma_xy): diag(1 + e_xx, 1 + e_yy, 1) plus eq. 14's shear."""
    return jnp.array([[1.0 + s[0], s[2], 0.0], [0.0, 1.0 + s[1], 0.0], [0.0, 0.0, 1.0]])


@dataclass
class DiamondModel:
    """Energy derivatives of the diamond crystal that define the fitted properties.

    With E the energy per atom and Omega = a^3/8 the volume per atom (seed 003, eqs. 14-16):
    B = E''_iso / (9 Omega) for F = (1+e) I; C' = E''_tet / (4 Omega) for F = diag(1+e, 1-e, 1);
    C11 = B + 4C'/3, C12 = B - 2C'/3; C44^0 = E''_shear / Omega for eq. 14 (atoms follow the
    strain); C44 = (E_gg - E_gu^2 / E_uu) / Omega with the second sublattice free to move
    along z (Kleinman relaxation: the exact small-strain limit of relaxing u for each shear).

    One 4x4 Hessian in (e_xx, e_yy, gamma, u_z) gives them all: by cubic symmetry
    E''_iso = 3 H_xx + 6 H_xy and E''_tet = 2 H_xx - 2 H_xy, and a shear in xy couples only to
    u_z (u_x, u_y and the other strains do not enter).  ``properties`` is jit-compiled.
    """

    a: float = 5.431
    neighbor_radius_over_a: float = 0.62

    def __post_init__(self):
        self.neighbors = diamond_neighbors(self.neighbor_radius_over_a)
        nb = self.neighbors

        def energy(v, x, a):        # v = (e_xx, e_yy, gamma, u_z)
            return energy_per_atom(x, a, _strained(v), jnp.array([0.0, 0.0, 1.0]) * v[3], nb)

        def properties(x, a):
            omega = a ** 3 / 8.0
            k = EV_PER_A3_GPA / omega
            zero = jnp.zeros(4)
            ec = energy(zero, x, a)
            g = jax.grad(energy)(zero, x, a)
            h = jax.hessian(energy)(zero, x, a)
            bulk = (3.0 * h[0, 0] + 6.0 * h[0, 1]) / 9.0 * k
            cp = (2.0 * h[0, 0] - 2.0 * h[0, 1]) / 4.0 * k
            return {"Ec_eV": ec, "dE_da_eV_per_A": 3.0 * g[0] / a, "B_GPa": bulk, "Cprime_GPa": cp,
                    "C11_GPa": bulk + 4.0 * cp / 3.0, "C12_GPa": bulk - 2.0 * cp / 3.0,
                    "C44_0_GPa": h[2, 2] * k, "C44_GPa": (h[2, 2] - h[2, 3] ** 2 / h[3, 3]) * k,
                    "d2E_da2": (3.0 * h[0, 0] + 6.0 * h[0, 1]) / a ** 2}

        self._properties = jax.jit(properties)

    def properties(self, x, a: float | None = None) -> dict[str, float]:
        """Ec (eV), dE/da (eV/A per atom), d2E/da2 and the elastic constants (GPa) at lattice constant a."""
        return self._properties(x, self.a if a is None else a)

    def lattice_constant(self, x, a0: float | None = None, tol: float = 1e-12) -> float:
        """Zero-pressure lattice constant by Newton's method on dE/da (A)."""
        a = self.a if a0 is None else a0
        for _ in range(50):
            p = self.properties(x, a)
            curvature = float(p["d2E_da2"])
            if not np.isfinite(curvature) or curvature <= 0:
                raise RuntimeError(f"lattice constant: no energy minimum near a = {a:.4f} A (d2E/da2 = {curvature:g})")
            step = float(p["dE_da_eV_per_A"]) / curvature
            a -= step
            if abs(step) < tol * a:
                return a
        raise RuntimeError("lattice constant: Newton did not converge")

    def evaluate(self, p: TersoffParameters, a: float | None = None) -> dict[str, float]:
        """Plain floats of :meth:`properties` for a parameter set."""
        props = self.properties(jnp.asarray(p.values()), a)
        return {k: float(v) for k, v in props.items() if k != "d2E_da2"}
