"""The peer of the static solver: the zero-rate modulus by LAMMPS alone, damped dynamics to rest.

What a LAMMPS user does instead of ``compression.method = "static"`` (``minimize`` cannot: bpm/rotational
reports no energy, so cg and sd stop after one iteration, and fire moves positions only, the rotations stay
locked).  The deck is the run's own (:func:`opalflow.bpm.deck.compression_deck`: the same data file, groups,
bonds and time step) with bonds that neither break nor smooth, no contacts (they carry no load at the
reference state, as in the static solve) and no plate; instead ``templates/relax.lmp``: the top layer
displaced by strain x H and held in z (its x, y and rotations free: the static solve's frictionless plate;
glued: held in all six), ``fix viscous`` and ``fix viscous/sphere`` on the moving particles, and E from the
top layer's force, sampled into ``relax.txt``.

The drag is set from the sample's lowest axial mode (omega_1 of the deck, from the affine modulus):
gamma = damping x 2 m omega_1, the critical drag of that mode for ``damping`` = 1; the spin drag gives
the spins the same rate, gamma_spin = gamma x (2/5) r^2 (a sphere's I / m).  bench/bench_peer.py tunes
``damping`` and the step count knowing the answer, as a user who had it would.
"""
from __future__ import annotations

import re

import numpy as np

from opalflow.bpm.deck import CompressionDeck
from opalflow.bpm.loading import LOADINGS
from opalflow.lammps.syntax import num, render

#: the blocks of the run's deck the relaxation keeps (the rest: contacts, plate, damping, output, run)
KEPT = ("system", "groups", "bonds", "integration")


def relaxation_deck(deck: CompressionDeck, *, steps: int, damping: float = 1.0, strain: float = 1e-4,
                    every: int = 100, target_MPa: float | None = None, tolerance: float = 1e-3) -> str:
    """The relaxation input script for ``deck`` (see the module docstring); it reads ``data.lmp``.  With
    ``target_MPa`` (the answer, known) the run stops (``fix halt``) at the first sample within ``tolerance``
    of it: the step count a user who knew the answer would choose."""
    parts = re.split(r"(?m)^(?=# --- )", deck.in_lmp)
    kept = [p for p in parts if any(p.startswith(f"# --- {b}:") for b in KEPT)]
    if len(kept) != len(KEPT):
        raise ValueError(f"the deck lacks one of the blocks {', '.join(KEPT)}")
    text = "".join(kept)
    text = re.sub(r"(?m)^(bond_style .*) smooth yes", r"\1 smooth no", text)
    text = re.sub(r"(?m)^(bond_style .*) break yes", r"\1 break no", text)
    s = deck.structure
    mobile = ~s.groups["substrate"]
    masses = s.densities * s.particle_volumes()
    gamma = damping * 2.0 * deck.omega1_per_ns * float(np.mean(masses[mobile]))
    radius = float(np.mean(s.diameters[mobile])) / 2
    if LOADINGS[deck.loading].glued:   # the glued layer is not integrated: it stays where it was put; its force is the sample's
        hold, force = "compute         top_fz top reduce sum fz", "c_top_fz"
    else:
        hold, force = "fix             hold top setforce NULL NULL 0.0", "f_hold[3]"
    sense = deck.loading_sense
    halt = "# (no stop before the last step)"
    if target_MPa is not None:
        halt = (f"variable        relax_error equal abs(v_modulus_MPa/{num(target_MPa)}-1)\n"
                f"fix             stop all halt {num(every)} v_relax_error < {num(tolerance)} error continue")
    return f"# opalflow: damped relaxation to the static modulus ({deck.loading})\n" + text + render(
        "relax", dz=num(-sense * strain * deck.height_nm), hold=hold, gamma=num(gamma),
        gamma_spin=num(gamma * 0.4 * radius**2), force_z=f"{'-' if sense < 0 else ''}{force}",
        area_strain=num(deck.area_nm2 * strain), every=num(every), steps=num(steps), halt=halt)
