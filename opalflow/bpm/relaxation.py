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


#: how the loading is put on before the relaxation: the top layer alone, or every moving particle by the
#: affine field (``displace_atoms ramp``: 0 at the substrate's highest centre, the top layer's displacement at
#: its mean centre height)
STARTS = ("top", "affine")


def relaxation_deck(deck: CompressionDeck, *, steps: int, damping: float = 1.0, strain: float = 1e-4,
                    every: int = 100, target_MPa: float | None = None, tolerance: float = 1e-3,
                    start: str = "top", timestep_factor: float = 1.0, newton_bond: bool = False) -> str:
    """The relaxation input script for ``deck`` (see the module docstring); it reads ``data.lmp``.  With
    ``target_MPa`` (the answer, known) the run stops (``fix halt``) at the first sample within ``tolerance``
    of it: the step count a user who knew the answer would choose.

    What a user tunes: ``start`` (:data:`STARTS`; the affine start leaves only the non-affine relaxation to
    the dynamics), ``timestep_factor`` (x the run's time step, which is ``compression.timestep_safety`` of the
    limit of the undamped motion), ``newton_bond`` (``newton on on``: each bond computed once, its forces
    sent back to the partner's owner; the same forces)."""
    if start not in STARTS:
        raise ValueError(f"start = {start!r}: must be one of {', '.join(STARTS)}")
    parts = re.split(r"(?m)^(?=# --- )", deck.in_lmp)
    kept = [p for p in parts if any(p.startswith(f"# --- {b}:") for b in KEPT)]
    if len(kept) != len(KEPT):
        raise ValueError(f"the deck lacks one of the blocks {', '.join(KEPT)}")
    text = "".join(kept)
    text = re.sub(r"(?m)^(bond_style .*) smooth yes", r"\1 smooth no", text)
    text = re.sub(r"(?m)^(bond_style .*) break yes", r"\1 break no", text)
    if newton_bond:
        text = re.sub(r"(?m)^newton +on off$", "newton          on on", text)
    if timestep_factor != 1.0:
        text = re.sub(r"(?m)^timestep +\S+$", f"timestep        {num(deck.dt_ns * timestep_factor)}", text)
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
    dz = -sense * strain * deck.height_nm
    displace = f"displace_atoms  top move 0 0 {num(dz)} units box"
    if start == "affine":          # the interior by the ramp from the substrate's highest centre (0) to the top layer's (dz)
        held_z = float(s.positions[s.groups["substrate"], 2].max())
        displace = ("group           interior subtract mobile top\n"
                    f"displace_atoms  interior ramp z 0.0 {num(dz)} z {num(held_z)} {num(deck.top_z0_nm)} units box\n"
                    + displace)
    return f"# opalflow: damped relaxation to the static modulus ({deck.loading})\n" + text + render(
        "relax", displace=displace, hold=hold, gamma=num(gamma),
        gamma_spin=num(gamma * 0.4 * radius**2), force_z=f"{'-' if sense < 0 else ''}{force}",
        area_strain=num(deck.area_nm2 * strain), every=num(every), steps=num(steps), halt=halt)
