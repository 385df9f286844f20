"""The sample side of every bonded-particle method: spec -> scene -> structure -> deck -> the run folder's inputs.

A scene (the opal, the lattice, a user's data file) gives only its structure (:class:`opalflow.bpm.scene.Scene`,
found through :mod:`opalflow.registry` by the spec's kind); everything after it is the same for all, and every
method (:mod:`opalflow.bpm.run`) starts from :func:`prepare`.  A run folder holds everything: data.lmp, in.lmp,
resume.lmp, run.sh (LAMMPS alone), run.json (what analysis needs to know about the deck), the raw output and the
results (results.h5, summary.json, report.md, PNG plots).  Results are written under temporary names and renamed,
so a failed run never replaces earlier results.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from opalflow.bpm.deck import CompressionDeck, compression_deck, particle_material
from opalflow.bpm.facts import SampleFacts
from opalflow.bpm.scene import scene_of, solid_fraction
from opalflow.bpm.spec import BpmWorkflow
from opalflow.lammps.datafile import write_data
from opalflow.lammps.engine import run_script_sh
from opalflow.materials import material
from opalflow.runs.record import RunRecord, refuse_finished, write_build_summary
from opalflow.runs.result import table_of
from opalflow.store import write_text_atomic
from opalflow.structure import Structure
from opalflow.version import __version__


def build_structure(spec: BpmWorkflow, progress=None) -> Structure:
    """The scene's structure."""
    return scene_of(spec).structure(spec, progress)


def prepare(spec: BpmWorkflow, out: Path, progress=None) -> tuple[CompressionDeck, RunRecord]:
    """Build the scene and write the run folder's inputs (data.lmp, decks, run.sh, run.json); returns the deck
    and the run's record, which the run then holds in memory (run.json is for a resume and for users)."""
    t = time.perf_counter()
    scene = scene_of(spec)
    s = scene.structure(spec, progress)
    deck = compression_deck(spec, s)
    build_s = time.perf_counter() - t
    out.mkdir(parents=True, exist_ok=True)
    (out / "snapshots").mkdir(exist_ok=True)
    t = time.perf_counter()
    write_data(out / "data.lmp", deck.structure, title=f"opalflow {__version__} {spec.name}")
    deck.structure.meta.setdefault("timings_s", {})["write"] = time.perf_counter() - t
    write_text_atomic(out / "in.lmp", deck.in_lmp)
    write_text_atomic(out / "resume.lmp", deck.resume_lmp)
    write_text_atomic(out / "run.sh", run_script_sh())
    (out / "run.sh").chmod(0o755)
    facts = SampleFacts.from_dict({
        "type_names": deck.structure.type_names, "n_particles": s.n_particles, "n_bonds": s.n_bonds,
        "solid_fraction": solid_fraction(s), "build_s": build_s, "mean_diameter_nm": float(np.mean(s.diameters)),
        "box_nm": s.box_lengths.tolist(), "periodic": s.periodic.tolist(), "source": s.meta.get("source", ""),
        "materials": {n: material(particle_material(n, spec.material), spec.materials)
                      for n in dict.fromkeys(particle_material(t, spec.material) for t in s.type_names)},
        **deck.info()})
    if scene.statistics:        # what build's summary.json says of the structure, for the run's summary too
        stats = scene.statistics_of(deck.source)
        facts.statistics = table_of(stats)
        facts.structure = {k: getattr(stats, k) for k in scene.run_keys}
    facts.build_timings_s = dict(deck.structure.meta.get("timings_s", {}))
    record = RunRecord.new(spec, deck=table_of(facts), folder=out)
    record.write(out)
    return deck, record


def build(spec: BpmWorkflow, out: Path, say=print) -> None:
    """Structure + full deck (data.lmp, in.lmp, resume.lmp, run.sh) + summary.json; no run."""
    start = time.perf_counter()
    refuse_finished(out)
    say(f"building {spec.name} ({spec.kind})")
    deck, _ = prepare(spec, out, progress=say)
    scene = scene_of(spec)
    summary = {"workflow": spec.name, "opalflow_version": __version__}
    stats = scene.statistics_of(deck.source)
    if stats is not None:
        summary.update(table_of(stats))
    else:
        summary.update({"n_particles": deck.structure.n_particles, "n_bonds": deck.structure.n_bonds})
    if scene.describe:
        say(scene.describe(stats))
    summary["deck"] = deck.info()
    summary["timings_s"] = {**deck.structure.meta.get("timings_s", {}),
                            "total": round(time.perf_counter() - start, 3)}
    summary["spec"] = spec.to_dict()
    write_build_summary(out, summary)
    say(f"wrote {out}/data.lmp, in.lmp, run.sh ({time.perf_counter() - start:.1f} s); "
        f"'bash {out}/run.sh' runs it with LAMMPS alone")
