"""The quasi-static fracture method (opalflow/bpm/quasistatic.py) against what it replaces and between its
own designs, on the same samples.

    python bench/bench_quasistatic.py dynamic      # LAMMPS runs at plate speeds 1, 0.5, 0.25, 0.125 m/s
    python bench/bench_quasistatic.py resolvers    # re-solve designs: direct (Cholesky + Woodbury) vs amg
    python bench/bench_quasistatic.py compare      # quasi-static vs the dynamic runs extrapolated to zero rate
    python bench/bench_quasistatic.py scale [--diameters 60 45] [--record DIR[:TIME]]   # the paper's sample coarser
    python bench/bench_quasistatic.py tolerance    # bonds an event and re-solve residual against the exact sequence
    python bench/bench_quasistatic.py local        # the local step's depth and bound against every event re-solved
    python bench/bench_quasistatic.py verify --record DIR [--at K ...]   # a run's events against global re-solves
    python bench/bench_quasistatic.py gap [--out DIR] [--only NAME ...]   # bulk and opal: bonds, contacts, one at a time
    python bench/bench_quasistatic.py size [--breaking RULE] [--only NAME ...]   # the bulk's strength / E by block size

``dynamic``: quickstart and opal_quick compressed by the plate with ``smooth no`` (bonds break at full
load, the quasi-static rule) at four plate speeds past their peaks, LAMMPS's ``smooth yes`` (opalflow's
default deck) at four speeds (quickstart) and at 0.25 m/s (opal_quick), and contacts off at 0.25 m/s; strength, strain at peak,
bonds broken, wall.  The zero-rate value is the intercept of a straight line through strength against
speed.  ``resolvers``: the three designs on quickstart at d = 60 nm and on the first 100 events at d = 40 nm, then
whole runs at d = 40 nm with event tolerances 0, 0.01, 0.05 (and amg at 0.05): events, broken bonds, strength,
time, factorisations or CG iterations.  ``scale``: the paper's standard sample (``opal_fcc``) at coarser
particle diameters, each the whole command ``python -m opalflow run opal_fcc --set packing.diameter_nm=D
--set compression.method=quasistatic ...`` in a child process (peak memory from its rusage), with the
re-solve, event tolerance and local step given; ``--record DIR[:TIME]`` adds a run of that command instead (its folder,
and the ``/usr/bin/time -v`` output for its memory and wall time; a run stopped before its end gives its
events so far); the cost law: events, broken bonds and wall time against particles (power laws through
the complete rows of one setting), extrapolated to the paper's d = 15 nm; a new row replaces those of its
size and setting, which are kept under ``superseded`` (older code).  ``tolerance``: quickstart at
d = 40 nm, whole runs: the factor at event tolerances 0 (the exact sequence), 0.05, 0.1, 0.2, and amg at
0.05 and 0.1 with re-solves to 1e-5 and 1e-4 |b|: events, strength against the exact one, CG iterations.
``local``: the paper's sample at d = 45 nm, the local step 2, 3 and 4 bonds deep at ``local_rtol`` 1e-4 and
3e-5 against every event re-solved: events settled locally, strength, CG iterations, time.  ``verify``: a
finished run (the paper's d = 15 nm with the local step, where every event re-solved would take hours)
checked at a few events: from its broken bonds there, the next event by a global re-solve to 1e-7 |b|
against its own (:func:`verify`).  ``gap``: the strength gap to the paper, one thing changed at a time
(:data:`GAP_PLAN`): the pore-free silica block (:data:`BULK`, d = 40 nm) and the paper's sample at d = 45 nm
(:data:`FCC45`), the paper's rule, bonds as built, without the pairs closer than 1.005 d, with contacts
(``contacts.quasistatic``, both friction bounds), packed by the paper's generator's rule and bonded as its code
does by default (overlapping pairs unbonded, touching by contacts): E, strength, strength / E and strain at peak against the
paper's (bulk 601 MPa / 21.9 GPa, the sample 41.1 MPa / 1.7 GPa), the network statistics, the bonds each check
broke before the peak, the contacts pressing there (a finished run in ``--out`` is read, not re-run).
``size``: the pore-free block at d = 40 nm (:data:`SIZE_PLAN`) from 0.28 to 4.0 um^2 in cross-section and 0.4 to
2.0 um high, loaded by the plate and glued, with the breaking rule given: E, strength, strength / E against the
paper's bulk (601 MPa / 21.9 GPa; its opal changed by < 4 % in strength above 4 um^2).
Results: bench/results/quasistatic_dynamic.json, _resolvers.json, _compare.json, _scale.json, _tolerance.json,
_local.json, _verify_dD_RULE.json, _gap.json, _size_RULE.json.
One BLAS thread (threadpoolctl), as the run layer's jobs.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
SPEEDS = [1.0, 0.5, 0.25, 0.125]
SAMPLES = ["quickstart", "opal_quick"]
#: each sample's runs go past its peak (quasi-static strain at peak 0.0087 and 0.0165; the plate strain of a
#: dynamic run is larger by the plate's settling on the rough top)
STRAIN_MAX = {"quickstart": 0.014, "opal_quick": 0.026}


def machine() -> dict:
    return {"host": platform.node(), "cpus": os.cpu_count(), "load_1min": os.getloadavg()[0],
            "python": platform.python_version(), "date": time.strftime("%Y-%m-%d %H:%M")}


def dynamic(out: Path) -> None:
    import opalflow

    path = RESULTS / "quasistatic_dynamic.json"
    rows = json.loads(path.read_text())["rows"] if path.exists() else []
    done = {(r["workflow"], r["smooth"], r["contacts"], r["plate_speed_m_s"]) for r in rows}
    plan = [(w, False, True, v) for w in SAMPLES for v in SPEEDS] + [("quickstart", True, True, v) for v in SPEEDS]
    plan += [("opal_quick", True, True, 0.25)] + [(w, False, False, 0.25) for w in SAMPLES]
    for w, smooth, contacts, v in plan:
        if (w, smooth, contacts, v) in done:
            continue
        sets = [f"compression.plate_speed_m_s={v}", f"compression.strain_max={STRAIN_MAX[w]}", "compression.snapshot_strains=[]",
                f"bonds.smooth={str(smooth).lower()}", f"contacts.enabled={str(contacts).lower()}"]
        t = time.perf_counter()
        s = opalflow.run(w, out / f"{w}-{smooth}-{contacts}-{v}", set=sets, quiet=True)
        rows.append({"workflow": w, "smooth": smooth, "contacts": contacts, "plate_speed_m_s": v, "strain_max": STRAIN_MAX[w],
                     "strength_MPa": s["strength_MPa"], "strain_at_peak": s["strain_at_peak"],
                     "strain_at_peak_specimen": s.get("strain_at_peak_specimen"),
                     "youngs_modulus_GPa": s["youngs_modulus_GPa"], "broken_bonds": s["broken_bonds"],
                     "wall_s": round(time.perf_counter() - t, 1)})
        print(json.dumps(rows[-1]), flush=True)
        path.write_text(json.dumps({"machine": machine(), "rows": rows}, indent=1))


def resolvers(out: Path) -> None:
    import opalflow

    rows = []
    # (diameter, resolver, events_max, tolerance): both designs on the same events, then whole runs
    cases = [(60, "direct", 100000, 0.0), (60, "amg", 100000, 0.0), (60, "block-amg", 100000, 0.0),
             (40, "direct", 100, 0.0), (40, "amg", 100, 0.0), (40, "block-amg", 100, 0.0),
             (40, "direct", 100000, 0.0), (40, "direct", 100000, 0.01), (40, "direct", 100000, 0.05),
             (40, "amg", 100000, 0.05)]
    for d, r, n, tol in cases:
        sets = [f"packing.diameter_nm={d}", "compression.method=quasistatic", f"compression.resolver={r}",
                "compression.strain_max=0.03", "compression.snapshot_strains=[]", "compression.drop_loose=true",
                f"compression.events_max={n}", f"compression.event_tolerance={tol}"]
        s = opalflow.run("quickstart", out / f"r-{d}-{r}-{n}-{tol}", set=sets, quiet=True)
        q = s["quasistatic"]
        rows.append({"workflow": "quickstart", "diameter_nm": d, "resolver": r, "events_max": n, "tolerance": tol,
                     "n_particles": s["n_particles"],
                     "n_bonds": s["n_bonds"], "events": q["events"], "broken_bonds": s["broken_bonds"],
                     "strength_MPa": s["strength_MPa"], "youngs_modulus_GPa": s["youngs_modulus_GPa"],
                     "setup_s": q["setup_s"], "events_s": q["events_s"], "factorizations": q["factorizations"],
                     "cg_iterations": q["cg_iterations"], "wall_s": s["wall_s"]})
        print(json.dumps(rows[-1]), flush=True)
    (RESULTS / "quasistatic_resolvers.json").write_text(json.dumps({"machine": machine(), "rows": rows}, indent=1))


def zero_rate(rows: list[dict], key: str) -> dict:
    v = np.array([r["plate_speed_m_s"] for r in rows])
    y = np.array([r[key] for r in rows])
    slope, intercept = np.polyfit(v, y, 1)
    return {"zero_rate": float(intercept), "per_m_s": float(slope), "speeds": v.tolist(), "values": y.tolist()}


def compare(out: Path) -> None:
    import opalflow

    dyn = json.loads((RESULTS / "quasistatic_dynamic.json").read_text())["rows"]
    res = []
    for w in SAMPLES:
        sets = ["compression.method=quasistatic", "compression.strain_max=0.03", "compression.snapshot_strains=[]"]
        q = opalflow.run(w, out / f"q-{w}", set=sets, quiet=True)
        st = opalflow.run(w, out / f"s-{w}", set=["compression.method=static", "compression.snapshot_strains=[]"],
                          quiet=True)
        row = {"workflow": w, "quasistatic": {k: q[k] for k in ("strength_MPa", "strain_at_peak", "youngs_modulus_GPa",
                                                                 "broken_bonds", "wall_s")},
               "static_youngs_modulus_GPa": st["youngs_modulus_GPa"],
               "first_branch_vs_static": q["youngs_modulus_GPa"] / st["youngs_modulus_GPa"] - 1}
        for smooth in (True, False):
            sel = [r for r in dyn if r["workflow"] == w and r["smooth"] == smooth and r["contacts"]]
            if len(sel) < 2:
                continue
            key = "smooth_yes" if smooth else "smooth_no"
            row[key] = {"strength": zero_rate(sel, "strength_MPa"), "strain_at_peak": zero_rate(sel, "strain_at_peak")}
            row[key]["strength_error"] = q["strength_MPa"] / row[key]["strength"]["zero_rate"] - 1
            # the quasi-static strain is the top layer's: compare with the dynamic top layer's (the plate's
            # holds its settling on the rough top)
            if all(r.get("strain_at_peak_specimen") for r in sel):
                row[key]["strain_at_peak_specimen"] = zero_rate(sel, "strain_at_peak_specimen")
                row[key]["strain_at_peak_error"] = (q["strain_at_peak"]
                                                    / row[key]["strain_at_peak_specimen"]["zero_rate"] - 1)
        off = [r for r in dyn if r["workflow"] == w and not r["contacts"]]
        on = [r for r in dyn if r["workflow"] == w and r["contacts"] and not r["smooth"] and r["plate_speed_m_s"] == 0.25]
        if off and on:
            row["contacts_off_strength_change"] = off[0]["strength_MPa"] / on[0]["strength_MPa"] - 1
        res.append(row)
        print(json.dumps(row), flush=True)
    (RESULTS / "quasistatic_compare.json").write_text(json.dumps({"machine": machine(), "rows": res}, indent=1))


#: the paper's standard sample at d = 15 nm (bench/results/build_opal_fcc.json)
PAPER_PARTICLES = 1_624_700
SCALE_SETS = ["compression.method=quasistatic", "compression.drop_loose=true", "bonds.smooth=false"]


def scale_row(folder: Path, peak_GiB: float | None, wall_s: float | None = None) -> dict:
    """One row of ``scale`` from a run folder: a finished one (summary.json; ``complete`` false where it stopped
    at ``compression.events_max``, a probe of its first events), or one stopped before its end (its
    quasistatic_state.json: the events so far, ``complete`` false; ``wall_s`` from the time output)."""
    run = json.loads((folder / "run.json").read_text())
    spec = run["spec"]
    row = {"diameter_nm": spec["packing"]["diameter_nm"], "resolver": spec["compression"]["resolver"],
           "tolerance": spec["compression"]["event_tolerance"],
           "resolve_rtol": spec["compression"].get("resolve_rtol", 1e-6),
           "local_rtol": spec["compression"].get("local_rtol", 0.0),
           "breaking": spec["bonds"].get("breaking", "lammps"),
           "peak_memory_GiB": round(peak_GiB, 2) if peak_GiB else None, "created": run["provenance"]["created"]}
    if not (folder / "summary.json").exists():
        state = json.loads((folder / "quasistatic_state.json").read_text())
        events = state["events"]
        stress = [e["stress_MPa"] for e in events]
        p = int(np.argmax(stress))
        return {**row, "complete": False, "events": len(events),
                "broken_bonds": sum(len(e["bonds"]) for e in events),
                "broken_bonds_at_peak": sum(len(e["bonds"]) for e in events[:p]), "strength_MPa": stress[p],
                "strain_at_peak": events[p]["strain"], "peak_event": p + 1,
                "youngs_modulus_GPa": state["modulus_MPa"] / 1e3,
                "cg_iterations": sum(e["iterations"] for e in events), "wall_s": wall_s,
                "s_per_event": round(wall_s / len(events), 2) if wall_s else None}
    s = json.loads((folder / "summary.json").read_text())
    q = s["quasistatic"]
    return {**row, "resolver": q["resolver"], "complete": q["stopped"] != "events_max",
            "n_particles": s["n_particles"], "n_bonds": s["n_bonds"], "events": q["events"],
            "broken_bonds": s["broken_bonds"], "broken_bonds_at_peak": s.get("broken_bonds_at_peak"),
            "strength_MPa": s["strength_MPa"], "strain_at_peak": s["strain_at_peak"],
            "youngs_modulus_GPa": s["youngs_modulus_GPa"], "stopped": q["stopped"], "setup_s": q["setup_s"],
            "events_s": q["events_s"], "s_per_event": round(q["events_s"] / max(q["events"], 1), 2),
            "cg_iterations": q["cg_iterations"], "settled_locally": q.get("settled_locally", 0), "wall_s": s["wall_s"]}


def _time_output(path: str) -> tuple[float, float]:
    """(peak memory GiB, wall s) from a ``/usr/bin/time -v`` output."""
    peak = wall = 0.0
    for line in Path(path).read_text().splitlines():
        if "Maximum resident set size" in line:
            peak = int(line.split(":")[1]) / 2**20
        if "Elapsed (wall clock)" in line:
            parts = [float(x) for x in line.split(": ")[-1].split(":")]
            wall = sum(v * 60**k for k, v in enumerate(reversed(parts)))
    return peak, wall


def _setting(r: dict) -> tuple:
    """A row's setting: (re-solve, event tolerance, re-solve residual, local step's residual, breaking rule)."""
    return (r["resolver"], r["tolerance"], r.get("resolve_rtol", 1e-6), r.get("local_rtol", 0.0),
            r.get("breaking", "lammps"))


def scale(out: Path, diameters: list[float], resolver: str, tolerance: float, rtol: float, local_rtol: float,
          breaking: str, record: list[str]) -> None:
    path = RESULTS / "quasistatic_scale.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    rows = [r for r in old.get("rows", []) if "diameter_nm" in r]
    superseded = old.get("superseded", [])

    def add(row: dict) -> None:
        """``row`` replaces the rows of its size and setting (they move to ``superseded``: older code)."""
        key = lambda r: (r["diameter_nm"], *_setting(r))  # noqa: E731
        superseded.extend(r for r in rows if key(r) == key(row))
        rows[:] = [r for r in rows if key(r) != key(row)] + [row]
        print(json.dumps(row), flush=True)

    for d in diameters:
        folder = out / f"fcc-{d:g}"
        cmd = [sys.executable, "-m", "opalflow", "run", "opal_fcc", "--out", str(folder), "--set",
               f"packing.diameter_nm={d:g}", "--set", f"packing.tile_nm={0 if d > 47 else 380}",
               *[x for kv in SCALE_SETS for x in ("--set", kv)], "--set", f"compression.resolver={resolver}",
               "--set", f"compression.event_tolerance={tolerance}", "--set", f"compression.resolve_rtol={rtol}",
               "--set", f"compression.local_rtol={local_rtol}", "--set", f'bonds.breaking="{breaking}"']
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        if os.waitstatus_to_exitcode(status):
            raise SystemExit(f"{' '.join(cmd)} failed")
        add(scale_row(folder, usage.ru_maxrss / 2**20))
    for item in record:
        folder, _, timing = item.partition(":")
        add(scale_row(Path(folder), *(_time_output(timing) if timing else (None, None))))
    rows.sort(key=lambda r: -r["diameter_nm"])
    law = {}            # per setting (:func:`_setting`): a law needs two sizes run alike
    for setting in sorted({_setting(r) for r in rows}):
        whole = [r for r in rows if r.get("complete") and r.get("n_particles") and _setting(r) == setting]
        if len({r["n_particles"] for r in whole}) < 2:
            continue
        x = np.log([r["n_particles"] for r in whole])
        fit = {"diameters_nm": [r["diameter_nm"] for r in whole]}
        law[f"{setting[0]}, tolerance {setting[1]:g}, rtol {setting[2]:g}"
            + (f", local_rtol {setting[3]:g}" if setting[3] else "")
            + (f", breaking {setting[4]}" if setting[4] != "lammps" else "")] = fit
        for key in ("events", "broken_bonds_at_peak", "wall_s", "s_per_event", "strength_MPa"):
            slope, icpt = np.polyfit(x, np.log([max(r[key], 1e-9) for r in whole]), 1)
            fit[key] = {"exponent": float(slope), "at_paper_scale": float(np.exp(icpt) * PAPER_PARTICLES ** slope)}
    before = old.get("before") or {k: v for k, v in old.items() if k in ("direct", "amg")}
    path.write_text(json.dumps({"machine": machine(), "sample": "opal_fcc (the paper's standard sample) at coarser "
                                "particle diameters", "sets": SCALE_SETS, "rows": rows,
                                "cost_law_vs_particles": law, "paper_particles": PAPER_PARTICLES, "before": before,
                                "superseded": superseded},
                               indent=1) + "\n")


#: (re-solve, event tolerance, re-solve residual) of ``tolerance``: the exact sequence, the factor at three
#: tolerances, and amg at two tolerances and two residuals
TOLERANCE_PLAN = [("direct", 0.0, 1e-6), ("direct", 0.05, 1e-6), ("direct", 0.1, 1e-6), ("direct", 0.2, 1e-6),
                  ("amg", 0.05, 1e-5), ("amg", 0.1, 1e-5), ("amg", 0.05, 1e-4), ("amg", 0.1, 1e-4)]


def tolerance(out: Path) -> None:
    """Several bonds an event and looser re-solves against the exact sequence (the factor, one bond an
    event): quickstart at d = 40 nm (9 412 particles), whole runs, ``bonds.smooth = false``."""
    import opalflow

    path = RESULTS / "quasistatic_tolerance.json"
    rows = []
    for resolver, tol, rtol in TOLERANCE_PLAN:
        sets = ["packing.diameter_nm=40", "compression.method=quasistatic", "bonds.smooth=false",
                "compression.drop_loose=true", "compression.snapshot_strains=[]", f"compression.resolver={resolver}",
                f"compression.event_tolerance={tol}", f"compression.resolve_rtol={rtol}"]
        s = opalflow.run("quickstart", out / f"{resolver}-{tol:g}-{rtol:g}", set=sets, quiet=True)
        q = s["quasistatic"]
        rows.append({"resolver": resolver, "tolerance": tol, "resolve_rtol": rtol, "events": q["events"],
                     "broken_bonds": s["broken_bonds"], "strength_MPa": s["strength_MPa"],
                     "strain_at_peak": s["strain_at_peak"], "cg_iterations": q["cg_iterations"],
                     "events_s": q["events_s"], "wall_s": s["wall_s"]})
        exact = rows[0]["strength_MPa"]
        rows[-1]["strength_vs_exact"] = rows[-1]["strength_MPa"] / exact - 1
        print(json.dumps(rows[-1]), flush=True)
        path.write_text(json.dumps({"machine": machine(), "workflow": "quickstart", "diameter_nm": 40,
                                    "rows": rows}, indent=1) + "\n")


#: (bonds deep, local_rtol) of ``local``: every event re-solved, then the local step at two depths and bounds
LOCAL_PLAN = [(4, 0.0), (2, 1e-4), (4, 1e-4), (3, 3e-5), (4, 3e-5)]


def local(out: Path) -> None:
    """The local step (opalflow.bpm.quasistatic.LocalSettle) against every event re-solved: the paper's sample
    at d = 45 nm, ``amg`` to 1e-5 |b|, event tolerance 0.05, the patch depth (LOCAL_HOPS) and the bound
    (``compression.local_rtol``) varied; whole runs in this process, one after the other."""
    import opalflow
    from opalflow.bpm import quasistatic

    path = RESULTS / "quasistatic_local.json"
    rows = []
    for hops, local_rtol in LOCAL_PLAN:
        quasistatic.LOCAL_HOPS = hops
        sets = ["packing.diameter_nm=45", "packing.tile_nm=380", *SCALE_SETS, "compression.resolver=amg",
                "compression.event_tolerance=0.05", "compression.resolve_rtol=1e-5",
                f"compression.local_rtol={local_rtol}", "compression.snapshot_strains=[]"]
        s = opalflow.run("opal_fcc", out / f"local-{hops}-{local_rtol:g}", set=sets, quiet=True)
        q = s["quasistatic"]
        rows.append({"hops": hops, "local_rtol": local_rtol, "events": q["events"],
                     "settled_locally": q["settled_locally"], "broken_bonds": s["broken_bonds"],
                     "strength_MPa": s["strength_MPa"], "strain_at_peak": s["strain_at_peak"],
                     "cg_iterations": q["cg_iterations"], "events_s": q["events_s"], "wall_s": s["wall_s"]})
        rows[-1]["strength_vs_every_event_resolved"] = rows[-1]["strength_MPa"] / rows[0]["strength_MPa"] - 1
        print(json.dumps(rows[-1]), flush=True)
        path.write_text(json.dumps({"machine": machine(), "workflow": "opal_fcc", "diameter_nm": 45,
                                    "rows": rows}, indent=1) + "\n")


def _events_of(folder: Path) -> list[dict]:
    """A finished run's events (results.h5, group quasistatic) as the event loop's state keeps them."""
    import h5py

    with h5py.File(folder / "results.h5") as h:
        g = h["quasistatic"]
        cuts = np.cumsum(g["bonds_per_event"][()])[:-1]
        bonds = np.split(g["broken_bond_index"][()], cuts)
        return [{"strain": float(e), "stress_MPa": float(s), "stress_after_MPa": float(a), "bonds": b.tolist()}
                for e, s, a, b in zip(g["strain"][()], g["stress_MPa"][()], g["stress_after_MPa"][()], bonds)]


def verify(run: Path, at: list[int], out: Path, rtol: float = 1e-7) -> None:
    """A run with the local step (or loose re-solves) checked where it went: from its own broken bonds
    before event k, the next event found by a global re-solve to ``rtol`` |b| (the run resumed from those
    events with ``compression.local_rtol = 0``, ``events_max = k + 1``): its strain, stress and bonds
    against the run's own event k.  ``at``: the events (default: a quarter, half way and the peak)."""
    import opalflow

    summary = json.loads((run / "summary.json").read_text())
    record = json.loads((run / "run.json").read_text())
    events = _events_of(run)
    peak = int(np.argmax([e["stress_MPa"] for e in events]))
    rule = record["spec"]["bonds"].get("breaking", "lammps")
    path = RESULTS / f"quasistatic_verify_d{record['spec']['packing']['diameter_nm']:g}_{rule}.json"
    head = {"machine": machine(), "run": str(run), "strength_MPa": summary["strength_MPa"],
            "setting": {key: record["spec"]["compression"].get(key)
                        for key in ("resolver", "resolve_rtol", "local_rtol", "event_tolerance")},
            "breaking": rule, "n_particles": summary["n_particles"], "resolve_rtol": rtol}
    rows = []
    for k in at or [peak // 4, peak // 2, peak]:
        folder = out / f"at-{k}"
        folder.mkdir(parents=True)
        spec = json.loads(json.dumps(record["spec"]))
        spec["compression"].update(local_rtol=0.0, resolve_rtol=rtol, events_max=k + 1)
        (folder / "run.json").write_text(json.dumps({**record, "spec": spec}))
        (folder / "quasistatic_state.json").write_text(json.dumps(
            {"events": events[:k], "modulus_MPa": summary["youngs_modulus_GPa"] * 1e3}))
        t = time.perf_counter()
        opalflow.run(None, folder, resume=True, quiet=True)
        got = _events_of(folder)[k]
        mine = events[k]
        a, b = set(got["bonds"]), set(mine["bonds"])
        rows.append({"event": k + 1, "peak_event": peak + 1, "strain": mine["strain"], "strain_resolved": got["strain"],
                     "strain_error": mine["strain"] / got["strain"] - 1, "stress_MPa": mine["stress_MPa"],
                     "stress_resolved_MPa": got["stress_MPa"],
                     "stress_error": mine["stress_MPa"] / got["stress_MPa"] - 1,
                     "bonds": len(b), "bonds_resolved": len(a), "bonds_shared": len(a & b),
                     "wall_s": round(time.perf_counter() - t, 1)})
        print(json.dumps(rows[-1]), flush=True)
        path.write_text(json.dumps({**head, "rows": rows}, indent=1) + "\n")       # (after every point)


#: the pore-free block of workflows/bulk_silica.toml (400 x 693 x 400 nm above a two-layer substrate, periodic
#: sides), quasi-static with the paper's code's rule, unsmoothed bonds, past its peak
BULK = ['pores.arrangement="none"', 'boundary.sides="periodic"', "pores.diameter_nm=400.0", "pores.spacing_nm=400.0",
        "pores.layers=1", "bonds.smooth=false", "compression.strain_max=0.15", 'compression.method="quasistatic"',
        'bonds.breaking="musen"', "compression.snapshot_strains=[]", "packing.diameter_nm=40.0"]
#: the paper's sample at d = 45 nm as ``scale`` runs it with the paper's rule (its README row: 8.844 MPa)
FCC45 = [*SCALE_SETS, "packing.diameter_nm=45", "packing.tile_nm=380", "compression.resolver=amg",
         "compression.event_tolerance=0.05", "compression.resolve_rtol=1e-5", 'bonds.breaking="musen"',
         "compression.snapshot_strains=[]"]
#: ... and at d = 30 nm (the scale row with the paper's rule: 20.59 MPa with the local step)
FCC30 = [kv.replace("packing.diameter_nm=45", "packing.diameter_nm=30") for kv in FCC45]
#: (name, workflow, settings, reference) of ``gap``: each sample as built, then one thing changed at a time
GAP_PLAN = [("bulk40_musen", "quickstart", BULK, "bulk"),
            ("bulk40_musen_min1005", "quickstart", [*BULK, "bonds.min_length_factor=1.005"], "bulk"),
            ("bulk40_c_frictionless_0.01", "quickstart", [*BULK, 'contacts.quasistatic="frictionless"'], "bulk"),
            ("bulk40_c_sticking_0.01", "quickstart", [*BULK, 'contacts.quasistatic="sticking"'], "bulk"),
            ("bulk40_c_sticking_0.05", "quickstart", [*BULK, 'contacts.quasistatic="sticking"',
                                                      "contacts.reference_strain=0.05"], "bulk"),
            ("bulk40_musenpack", "quickstart", [*BULK, 'packing.method="musen"'], "bulk"),
            ("bulk40_musenpack_min1", "quickstart", [*BULK, 'packing.method="musen"', "bonds.min_length_factor=1.0"],
             "bulk"),
            ("bulk40_musenpack_min1_c_sticking", "quickstart", [*BULK, 'packing.method="musen"',
                                                                "bonds.min_length_factor=1.0",
                                                                'contacts.quasistatic="sticking"'], "bulk"),
            # on one network strength / E follows sigma_b / E_b (the paper's Table 1: titania's row does, silica's
            # is 1.9x it): silica's bonds at titania's Poisson ratio, then titania's bonds (20 nm coating's E_b)
            ("bulk40_nu028", "quickstart", [*BULK, "materials.silica.bond_poisson_ratio=0.28"], "bulk"),
            ("bulk40_titania_bonds", "quickstart", [*BULK, "materials.silica.bond_poisson_ratio=0.28",
                                                     "materials.silica.bond_youngs_modulus_GPa=17.89",
                                                     "materials.silica.bond_strength_MPa=834.0"], "titania_bulk"),
            ("fcc45_musen", "opal_fcc", FCC45, "opal"),
            ("fcc45_c_frictionless", "opal_fcc", [*FCC45, 'contacts.quasistatic="frictionless"'], "opal"),
            ("fcc45_c_sticking", "opal_fcc", [*FCC45, 'contacts.quasistatic="sticking"'], "opal"),
            ("fcc45_musenpack", "opal_fcc", [*FCC45, 'packing.method="musen"'], "opal"),
            ("fcc45_musenpack_min1", "opal_fcc", [*FCC45, 'packing.method="musen"', "bonds.min_length_factor=1.0"],
             "opal"),
            ("fcc30_musen", "opal_fcc", FCC30, "opal"),
            ("fcc30_c_frictionless", "opal_fcc", [*FCC30, 'contacts.quasistatic="frictionless"'], "opal"),
            ("fcc30_c_sticking", "opal_fcc", [*FCC30, 'contacts.quasistatic="sticking"'], "opal"),
            ("fcc30_musenpack", "opal_fcc", [*FCC30, 'packing.method="musen"'], "opal"),
            ("fcc30_musenpack_min1", "opal_fcc", [*FCC30, 'packing.method="musen"', "bonds.min_length_factor=1.0"],
             "opal")]
#: the paper's numbers (Dosta et al.): the bulk silica (section 3.1.2: E_macro, strength ~ E/35) and the standard
#: sample (41.1 MPa at ~1.7 GPa: strain >= 0.024)
PAPER = {"bulk": {"youngs_modulus_GPa": 21.9, "strength_MPa": 601.0, "source": "section 3.1.2"},
         "opal": {"youngs_modulus_GPa": 1.7, "strength_MPa": 41.1, "source": "section 3.1.2, Fig. 8"},
         "titania_bulk": {"youngs_modulus_GPa": None, "strength_MPa": 2843.0,
                          "source": "Table 1 (20 nm coating's bonds): 2843 MPa simulated; its 60 GPa is the experiment "
                                    "(Colombi et al.) the bonds were scaled to, an input, not a simulated E"}}


def gap(out: Path, names: list[str]) -> None:
    """The rows of :data:`GAP_PLAN` (those named, or all): E, strength, strength / E and strain at peak against the
    paper's, the network statistics and the bonds each check broke before the peak (module docstring)."""
    import opalflow
    from opalflow.bpm.bonds import network_statistics
    from opalflow.opal.scene import build_opal
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    path = RESULTS / "quasistatic_gap.json"
    for name, workflow, sets, ref in GAP_PLAN:
        if names and name not in names:
            continue
        folder = out / name
        done = folder / "summary.json"
        s = json.loads(done.read_text()) if done.exists() else opalflow.run(workflow, folder, set=sets, quiet=True)
        structure = build_opal(load_spec(WORKFLOWS / f"{workflow}.toml", sets))[0]
        net = network_statistics(structure.positions, structure.diameters, structure.box_lengths, structure.periodic,
                                 structure.bonds, structure.meta["packing_solid_fraction"])
        paper = PAPER[ref]
        ratio = s["strength_MPa"] / (1e3 * s["youngs_modulus_GPa"])
        q = s["quasistatic"]
        row = {"name": name, "workflow": workflow, "set": sets, "n_particles": s["n_particles"],
               "n_bonds": s["n_bonds"], "box_nm": structure.box_lengths.tolist(), "network": net,
               "youngs_modulus_GPa": s["youngs_modulus_GPa"], "strength_MPa": s["strength_MPa"],
               "strain_at_peak": s["strain_at_peak"], "strength_over_E": ratio,
               "paper": ref, "strength_vs_paper": s["strength_MPa"] / paper["strength_MPa"] - 1,
               **({"E_vs_paper": s["youngs_modulus_GPa"] / paper["youngs_modulus_GPa"] - 1,
                   "strength_over_E_vs_paper": ratio / (paper["strength_MPa"] / 1e3 / paper["youngs_modulus_GPa"]) - 1}
                  if paper["youngs_modulus_GPa"] else {}),
               "events": q["events"], "broken_bonds_at_peak": s["broken_bonds_at_peak"],
               "broken_bonds_by_check_at_peak": s["broken_bonds_by_check_at_peak"],
               "contacts": q.get("contacts", "off"), "contact_pairs": q.get("contact_pairs", 0),
               "contacts_pressing_at_peak": q.get("contacts_pressing_at_peak", 0),
               "wall_s": s["wall_s"], "machine": machine()}
        print(json.dumps({k: row[k] for k in ("name", "youngs_modulus_GPa", "strength_MPa", "strain_at_peak",
                                              "contacts_pressing_at_peak", "wall_s")}), flush=True)
        kept = {r["name"]: r for r in json.loads(path.read_text())["rows"]} if path.exists() else {}
        kept[name] = row             # (read again before each write: several gap runs may share the file)
        rows = [kept[n] for n, *_ in GAP_PLAN if n in kept]
        path.write_text(json.dumps({"paper": PAPER, "rows": rows}, indent=1) + "\n")


#: the pore-free silica block at d = 40 nm by size, (name, cross-section cells of ``pores.spacing_nm`` (x, y), spacing,
#: height's ``pores.diameter_nm`` and ``pores.layers``): lx = cells_x a, ly = cells_y a sqrt(3), h = D + (layers - 1)
#: a sqrt(2/3) (opalflow.opal.spec.sample_box_nm) above the two-layer substrate; periodic sides, packed whole
SIZE_PLAN = [("a0.28_h0.4", (1, 1), 400.0, 400.0, 1),        # 400 x 693 x 400 nm: bulk_silica's block
             ("a1.0_h0.4", (1, 1), 762.0, 400.0, 1),         # 762 x 1320 x 400
             ("a4.0_h0.4", (2, 2), 762.0, 400.0, 1),         # 1524 x 2640 x 400
             ("a0.28_h2.0", (1, 1), 400.0, 400.0, 6),        # 400 x 693 x 2033
             ("a1.0_h2.0", (1, 1), 762.0, 762.0, 3),         # 762 x 1320 x 2006: the opal's cell
             ("a4.0_h2.0", (2, 2), 762.0, 762.0, 3)]         # 1524 x 2640 x 2006: above the paper's 4 um^2
#: the quasi-static settings of the size runs (FCC45's: AMG re-solves to 1e-5, bonds within 5 % of the next limit
#: in one event, the local step; the 2 um blocks stop at 0.8 of the peak, the 0.4 um ones ran to 0.5)
SIZE_SETS = ['pores.arrangement="none"', 'boundary.sides="periodic"', "packing.diameter_nm=40.0", "packing.tile_nm=0.0",
             "bonds.smooth=false", 'compression.method="quasistatic"', "compression.strain_max=0.1",
             "compression.stop_fraction=0.8", "compression.snapshot_strains=[]", "compression.event_tolerance=0.05",
             "compression.resolve_rtol=1e-5", "compression.local_rtol=3e-5", "compression.resolver=amg",
             'compression.plots="none"']


def size(out: Path, breaking: str, names: list[str], seeds: list[int], loadings: list[str]) -> None:
    """The rows of :data:`SIZE_PLAN` (those named, or all) under each of ``loadings``, one packing per seed of
    ``seeds`` (packing.seed; the workflow's, 1, where none is given: the rows without ``seed``), a finished run in
    ``--out`` read."""
    import opalflow

    path = RESULTS / f"quasistatic_size_{breaking}.json"
    paper = PAPER["bulk"]
    for name, (cx, cy), a, D, layers in SIZE_PLAN:
        if names and name not in names:
            continue
        for loading, seed in ((x, k) for x in loadings for k in (seeds or [None])):
            folder = out / (f"{name}_{loading}_{breaking}" + (f"_seed{seed}" if seed is not None else ""))
            sets = [*SIZE_SETS, f"pores.cells_x={cx}", f"pores.cells_y={cy}", f"pores.spacing_nm={a}",
                    f"pores.diameter_nm={D}", f"pores.layers={layers}", f'compression.loading="{loading}"',
                    f'bonds.breaking="{breaking}"', *([f"packing.seed={seed}"] if seed is not None else [])]
            done = folder / "summary.json"
            s = json.loads(done.read_text()) if done.exists() else opalflow.run("quickstart", folder, set=sets,
                                                                                 quiet=True)
            info = json.loads((folder / "run.json").read_text())["deck"]
            ratio = s["strength_MPa"] / (1e3 * s["youngs_modulus_GPa"])
            row = {"name": name, "loading": loading, "breaking": breaking, "set": sets,
                   **({"seed": seed} if seed is not None else {}),
                   "cross_section_um2": info["area_nm2"] / 1e6, "height_um": info["height_nm"] / 1e3,
                   "n_particles": s["n_particles"], "n_bonds": s["n_bonds"],
                   "youngs_modulus_GPa": s["youngs_modulus_GPa"], "strength_MPa": s["strength_MPa"],
                   "strain_at_peak": s["strain_at_peak"], "strength_over_E": ratio,
                   "strength_over_E_vs_paper": ratio / (paper["strength_MPa"] / 1e3 / paper["youngs_modulus_GPa"]) - 1,
                   "events": s["quasistatic"]["events"], "broken_bonds_at_peak": s["broken_bonds_at_peak"],
                   "broken_bonds_by_check_at_peak": s["broken_bonds_by_check_at_peak"], "wall_s": s["wall_s"],
                   "machine": machine()}
            print(json.dumps({k: row[k] for k in ("name", "loading", "n_particles", "youngs_modulus_GPa",
                                                  "strength_MPa", "strength_over_E", "wall_s")}), flush=True)
            key = lambda r: (r["name"], r["loading"], r.get("seed", 0))          # noqa: E731 (seed 0: the workflow's)
            kept = {key(r): r for r in json.loads(path.read_text())["rows"]} if path.exists() else {}
            kept[key(row)] = row
            rows = [kept[k] for k in sorted(kept, key=lambda k: ([n for n, *_ in SIZE_PLAN].index(k[0]), k[1], k[2]))]
            path.write_text(json.dumps({"paper": paper, "rows": rows}, indent=1) + "\n")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("part", choices=["dynamic", "resolvers", "compare", "scale", "tolerance", "local", "verify", "gap",
                                   "size"])
    p.add_argument("--out", default="", help="folder for the runs (default: a temporary one)")
    p.add_argument("--diameters", type=float, nargs="*", default=[60.0, 45.0], help="scale: particle diameters (nm)")
    p.add_argument("--resolver", default="amg", help="scale: compression.resolver")
    p.add_argument("--tolerance", type=float, default=0.05, help="scale: compression.event_tolerance")
    p.add_argument("--rtol", type=float, default=1e-6, help="scale: compression.resolve_rtol")
    p.add_argument("--local-rtol", type=float, default=0.0, help="scale: compression.local_rtol")
    p.add_argument("--breaking", default="lammps", help="scale, size: bonds.breaking (the breaking rule)")
    p.add_argument("--record", nargs="*", default=[], help="scale: finished run folders to add, DIR[:TIME_OUTPUT]; "
                   "verify: the run to check")
    p.add_argument("--at", type=int, nargs="*", default=[], help="verify: event indices (0-based) to check")
    p.add_argument("--only", nargs="*", default=[], help="gap, size: the rows to run (names of GAP_PLAN, SIZE_PLAN)")
    p.add_argument("--seeds", type=int, nargs="*", default=[], help="size: packing seeds (default: the workflow's)")
    p.add_argument("--loadings", nargs="*", default=["plate", "glued"], choices=["plate", "glued"],
                   help="size: the loadings run (default both)")
    a = p.parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(a.out or tmp)
        if a.part == "scale":
            scale(out, a.diameters, a.resolver, a.tolerance, a.rtol, a.local_rtol, a.breaking, a.record)
        elif a.part == "verify":
            verify(Path(a.record[0]), a.at, out)
        elif a.part == "gap":
            gap(out, a.only)
        elif a.part == "size":
            size(out, a.breaking, a.only, a.seeds, a.loadings)
        else:
            {"dynamic": dynamic, "resolvers": resolvers, "compare": compare, "tolerance": tolerance,
             "local": local}[a.part](out)


if __name__ == "__main__":
    sys.exit(main())
