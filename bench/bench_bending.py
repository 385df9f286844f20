"""Three-point bending of the simple-cubic lattice beam (workflows/lattice_bending.toml) by the static and the
dynamic method, against Timoshenko's beam with the lattice's EI and GA, and Euler-Bernoulli's (no shear).

    python bench/bench_bending.py

Runs both with ``python -m opalflow run`` in child processes (their whole-command wall times) and writes
bench/results/bending.json (flexural moduli, errors against beam theory, times, the machine) and
docs/figures/lattice_bending.png (the dynamic run's flexural stress-strain curve with the three slopes).
"""
from __future__ import annotations

import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

HERE = Path(__file__).resolve().parent


def run(out: Path, *sets: str) -> tuple[dict, float]:
    t = time.perf_counter()
    args = [sys.executable, "-m", "opalflow", "run", "lattice_bending", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    proc = subprocess.run(args, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(proc.stderr)
    return json.loads((out / "summary.json").read_text()), time.perf_counter() - t


def euler_bernoulli() -> float:
    """The flexural modulus without the shear term: the lattice's EI alone."""
    from opalflow.materials import material
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    spec = load_spec(WORKFLOWS / "lattice_bending.toml", [])
    return spec.flexural_modulus(material(spec.material, spec.materials), spec.bonds.radius_factor / 2, shear=False)


def main() -> None:
    from opalflow.store import new_figure, save_figure

    with tempfile.TemporaryDirectory() as tmp:
        static, static_s = run(Path(tmp) / "static", "compression.method=static")
        dynamic, dynamic_s = run(Path(tmp) / "dynamic")
        with h5py.File(Path(tmp) / "dynamic" / "results.h5") as h:
            strain, stress = h["curve/strain"][:], h["curve/stress_MPa"][:]
    ref = static["reference"]["youngs_modulus_GPa"]
    eb = euler_bernoulli()
    rows = {name: {"flexural_modulus_GPa": s["youngs_modulus_GPa"],
                   "error_vs_timoshenko": s["youngs_modulus_GPa"] / ref["value"] - 1,
                   "error_vs_euler_bernoulli": s["youngs_modulus_GPa"] / eb - 1, "command_s": round(wall, 2)}
            for name, s, wall in (("static", static, static_s), ("dynamic", dynamic, dynamic_s))}
    result = {"workflow": "lattice_bending", "n_particles": static["n_particles"], "n_bonds": static["n_bonds"],
              "timoshenko_GPa": ref["value"], "euler_bernoulli_GPa": eb, "source": ref["source"], **rows,
              "machine": {"cpu_count": __import__("os").cpu_count(), "python": platform.python_version()},
              "date": time.strftime("%Y-%m-%d")}
    (HERE / "results" / "bending.json").write_text(json.dumps(result, indent=2) + "\n")
    fig, ax = new_figure(figsize=(5, 3.6))
    ax.plot(100 * strain, stress, lw=1.4, label="LAMMPS (dynamic, 0.1 m/s)")
    x = [0, 100 * max(strain)]
    for E, style, label in ((static["youngs_modulus_GPa"], "--", "static solve"),
                            (ref["value"], ":", "Timoshenko beam"), (eb, "-.", "Euler-Bernoulli beam")):
        ax.plot(x, [0, E * 1e3 * x[1] / 100], style, lw=1, label=f"{label}: {E:.4g} GPa")
    ax.set_xlabel("flexural strain 6 delta h / L^2 (%)")
    ax.set_ylabel("flexural stress 3 F L / (2 b h^2) (MPa)")
    ax.set_title("three-point bending, simple-cubic beam, 60 x 2 x 4 cells", fontsize=9)
    ax.legend(fontsize=8)
    save_figure(fig, HERE.parent / "docs" / "figures" / "lattice_bending.png")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
