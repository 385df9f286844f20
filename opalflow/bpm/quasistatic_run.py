"""``compression.method = "quasistatic"``: strength without dynamics, by event-driven breaking on the
linear network (:mod:`opalflow.bpm.quasistatic`), for any bonded-particle scene and loading.

The run folder gets what a dynamic run writes where it applies: ``data.lmp``, ``run.json``,
``results.h5`` (group ``quasistatic``: each event's strain, stress before and after, bonds broken),
``summary.json`` (E of the first branch, strength, strain at peak, bonds broken in all and per material),
``report.md``, ``stress_strain.png`` (the saw-tooth and its envelope), ``fracture.png`` and, for OVITO,
``fracture.peak.dump`` and ``fracture.end.dump`` (LAMMPS text dumps: particles with the bonds each has lost).
A killed run continues with ``--resume`` from ``quasistatic_state.json`` and ``quasistatic_peak.npy``
(written every few seconds) to the same numbers and the same fracture dumps.
"""
from __future__ import annotations

import json

import math
import resource
import time
from pathlib import Path

import numpy as np

from opalflow.analysis import fracture
from opalflow.bpm.contacts import Contacts, GranularContacts, contact_elements, describe as describe_contacts
from opalflow.bpm.deck import particle_contacts, particle_material
from opalflow.bpm.facts import RunFacts
from opalflow.bpm.loading import LOADINGS
from opalflow.materials import contact_properties
from opalflow.bpm.quasistatic import (CHECKS, Event, FractureResult, SavedState, Stopped, Strengths, peak_facts,
                                      solve_fracture)
from opalflow.bpm.scene import scene_of
from opalflow.bpm.spec import BREAKING_RULES, BpmWorkflow
from opalflow.bpm.methods import METHODS
from opalflow.bpm.nonlinear import solve_nonlinear_fracture
from opalflow.bpm.report import network_inputs, plots_line, sample_lines, structure_cost
from opalflow.bpm.result import CompressionResult, EventFacts
from opalflow.bpm.static_run import network_run, particle_stress
from opalflow.runs.plan import CostFacts
from opalflow.runs.record import finish
from opalflow.progress import note
from opalflow.lammps.datafile import write_dump
from opalflow.lammps.engine import Interrupted, Preempted, stop_requested
from opalflow.spec import SpecError
from opalflow.store import (RESULTS, SUMMARY, DamagedFile, atomic_path, h5_bytes, new_figure, put, read_json, save_figure,
                            write_json_atomic)

STATE = "quasistatic_state.json"
PEAK = "quasistatic_peak.npy"     # the state's displacements just before the peak event (N, 6), beside STATE


def save_state(out: Path, state: SavedState) -> None:
    """The event loop's state: the events as JSON, the peak's displacements as .npy (written first: a
    state file never names a peak the .npy does not hold; not written again while the peak is the one the
    state file names: 78 MB at the paper's sample, every few seconds)."""
    if state.peak_x is not None and not ((out / PEAK).exists() and _saved_peak(out) == state.peak_event):
        with atomic_path(out / PEAK, PEAK + ".tmp.npy") as tmp:
            np.save(tmp, state.peak_x)
    write_json_atomic(out / STATE, {"events": state.events, "modulus_MPa": state.modulus_MPa,
                                    "peak_event": state.peak_event})


def _saved_peak(out: Path) -> int | None:
    """The peak event the state file in ``out`` names (None: no state file, or none readable)."""
    try:
        return json.loads((out / STATE).read_bytes()).get("peak_event")
    except (OSError, ValueError, AttributeError):
        return None


def has_state(out: Path) -> bool:
    """Whether a quasi-static run in ``out`` saved a state to go on from."""
    return (Path(out) / STATE).exists()


def load_state(out: Path) -> SavedState:
    """The state :func:`save_state` wrote (``peak_x`` None where no .npy is kept)."""
    raw = read_json(out / STATE, "the quasi-static run's saved state", "run it anew without --resume",
                    keys=("events", "modulus_MPa"))
    try:
        events = [Event(**e) for e in raw.pop("events")]
        for e in events:
            np.asarray(e.bonds, np.int64)
        state = SavedState(events, float(raw.pop("modulus_MPa")), int(raw.pop("peak_event", -1)))
    except (TypeError, ValueError) as exc:
        raise DamagedFile(out / STATE, "the quasi-static run's saved state", f"damaged ({exc})",
                          "run it anew without --resume") from None
    if state.peak_event >= 0 and (out / PEAK).exists():
        state.peak_x = np.load(out / PEAK)
    return state


def strengths_of(data, coefficients, rule: str = "lammps") -> Strengths:
    """Each bond's critical forces and torques, from its type's bpm/rotational coefficients (a table by bond
    type, 1-based: row 0 unused), and the breaking rule (``bonds.breaking``)."""
    tables = (np.array([np.nan] + [getattr(c, k) for c in coefficients]) for k in ("fr_c", "fs_c", "tb_c", "tt_c"))
    return Strengths(*tables, rule, index=data.bond_types)


def contacts_of(spec: BpmWorkflow, data) -> Contacts | None:
    """The contacts of ``contacts.quasistatic`` (None: off) between the particles of ``data``, each particle of its
    type's material (the substrate's is the matrix's)."""
    k = spec.contacts
    if k.quasistatic == "off":
        return None
    properties = [contact_properties(particle_material(name, spec.material)) for name in data.type_names]
    return contact_elements(data.positions, data.diameters, data.box_lengths, data.periodic, data.bonds, properties,
                            data.types - 1, k.quasistatic, k.reference_strain)


def granular_contacts(spec: BpmWorkflow, data) -> GranularContacts | None:
    """The nonlinear method's contacts (``contacts.enabled``): the dynamic deck's Hertz-Mindlin law, friction and
    materials (:func:`opalflow.bpm.deck.particle_contacts`); None where contacts are off."""
    if not spec.contacts.enabled:
        return None
    _, props, _ = particle_contacts(spec, data)
    return GranularContacts.of(data.positions, data.diameters, data.box_lengths, data.periodic,
                               [props[t] for t in sorted(props)], data.types - 1)


def run_quasistatic(spec: BpmWorkflow, out: Path, *, resume: bool = False, say=print) -> CompressionResult:
    """Build the scene, run the event loop, write the results (see the module docstring)."""
    t0 = time.perf_counter()
    c = spec.compression

    def tell(line: str) -> None:                 # said, and kept in progress.json for status
        say(line)
        note(out, line)

    state = resumed_state(out, tell) if resume else None
    s = scene_of(spec).structure(spec, tell)
    loading = LOADINGS[c.loading]
    sample, net, run, record, written = network_run(spec, s, out, t0, launcher="in-process (quasi-static)",
                                                  resume=STATE if resume else "")
    data = sample.structure
    contacts = contacts_of(spec, data)
    tell(f"quasi-static ({loading.title}): {s.n_particles} particles, {s.n_bonds} bonds, to strain {c.strain_max:g}"
        + (f"; contacts: {describe_contacts(contacts, spec.contacts.quasistatic, spec.contacts.reference_strain)}"
           if contacts else ""))
    strengths, supports = strengths_of(data, sample.coefficients, spec.bonds.breaking), loading.supports(sample)
    res = _solve(spec, out, net, data, sample, strengths, supports, contacts, state, record, written, tell)
    result = _result(spec, res, s, sample, run, loading, contacts)
    summary = result.summary()
    record.sessions[-1].last_step = result.quasistatic.events
    plots = METHODS["quasistatic"].draws_plots(c.plots)

    def files(stage):
        stage(RESULTS).write_bytes(h5_bytes(lambda h: _fill_h5(h, res, data, result, sample, run,
                                                                          spec.bonds.breaking)))
        if plots:
            _plot_curve(stage("stress_strain.png"), res, result)
        frames = _frames(net, data, res)
        if frames and plots:
            fracture.plot_fracture(stage("fracture.png"), frames, data.box_lengths, float(np.mean(data.diameters)),
                                   title=f"{spec.name} (quasi-static, {loading.name})")
        for tag, (_, snap) in zip(("peak", "end"), frames):
            x, y, z = snap.position_nm.T
            write_dump(stage(f"fracture.{tag}.dump"), data, {"id": snap.id, "type": data.types, "x": x, "y": y, "z": z,
                                                             "radius": data.diameters / 2,
                                                             "broken_bonds": snap.broken_bonds})

    written = finish(out, summary, lambda: _report(run, summary, result, loading, sample, plots), result=type(result),
                     files=files, record=record, started=t0)
    (out / STATE).unlink(missing_ok=True)
    (out / PEAK).unlink(missing_ok=True)
    return written


def _solve(spec: BpmWorkflow, out: Path, net, data, sample, strengths, supports, contacts, state, record, written,
           tell) -> FractureResult:
    """The events of the linear method (and the nonlinear one after its first event sets the load step); a
    scheduler's signal or Ctrl-C ends the session in run.json with the state saved."""
    c = spec.compression
    try:
        res = solve_fracture(net, strengths, data.positions, supports, strain_max=c.strain_max,
                             stop_fraction=c.stop_fraction, events_max=1 if c.geometry == "nonlinear" else c.events_max,
                             tolerance=c.event_tolerance, resolver=c.resolver, rtol=c.resolve_rtol,
                             local_rtol=c.local_rtol, state=state, checkpoint=lambda st: save_state(out, st),
                             should_stop=stop_requested, contacts=contacts, say=tell)
        if c.geometry == "nonlinear":           # the linear first event sets the load step
            res = solve_nonlinear_fracture(net, strengths, supports, strain_max=c.strain_max,
                                           first_strain=res.events[0].strain if res.events else math.inf,
                                           stop_fraction=c.stop_fraction, events_max=c.events_max,
                                           tolerance=c.event_tolerance, contacts=granular_contacts(spec, data),
                                           say=tell)
    except Stopped as exc:                       # a scheduler's signal: the state is saved, a requeue resumes
        record.end(out, "interrupted", last_step=exc.events)
        raise Preempted(out, exc.events) from None
    except KeyboardInterrupt:
        record.end(out, "interrupted")
        raise Interrupted(out, None) from None
    finally:
        written.result()                         # data.lmp, written while the events ran, is whole
    return res


def _result(spec: BpmWorkflow, res: FractureResult, s, sample, run, loading, contacts) -> CompressionResult:
    """The run's result: the peak's facts, the broken bonds by material and by check, the events' facts."""
    data = sample.structure
    got = peak_facts(res)
    by_type = np.bincount(data.bond_types[~res.alive] - 1, minlength=len(sample.bins.materials))
    by_material = {m: int(sum(k for k, mk in zip(by_type, sample.bins.materials) if mk == m))
                   for m in sorted(set(sample.bins.materials))}       # (no string per bond: 0.6 GiB at the paper's)
    E = got.youngs_modulus_GPa
    return CompressionResult.of(
        spec.kind, run.sample.structure or {}, workflow=spec.name, method="quasistatic", loading=loading.name,
        youngs_modulus_GPa=E, youngs_modulus_specimen_GPa=E,
        strength_MPa=got.strength_MPa, strain_at_peak=got.strain_at_peak,
        energy_to_peak_kJ_m3=got.energy_to_peak_kJ_m3, broken_bonds=got.broken_bonds,
        broken_bonds_by_material=by_material,
        broken_bonds_at_peak=got.broken_bonds_at_peak,
        broken_bonds_by_check=broken_by_check(res, sample, spec.bonds.breaking, peak_only=False),
        broken_bonds_by_check_at_peak=broken_by_check(res, sample, spec.bonds.breaking, peak_only=True),
        n_particles=s.n_particles, n_bonds=s.n_bonds, solid_fraction=run.sample.solid_fraction,
        build_s=run.sample.build_s, quasistatic=_event_facts(spec, res, got.events, contacts),
        headline=f"E = {E:.4g} GPa, strength = {got.strength_MPa:.4g} MPa (strain at peak "
                 f"{got.strain_at_peak:.4f}; quasi-static, {got.events} events, {got.broken_bonds} "
                 f"bonds broken)" if got.events else
                 f"E = {E:.4g} GPa, no strength: no bond reached its limit before the run stopped ({res.stopped}; "
                 "quasi-static)",
    ).refer(run.references)


def resumed_state(out: Path, say) -> SavedState:
    """The state a killed or stopped run saved (``--resume``); one line where it saved none."""
    if not (out / STATE).exists():
        raise SpecError("--resume", str(out), f"no {STATE} in the folder (the run saved none yet): run it anew")
    state = load_state(out)
    say(f"quasi-static: resuming from {STATE} ({len(state.events)} events done"
        + (", the peak's displacements kept" if state.peak_x is not None else "") + ")")
    return state


def _event_facts(spec: BpmWorkflow, res, events: int, contacts) -> EventFacts:
    """summary.json's ``quasistatic``: how the events went (where they stopped, the re-solves, the local steps,
    the contacts) and what they cost."""
    c = spec.compression
    return EventFacts(
        events=events, stopped=res.stopped, resolver=res.resolver, tolerance=c.event_tolerance,
        setup_s=round(res.setup_seconds, 3), events_s=round(res.seconds - res.setup_seconds, 3),
        factorizations=res.factorizations,
        cg_iterations=(int(sum(e.iterations for e in res.events)) if res.resolver not in ("direct", "newton")
                       else 0),
        local_rtol=c.local_rtol, settled_locally=int(sum(e.settled for e in res.events)), loose_particles=res.loose,
        contacts=("hertz-mindlin (nonlinear)" if c.geometry == "nonlinear" and spec.contacts.enabled
                  else spec.contacts.quasistatic), contact_pairs=len(contacts.bond) if contacts else 0,
        contacts_pressing_at_peak=res.events[max(res.peak - 1, 0)].contacts if res.events else 0,
        contacts_pressing_at_end=res.events[-1].contacts if res.events else 0,
        peak_memory_MiB=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        out_of_balance_states=len(res.unbalanced), out_of_balance_max=max(res.unbalanced, default=0.0))


def _length_bins(sample) -> tuple[np.ndarray, list[str]]:
    """Each bond's length bin (the deck's bond type, :class:`opalflow.bpm.deck.BondBins`, 0-based) and each
    bin's label: its material and range of L0 / d (d the mean particle diameter)."""
    data = sample.structure
    which = data.bond_types - 1
    d = float(np.mean(data.diameters))
    labels = []
    for k, mat in enumerate(sample.bins.materials):
        r0 = sample.bond_lengths[which == k]
        labels.append(f"{mat} {r0.min() / d:.3f}-{r0.max() / d:.3f}" if len(r0) else f"{mat} -")
    return which, labels


def _broken_in_order(res) -> tuple[np.ndarray, np.ndarray]:
    """(the broken bonds in the order they broke, the check that broke each: -1 where the state a run
    resumed from kept none)."""
    bonds = [np.asarray(e.bonds, np.int64) for e in res.events]
    checks = [np.asarray(e.checks if len(e.checks) == len(e.bonds) else [-1] * len(e.bonds), np.int64)
              for e in res.events]
    return (np.concatenate(bonds) if bonds else np.zeros(0, np.int64),
            np.concatenate(checks) if checks else np.zeros(0, np.int64))


def broken_by_check(res, sample, rule: str, *, peak_only: bool) -> dict[str, dict[str, int]]:
    """Broken bonds counted by the check of ``rule`` that broke them (:data:`opalflow.bpm.quasistatic.CHECKS`:
    for LAMMPS's rule, the paper's and today's MUSEN's Dosta et al. eqs. 16-17 apart) and by length bin:
    ``{check: {bin label: count}}``, all events or those before the peak event (``peak_only``)."""
    bonds, checks = _broken_in_order(res)
    if peak_only:
        bonds, checks = (bonds[:sum(len(e.bonds) for e in res.events[:res.peak])],
                         checks[:sum(len(e.bonds) for e in res.events[:res.peak])])
    which, labels = _length_bins(sample)
    out = {}
    names = CHECKS[rule]
    for k, name in enumerate(names + ("not recorded",)):
        sel = checks == (k if k < len(names) else -1)
        if sel.any() or k < len(names):
            counts = np.bincount(which[bonds[sel]], minlength=len(labels))
            out[name] = {label: int(c) for label, c in zip(labels, counts) if c}
    return out


def _broken_per_particle(net, alive: np.ndarray) -> np.ndarray:
    dead = ~alive
    return np.bincount(net.i[dead], minlength=net.n_particles) + np.bincount(net.j[dead], minlength=net.n_particles)


def _frames(net, data, res) -> list[fracture.Frame]:
    """Fracture pictures at the peak and at the end (the snapshots of :mod:`opalflow.analysis.fracture`)."""
    if not res.events:
        return []
    volumes = data.particle_volumes()

    def snap(alive, x, strain):
        """The particles displaced (x: None after a resume, which keeps no displacements: zero stress drawn)."""
        x = np.zeros((data.n_particles, 6)) if x is None else x
        return fracture.Snapshot(strain, data.positions + x[:, :3], data.diameters / 2,
                                 _broken_per_particle(net, alive),
                                 particle_stress(net, x[:, :3], x[:, 3:], volumes, alive),
                                 id=np.arange(1, data.n_particles + 1), type=data.types)

    p, last = res.peak, res.events[-1]
    peak_alive = res.peak_alive if res.peak_alive is not None else res.alive
    return [(f"at the peak (strain {100 * res.events[p].strain:.2f} %)", snap(peak_alive, res.peak_x, res.events[p].strain)),
            (f"at the end (strain {100 * last.strain:.2f} %, {int((~res.alive).sum())} bonds broken)",
             snap(res.alive, res.end_x, last.strain))]


def _fill_h5(h, res, data, result, sample, run: RunFacts, rule: str) -> None:
    result.h5_attrs(h, run)
    g = h.create_group("quasistatic")
    ev = res.events
    put(g, "strain", np.array([e.strain for e in ev]), "1", description="strain of each event (the next bond's limit)")
    put(g, "stress_MPa", np.array([e.stress_MPa for e in ev]), "MPa", description="stress just before each event")
    put(g, "stress_after_MPa", np.array([e.stress_after_MPa for e in ev]), "MPa",
        description="stress at the same strain just after the event's bonds broke")
    put(g, "bonds_per_event", np.array([len(e.bonds) for e in ev]), "1")
    put(g, "broken_bond_index", np.concatenate([e.bonds for e in ev]).astype(np.int64) if ev else np.zeros(0, int), "1",
        description="0-based bond index (data.lmp order) of the broken bonds, in order")
    bonds, checks = _broken_in_order(res)
    put(g, "broken_bond_check", checks.astype(np.int8), "1",
        description="the check that broke each bond (as broken_bond_index): "
                    + ", ".join(f"{k} {name}" for k, name in enumerate(CHECKS[rule])) + ", -1 not recorded")
    put(g, "broken_bond_length_nm", sample.bond_lengths[bonds], "nm", description="L0 of each broken bond")
    put(g, "broken_bond_length_bin", (data.bond_types[bonds] - 1).astype(np.int32), "1",
        description="length bin (data.lmp bond type - 1) of each broken bond")
    put(g, "intact", res.alive.astype(np.int8), "1", description="1 for each bond intact at the end")
    put(g, "position_nm", data.positions, "nm", ["x", "y", "z"])


def _plot_curve(path: Path, res, result: CompressionResult) -> None:
    fig, ax = new_figure()
    pts = [(0.0, 0.0)]
    for e in res.events:
        pts += [(e.strain, e.stress_MPa), (e.strain, e.stress_after_MPa)]
    x, y = np.array(pts).T
    ax.plot(x, y, "-", lw=0.8, color="0.5", label="saw-tooth: load to each event, drop as its bonds break")
    ax.plot([e.strain for e in res.events], [e.stress_MPa for e in res.events], ".", ms=4, color="C0",
            label="events (the envelope)")
    if res.events:
        ax.plot([result.strain_at_peak], [result.strength_MPa], "o", color="C3",
                label=f"strength {result.strength_MPa:.3g} MPa")
    ax.set_xlabel("strain")
    ax.set_ylabel("stress (MPa)")
    ax.legend()
    save_figure(fig, path)


def _check_table(result: CompressionResult) -> list[str]:
    """Which check broke the bonds, by length bin, before the peak and in all (the result's counts)."""
    peak, total = result.broken_bonds_by_check_at_peak, result.broken_bonds_by_check
    names = [name for name in total]
    labels = sorted({label for counts in total.values() for label in counts},
                    key=lambda label: (label.split(" ")[0], label.split(" ")[-1]))
    lines = ["Bonds broken by each check of the breaking rule (the largest of its checks at the event: "
             "opalflow.bpm.quasistatic.CHECKS; L0 / d by length bin), before the peak / in all:",
             "", "| length bin | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for label in labels:
        lines.append(f"| {label} | " + " | ".join(f"{peak.get(n, {}).get(label, 0)} / {total[n].get(label, 0)}"
                                               for n in names) + " |")
    return lines


def _report(run: RunFacts, summary: dict, result: CompressionResult, loading, sample, plots: bool) -> str:
    """report.md; ``summary`` as written (its ``wall_s``, set as the files are written)."""
    spec, facts, q = run.spec, run.sample, result.quasistatic
    lines = [f"# {spec.name}: quasi-static {loading.title}", "",
             f"{facts.n_particles} particles, {facts.n_bonds} bonds; the bond network linearised from LAMMPS's "
             f"bpm/rotational, bonds broken one event at a time by {BREAKING_RULES[spec.bonds.breaking]} at full "
             f"load (as `smooth no`; opalflow/bpm/quasistatic.py); {loading.held_text(facts.top_layer_particles)}.",
             "",
             *sample_lines(facts), *network_inputs(run, sample), "## Results", "",
             *([f"Contacts (`contacts.quasistatic = \"{q.contacts}\"`, opalflow/bpm/contacts.py): "
                f"{q.contact_pairs} touching pairs, linear Hertz-Mindlin springs at "
                f"{100 * spec.contacts.reference_strain:g} % overlap, in compression only; pressing just before the "
                f"peak: {q.contacts_pressing_at_peak}, at the end: {q.contacts_pressing_at_end}.", ""]
               if q.contacts != "off" else []),
             *result.results_table(float(sample.structure.diameters.mean()))]
    lines += ["", f"{q.events} events, {result.broken_bonds} bonds broken "
              f"({', '.join(f'{m}: {k}' for m, k in result.broken_bonds_by_material.items())}), "
              f"{result.broken_bonds_at_peak} before the peak; stopped: {q.stopped}.", "",
              *_check_table(result), "",
              f"Re-solves `{q.resolver}`: set-up {q.setup_s:.1f} s, events {q.events_s:.1f} s, "
              f"{q.factorizations} factorisations" + (f", {q.cg_iterations} CG iterations" if q.cg_iterations else "")
              + (f"; {q.settled_locally} events settled by the local step alone (local_rtol {q.local_rtol:g})"
                 if q.local_rtol else "")
              + f"; {structure_cost(facts)}; wall {summary['wall_s']:.1f} s.", "",
              plots_line(plots, "stress_strain.png, fracture.png", spec.compression.plots) + f" Data: {RESULTS} "
              f"(group `quasistatic`), fracture.peak.dump and fracture.end.dump (OVITO), {SUMMARY}."]
    return "\n".join(lines) + "\n"


def price(spec: BpmWorkflow, s) -> CostFacts:
    """What :mod:`opalflow.runs.plan` prices a quasi-static run by: the measured runs with its breaking rule and
    event tolerance (or, where none, its first solve); the nonlinear method's, by its measured jobs."""
    return CostFacts("quasistatic", s.n_particles, s.n_bonds, bond_model=spec.bonds.model, solver="amg",
                     breaking=spec.bonds.breaking, event_tolerance=spec.compression.event_tolerance,
                     geometry=spec.compression.geometry)
