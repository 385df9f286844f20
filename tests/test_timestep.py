"""Acceptance 5: the time-step estimate against bisection on real LAMMPS runs.

For each case a small bonded random packing (~300 particles, d = 60 nm, contacts on,
bond damping on; no plate) is given random velocities and run for 1000 steps; a time
step is stable when the kinetic energy stays finite and does not grow tenfold.  The largest stable step is
found by bisection to 3 %; the estimate must lie between half of it and it.
"""
import math
import os

import pytest

from opalflow.bpm.deck import compression_deck
from opalflow.lammps.engine import new_lammps, script_commands
from opalflow.bpm.pipeline import build_structure
from opalflow.lammps.datafile import write_data
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec

SMALL = ["pores.arrangement=none", "pores.spacing_nm=300.0", "pores.diameter_nm=250.0",
         "pores.layers=1", "packing.seed=3"]
CASES = {
    "silica": [],
    "titania_89.5GPa": ["material=titania", "materials.titania.bond_youngs_modulus_GPa=89.5"],
    "silica_10x_stiffer": ["materials.silica.bond_youngs_modulus_GPa=65.3"],
}


def is_stable(folder, deck_text: str, dt_ns: float, steps: int = 1000) -> bool:
    lines = []
    for cmd in script_commands(deck_text):
        word = cmd.split()[0]
        # the probe keeps particles, bonds, contacts and the integrator; no plate, no drag field
        # (a "run 0" stays: the snapshot set-up needs one before it reads the bond counts)
        if cmd.split()[:2] == ["run", "0"]:
            lines.append(cmd)
            continue
        if word in ("run", "restart", "dump", "dump_modify") or any(
                key in cmd for key in ("plate", "curve", "strain", "damp_", "fix damping", "top_z", "thermo")):
            continue
        lines.append(f"timestep {dt_ns!r}" if word == "timestep" else cmd)
    lines += ["velocity mobile create 300.0 4928 loop geom", "thermo_style custom step ke",
              "run 0", "variable ke0 equal ke"]
    lmp = new_lammps()
    cwd = os.getcwd()
    try:
        os.chdir(folder)
        for cmd in lines:
            lmp.command(cmd)
        ke0 = lmp.get_thermo("ke")
        try:
            lmp.command(f"run {steps}")
        except Exception:
            return False  # lost atoms, bonds stretched past the comm cutoff ...
        ke = lmp.get_thermo("ke")
    finally:
        os.chdir(cwd)
        lmp.close()
    return math.isfinite(ke) and ke < 10 * ke0


def stability_limit(folder, deck_text, start: float) -> float:
    lo, hi = None, None
    dt = start
    while lo is None or hi is None:
        if is_stable(folder, deck_text, dt):
            lo, dt = dt, dt * 2
        else:
            hi, dt = dt, dt / 2
        if lo is not None and hi is not None:
            break
    while hi / lo > 1.03:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if is_stable(folder, deck_text, mid) else (lo, mid)
    return lo


@pytest.mark.parametrize("case", list(CASES))
def test_estimate_between_half_and_measured_limit(tmp_path, case):
    spec = load_spec(WORKFLOWS / "opal_quick.toml", SMALL + CASES[case] + ["bonds.breakable=false"])
    s = build_structure(spec)
    deck = compression_deck(spec, s)
    write_data(tmp_path / "data.lmp", deck.structure)
    estimate = deck.timestep.limit_ns
    measured = stability_limit(tmp_path, deck.in_lmp, estimate)
    print(f"{case}: estimate {estimate * 1e-9:.3g} s, measured {measured * 1e-9:.3g} s, "
          f"ratio {estimate / measured:.2f} (stiffest mode: {deck.timestep.stiffest})")
    assert 0.5 * measured <= estimate <= measured


def test_the_spectral_limit_of_a_small_network_starts_no_numba(monkeypatch):
    """Was: every dynamic run's time step came from the compiled bond operator, so the quickstart (19 891 bonds)
    imported numba (0.5 s, ~110 MiB: its peak memory 150 -> 263 MiB in bench_cost.py). Below KERNEL_MIN_BONDS the
    products come from the assembled matrices: the same time step to the eigensolver's rounding, and no numba in a
    fresh process that writes the quickstart's deck."""
    import subprocess
    import sys

    from opalflow.bpm import timestep

    spec = load_spec(WORKFLOWS / "quickstart.toml")
    s = build_structure(spec)

    assembled = compression_deck(spec, s).timestep
    assert assembled.method == "spectral"
    monkeypatch.setattr(timestep, "KERNEL_MIN_BONDS", 0)
    assert compression_deck(spec, s).timestep.limit_ns == pytest.approx(assembled.limit_ns, rel=1e-9)
    code = ("import sys\nfrom opalflow.registry import load_spec\nfrom opalflow.resources import WORKFLOWS\n"
            "from opalflow.bpm.deck import compression_deck\nfrom opalflow.bpm.pipeline import build_structure\n"
            "spec = load_spec(WORKFLOWS / 'quickstart.toml')\ncompression_deck(spec, build_structure(spec))\n"
            "print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"
