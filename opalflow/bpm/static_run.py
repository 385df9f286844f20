"""``compression.method = "static"``: the compression workflow of a bonded-particle scene as one linear
solve (:mod:`opalflow.bpm.static`) instead of a LAMMPS run.

The run folder gets what a dynamic run writes where it applies: ``data.lmp`` and ``run.json`` (the same
structure, bond types and groups as the dynamic deck), ``results.h5``, ``summary.json`` (``method =
"static"``), ``report.md`` and plots.  Particle stresses (eq. 21 of Dosta et al., as LAMMPS's ``compute
stress/atom`` tallies bonds: 1/2 r (x) F per particle, over V_p) and bond-strain histograms (Fig. 7) are
given at each of ``compression.snapshot_strains`` (the response is linear: one solve, scaled).  No strength:
bonds do not break in a linear solve.

A sample periodic in all three directions (``lattice.periodic_z``) has no substrate to compress on: it
gets its 6 x 6 stiffness tensor instead (:func:`opalflow.bpm.static.solve_tensor`), with the Young's
moduli, Poisson ratios and bulk modulus it implies.
"""
from __future__ import annotations

import dataclasses
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from opalflow.analysis import compression as mech
from opalflow.analysis.elasticity import VOIGT, isotropic_average
from opalflow.bpm.deck import bond_model, loaded_sample
from opalflow.bpm.facts import RunFacts, SampleFacts
from opalflow.bpm.loading import LOADINGS
from opalflow.bpm.methods import METHODS
from opalflow.bpm.report import network_inputs, plots_line, sample_lines, structure_cost
from opalflow.bpm.result import CompressionResult
from opalflow.bpm.scene import scene_of, solid_fraction
from opalflow.bpm.spec import BpmWorkflow
from opalflow.bpm.static import (LooseParticlesError, StaticResult, auto_solver, loose_message,
                                  loose_particles, solve_compression, solve_tensor)
from opalflow.bpm.stiffness import BondNetwork, EnergyParts, stiffness_network
from opalflow.lammps.datafile import write_data
from opalflow.runs.plan import CostFacts
from opalflow.runs.record import RunRecord, finish
from opalflow.runs.result import table_of
from opalflow.store import RESULTS, SUMMARY, h5_bytes, new_figure, put, save_figure
from opalflow.version import __version__

#: the strain of the solve (any: the answer is linear; small keeps the reported displacements physical)
STRAIN = 1e-4


def particle_stress(net: BondNetwork, u: np.ndarray, theta: np.ndarray, volumes: np.ndarray,
                    alive: np.ndarray | None = None) -> np.ndarray:
    """Eq. 21 per particle (MPa, tension positive), columns xx yy zz xy xz yz, as LAMMPS's compute
    stress/atom tallies a bond (ev_tally_xyz: 1/2 r_a F_b to each partner, r = x_i - x_j, F = force1on2), for
    displacements ``u`` and rotations ``theta`` (N, 3); ``alive`` (M,) bool: the bonds it holds false left out
    (broken).  One (M,) column at a time: the paper's 17.5 M bonds need their forces and two columns, not a copy
    of the intact network (1.4 GiB: the quasi-static run's peak memory, at its fracture pictures)."""
    F = net.bond_forces(u, theta)
    if alive is not None:
        F[~alive] = 0.0
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    sigma = np.zeros((net.n_particles, 6))
    for k, (a, b) in enumerate(pairs):
        w = 0.5 * (net.n[:, a] * net.L) * F[:, b]
        sigma[:, k] = np.bincount(net.i, w, net.n_particles) + np.bincount(net.j, w, net.n_particles)
    return sigma / volumes[:, None]


def bond_strain(net: BondNetwork, u: np.ndarray) -> np.ndarray:
    """r / r0 - 1 of each bond to first order: n . (u_i - u_j) / L."""
    return np.einsum("ij,ij->i", net.n, u[net.i] - u[net.j]) / net.L


def network_run(spec: BpmWorkflow, s, out: Path, t0: float, *, launcher: str, resume: str = ""):
    """What the static and quasi-static runs of a scene ``s`` share: the loaded sample (the dynamic deck's
    bonded structure, height, cross-section and top layer; no deck: :func:`opalflow.bpm.deck.loaded_sample`),
    its linear network (loose particles refused before anything is written, unless
    ``compression.drop_loose``), data.lmp and the run record, begun (``resume``: the state file a session
    continues from).  Returns (sample, network, the run's facts, record, written): ``written`` is the future of
    data.lmp,
    written on a thread of its own while the solve runs (:func:`_behind`)."""
    c = spec.compression
    timings = {"structure": time.perf_counter() - t0}
    sample = loaded_sample(spec, s)
    build_s = time.perf_counter() - t0
    timings["sample"] = build_s - timings["structure"]
    data = sample.structure
    t = time.perf_counter()
    net = stiffness_network(data, sample.coefficients, sample.bond_lengths)     # (L the sample's: no copy)
    loose = loose_particles(net, LOADINGS[c.loading].supports(sample).anchored)
    timings["network"] = time.perf_counter() - t
    if loose.any() and not c.drop_loose:     # refused before anything is written
        raise LooseParticlesError(loose_message(int(loose.sum())))
    out.mkdir(parents=True, exist_ok=True)
    written = _behind(timings, "data_file", write_data, out / "data.lmp", data,
                      title=f"opalflow {__version__} {spec.name} ({c.method})")
    facts = SampleFacts(
        n_particles=s.n_particles, n_bonds=s.n_bonds, type_names=data.type_names, solid_fraction=solid_fraction(s),
        build_s=build_s, periodic=data.periodic.tolist(), loading=sample.loading, loading_sense=sample.loading_sense,
        height_nm=sample.height_nm, area_nm2=sample.area_nm2, source=data.meta.get("source", ""), method=c.method,
        top_layer_particles=int(sample.top_layer.sum()), structure_cache=s.meta.get("cache", ""),
        structure_first_build_s=s.meta.get("build_s", build_s), timings_s=timings)
    scene = scene_of(spec)
    if scene.run_keys:
        stats = scene.statistics_of(sample.source)
        facts.structure = {k: getattr(stats, k) for k in scene.run_keys}
    record = RunRecord.read(out) if resume else RunRecord.new(spec, deck=table_of(facts), folder=out)
    record.begin(out, launcher=launcher, restart=resume or "")
    return sample, net, RunFacts(spec, facts, spec.references()), record, written


def _behind(timings: dict, key: str, work, *args, **kwargs) -> Future:
    """``work(*args, **kwargs)`` on a thread of its own, its time in ``timings[key]``: data.lmp is written
    while the solver sets up and iterates (numpy's formatting and the numba kernels release the GIL; the
    paper's sample: 17 s of writing that no longer add to the run).  The caller waits on the Future before
    it writes its results."""
    def timed():
        t = time.perf_counter()
        work(*args, **kwargs)
        timings[key] = time.perf_counter() - t
    pool = ThreadPoolExecutor(1, thread_name_prefix=key)
    future = pool.submit(timed)
    pool.shutdown(wait=False)
    return future


def run_static(spec: BpmWorkflow, out: Path, say=print) -> CompressionResult:
    """Build the scene, solve the compression, write the results (see the module docstring)."""
    t0 = time.perf_counter()
    c = spec.compression
    s = scene_of(spec).structure(spec, say)
    if np.all(s.periodic):
        return run_tensor(spec, s, out, t0, say)
    sample, net, run, _, written = network_run(spec, s, out, t0, launcher="in-process (static solve)")
    facts = run.sample
    data = sample.structure
    say(f"static solve ({c.solver}): {s.n_particles} particles, {s.n_bonds} bonds, {6 * s.n_particles} dofs")
    res = solve_compression(net, data.positions, LOADINGS[c.loading].supports(sample), strain=STRAIN,
                            solver=c.solver, drop_loose=c.drop_loose, say=say)
    written.result()                 # data.lmp (written while the solver ran)
    E_GPa = res.modulus_MPa / 1e3
    t = time.perf_counter()
    volumes = data.particle_volumes()
    sigma_unit = particle_stress(net, res.u, res.theta, volumes) / STRAIN       # per unit strain
    strain_unit = bond_strain(net, res.u) / STRAIN
    types = data.types
    snapshots = {e: sigma_unit * e for e in c.snapshot_strains}       # strain -> the particles' stresses (MPa)
    result = CompressionResult.of(
        spec.kind, facts.structure or {}, workflow=spec.name, method="static", loading=c.loading,
        youngs_modulus_GPa=E_GPa, youngs_modulus_specimen_GPa=E_GPa,
        n_particles=s.n_particles, n_bonds=s.n_bonds, solid_fraction=facts.solid_fraction,
        solver=res.solver, iterations=res.iterations, relative_residual=res.residual,
        setup_s=res.setup_seconds, solve_s=res.seconds - res.setup_seconds,
        static_s=res.seconds, peak_memory_MiB=res.peak_memory_MiB,
        # where the time went: the run's steps (set-up: assembly and AMG or factor; analysis: particle stresses and
        # bond strains; files: results.h5 and the plots), the whole in wall_s
        timings_s={**facts.timings_s, "setup": res.setup_seconds, "solve": res.seconds - res.setup_seconds,
                   "analysis": time.perf_counter() - t},
        build_s=facts.build_s, loose_particles_left_out=res.loose,
        energy_split=net.energy_parts(res.u, res.theta).fractions(),
        stress_by_material={f"{e:.4f}": mech.stress_by_material(sigma, types, data.type_names)
                            for e, sigma in snapshots.items()},
        bond_strain_per_strain={"mean": float(strain_unit.mean()), "std": float(strain_unit.std()),
                                "min": float(strain_unit.min()), "max": float(strain_unit.max())},
        headline=f"E = {E_GPa:.4g} GPa (static, {res.solver}: {res.iterations} iterations, residual "
                 f"{res.residual:.1e}, {res.seconds:.1f} s)").refer(run.references)
    summary = result.summary()
    plots = METHODS["static"].draws_plots(c.plots)

    def files(stage):
        t = time.perf_counter()
        _write_h5(stage(RESULTS), data, res, sigma_unit, strain_unit, snapshots, result, run)
        if plots:
            _plots(stage, data, res, snapshots, strain_unit, c.snapshot_strains)
        result.timings_s["files"] = time.perf_counter() - t

    sides = "periodic" if s.periodic[0] else "open"       # the structure's, whatever section set it
    return finish(out, summary, lambda: _report(run, summary, result, res, sides, sample, plots),
                  result=type(result), files=files, started=t0)


def _write_h5(path: Path, data, res: StaticResult, sigma_unit, strain_unit, snapshots, result,
              run: RunFacts) -> None:
    def fill(h):
        result.h5_attrs(h, run)
        g = h.create_group("static")
        g.attrs["strain"] = res.strain
        put(g, "position_nm", data.positions, "nm", ["x", "y", "z"])
        put(g, "type", data.types, "1", type_names=data.type_names)
        put(g, "displacement_nm", res.u, "nm", ["x", "y", "z"], description=f"at strain {res.strain:g}")
        put(g, "rotation_rad", res.theta, "rad", ["x", "y", "z"], description=f"at strain {res.strain:g}")
        put(g, "sigma_per_strain_MPa", sigma_unit, "MPa", mech.STRESS_COLUMNS,
            description="particle stress (eq. 21) per unit macroscopic strain")
        put(g, "bond_strain_per_strain", strain_unit, "1", description="bond strain per unit macroscopic strain")
        put(g, "residual_history", np.asarray(res.history), "1", description="relative residual per iteration")
        for e, sigma in snapshots.items():
            sg = h.create_group(f"snapshots/{e:.4f}")
            sg.attrs["strain"] = e
            put(sg, "sigma_MPa", sigma, "MPa", mech.STRESS_COLUMNS)
    path.write_bytes(h5_bytes(fill))


def _plots(stage, data, res: StaticResult, snapshots, strain_unit, strains) -> None:
    fig, ax = new_figure(figsize=(5, 3.6))
    mobile = ~data.groups["substrate"]
    ax.plot(data.positions[mobile, 2], -res.u[mobile, 2] / res.strain, ".", ms=2)
    ax.set_xlabel("height z (nm)")
    ax.set_ylabel("-u_z / strain (nm)")
    ax.set_title("displacement per unit strain (static)")
    save_figure(fig, stage("displacement.png"))
    if snapshots:
        mech.plot_stress_histograms(stage("stress_hist.png"), [(e, sigma, data.types)
                                                               for e, sigma in snapshots.items()], data.type_names)
        edges = mech.strain_bins([strain_unit * max(strains)])
        mech.plot_bond_strains(stage("bond_strain.png"), edges, {
            f"strain {100 * e:.2f} %": mech.histogram_fraction(strain_unit * e, edges) for e in strains})


def _report(run: RunFacts, summary: dict, result, res: StaticResult, sides: str, sample, plots: bool) -> str:
    spec, facts = run.spec, run.sample
    loading = LOADINGS[spec.compression.loading]
    lines = [f"# {spec.name}: static {loading.title}", "",
             f"{facts.n_particles} particles, {facts.n_bonds} bonds; the bond network linearised from LAMMPS's "
             f"bpm/rotational (opalflow/bpm/stiffness.py); {loading.held_text(facts.top_layer_particles)}, by "
             f"strain {res.strain:g} x H (H = {facts.height_nm:.1f} nm); sides {sides}. Contacts carry no load at "
             "the reference state and bonds do not break: no strength.", "", *sample_lines(facts),
             *network_inputs(run, sample), "## Results", "",
             *result.results_table(float(sample.structure.diameters.mean()))]
    if result.energy_split:
        lines += ["", "Strain energy of the bonds by mode: " + ", ".join(
            f"{f.name} {100 * getattr(result.energy_split, f.name):.1f} %" for f in dataclasses.fields(EnergyParts))
            + " (BondNetwork.energy_parts)."]
    lines += ["", f"Solver `{res.solver}`: {res.iterations} iterations to relative residual {res.residual:.1e}; "
              f"set-up {res.setup_seconds:.1f} s, iterations {res.seconds - res.setup_seconds:.1f} s, peak memory "
              f"{res.peak_memory_MiB:.0f} MiB; "
              f"{structure_cost(facts)}; wall {summary['wall_s']:.1f} s.", ""]
    lines += mech.stress_table(result.stress_by_material, digits=2)
    lines += ["", plots_line(plots, "displacement.png, stress_hist.png, bond_strain.png", spec.compression.plots)
              + f" Data: {RESULTS} (group `static`), {SUMMARY}."]
    return "\n".join(lines) + "\n"


def run_tensor(spec: BpmWorkflow, s, out: Path, t0: float, say=print) -> CompressionResult:
    """The stiffness tensor of a sample periodic in x, y and z, and what it implies."""
    c = spec.compression
    data, _, coeffs = bond_model(spec, s)
    build_s = time.perf_counter() - t0
    net = stiffness_network(data, coeffs)
    volume = float(np.prod(data.box_lengths))
    say(f"static stiffness tensor ({c.solver}): {s.n_particles} particles, {s.n_bonds} bonds, six loadings")
    res = solve_tensor(net, data.positions, volume, solver=c.solver, drop_loose=c.drop_loose, say=say)
    C = res.C_GPa
    S = np.linalg.inv(C)
    E = 1.0 / np.diag(S)[:3]
    iso = isotropic_average(C)
    run = RunFacts(spec, SampleFacts(
        n_particles=s.n_particles, n_bonds=s.n_bonds, type_names=data.type_names, solid_fraction=solid_fraction(s),
        build_s=build_s, periodic=data.periodic.tolist(), loading="periodic", method="static", volume_nm3=volume),
        spec.references())
    out.mkdir(parents=True, exist_ok=True)
    write_data(out / "data.lmp", data, title=f"opalflow {__version__} {spec.name} (static, periodic)")
    RunRecord.new(spec, deck=table_of(run.sample), folder=out).begin(out, launcher="in-process (static solve)")
    result = CompressionResult.of(
        spec.kind, {}, workflow=spec.name, method="static", loading="periodic", stiffness_tensor_GPa=C.tolist(),
        youngs_modulus_GPa=float(E[2]), youngs_moduli_GPa={"x": float(E[0]), "y": float(E[1]), "z": float(E[2])},
        poisson_ratio_zx=float(-S[0, 2] / S[2, 2]), bulk_modulus_GPa=float(1.0 / S[:3, :3].sum()),
        youngs_modulus_isotropic_GPa=iso.hill.E, poisson_ratio_isotropic=iso.hill.nu,
        anisotropy_index=iso.anisotropy_index, isotropic_average_GPa=iso,
        n_particles=s.n_particles, n_bonds=s.n_bonds, solver=res.solver, iterations=res.iterations,
        relative_residual=res.residual, static_s=res.seconds, peak_memory_MiB=res.peak_memory_MiB,
        build_s=build_s, loose_particles_left_out=res.loose,
        headline=f"E_z = {E[2]:.4g} GPa, C11 = {C[0, 0]:.4g}, C12 = {C[0, 1]:.3g}, C44 = {C[3, 3]:.4g} GPa "
                 f"(static, periodic, {res.solver}: {sum(res.iterations)} iterations, {res.seconds:.1f} s)",
    ).refer(run.references)
    summary = result.summary()
    names = [f"{'xyz'[a]}{'xyz'[b]}" for a, b in VOIGT]
    lines = [f"# {spec.name}: static stiffness tensor", "",
             f"{s.n_particles} particles, {s.n_bonds} bonds, periodic in x, y and z; six unit macroscopic strains "
             "through the periodic images, the particles relaxed (opalflow/bpm/static.py, solve_tensor); stress "
             "= bond virial / volume.", "", "C (GPa), Voigt order:", "",
             "| | " + " | ".join(names) + " |", "|---|" + "---|" * 6]
    lines += [f"| {names[r]} | " + " | ".join(f"{C[r, k]:.4g}" for k in range(6)) + " |" for r in range(6)]
    lines += ["", f"Young's moduli x / y / z: {E[0]:.4g} / {E[1]:.4g} / {E[2]:.4g} GPa; Poisson ratio zx "
              f"{result.poisson_ratio_zx:.4f}; bulk modulus (Reuss) {result.bulk_modulus_GPa:.4g} GPa.", "",
              "Isotropic averages (opalflow/analysis/elasticity.py: Voigt, Reuss, Hill; universal anisotropy index "
              f"A^U = {iso.anisotropy_index:.3g}, 0 for an isotropic tensor):", "",
              "| average | K (GPa) | G (GPa) | E (GPa) | nu |", "|---|---|---|---|---|",
              *(f"| {k} | {m.K:.4g} | {m.G:.4g} | {m.E:.4g} | {m.nu:.4f} |"
                for k, m in (("voigt", iso.voigt), ("reuss", iso.reuss), ("hill", iso.hill))), ""]
    for k, r in result.reference.items():
        lines.append(f"Reference {k}: {r['value']:.6g} ({r['source']}); error {100 * r['error']:+.4f} %.")
    lines += ["", f"Solver `{res.solver}`: iterations per loading {res.iterations}, worst relative residual "
              f"{res.residual:.1e}; {res.seconds:.1f} s, peak memory {res.peak_memory_MiB:.0f} MiB."]
    voigt = result.voigt_order.split()

    def fill(h):
        result.h5_attrs(h, run)
        put(h, "stiffness_tensor_GPa", C, "GPa", voigt, rows=voigt)
    tensor = h5_bytes(fill)
    return finish(out, summary, "\n".join(lines), result=type(result),
                  files=lambda stage: stage(RESULTS).write_bytes(tensor), started=t0)


def price(spec: BpmWorkflow, s) -> CostFacts:
    """What :mod:`opalflow.runs.plan` prices a static solve of structure ``s`` by: its size and solver."""
    solver = spec.compression.solver
    return CostFacts("static", s.n_particles, s.n_bonds, bond_model=spec.bonds.model,
                     solver=auto_solver(s.n_particles, s.n_bonds) if solver == "auto" else solver)
