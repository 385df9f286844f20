"""MUSEN, the paper's own code (Dosta et al.; github.com/msolids/musen), as the peer of opalflow's bonded-particle
model: the same particles, bonds, substrate, loading and periodic box run by both codes, side by side.

Not in CI and not run by the tests: it needs a ``CMUSEN`` binary built from a MUSEN checkout (``--cmusen PATH`` or
the ``MUSEN_CMUSEN`` environment variable).  opalflow holds no MUSEN code and no recipe that builds it.

How opalflow's scene becomes a MUSEN scene (MUSEN's text format: its ``Documentation/Text file format.pdf`` and
``Modules/SimResultsStorage/ImportFromText.cpp``; script keys: ``Modules/ScriptInterface/ScriptAnalyzer.cpp``):

- every particle a sphere of the same radius (contact radius = radius), SI units (m, kg, s);
- every bond a solid bond between the same two particles, diameter ``2 bonds.radius_factor r`` and initial length
  the built centre distance, of a bond compound with the material's bond E, nu and strength (data/materials.toml;
  MUSEN's tangential strength = normal, as opalflow and the paper take it): ``ModelSBElastic`` with
  ``CONSIDER_BREAKAGE 1``, the paper's rule as MUSEN computes it (``bonds.breaking = "musen"`` in opalflow);
- the substrate: its particles of a compound ``held`` with the density x :data:`HEAVY` (at rest, they do not move
  within the run); the top particle layer (opalflow's: centres within 3/4 d of the top) of a compound ``driven``,
  as heavy, moving at the plate's velocity from the first step: opalflow's ``compression.loading = "glued"`` (the
  top layer moves with the wall in all six degrees of freedom); the plate stress is the z force on the driven
  layer over the cross-section, the strain the driven layer's displacement over the sample's height;
- periodic sides where opalflow's are (PBC over the same box);
- unbonded touching particles: Hertz-Mindlin contacts (``ModelPPHertzMindlin``, the material's contact E, nu,
  restitution, friction), MUSEN's contact model for pairs without a bond;
- every free particle starts at the velocity of its height in the uniform strain rate (opalflow's affine start);
- no damping: MUSEN's elastic bond has none (opalflow's dynamic decks damp bonds at ``bonds.damping_ratio``).

``--loading plate`` is the paper's loading instead (section 2.1: "a diamond plate ... moving in the vertical
direction"): every particle at rest, no driven layer; the plate two triangular walls over the whole periodic box at
the sample's top (a geometry of compound ``plate``, diamond's contact E and nu, data/materials.toml), moving down at
the plate speed from the first step (``ModelPWHertzMindlin``); the stress is the walls' z force over the
cross-section, the strain the plate's displacement over the sample's height.  MUSEN removes a broken bond at once
(no 1 ns fade in its code), as opalflow's ``bonds.smooth = false``.

``--rule`` names opalflow's breaking rule the row compares (:data:`CRITERION`): ``musen`` and ``musen_crit2`` are
MUSEN's ``CONSIDER_BREAKAGE`` 1 and 2; ``musen_2020`` needs a CMUSEN whose ModelSBElastic check is that of MUSEN's
first public commit (655e066).  ``--musen-commit`` says which MUSEN source built the binary; every row records it.

opalflow runs the same spec: quasi-static (the rule given, contacts off / frictionless / sticking) and dynamic
(LAMMPS, ``bonds.smooth = false``; with the plate: undamped, sample at rest, LAMMPS's rule, the only one it has).
Every curve gives its first peak (:func:`first_peak`) and its maximum.  Results: bench/results/musen_peer.json.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
#: the substrate's and the driven layer's density factor: a driven particle's velocity changes by
#: F t / (HEAVY m) ~ 1e-7 of the plate's over a run
HEAVY = 1.0e12
NM = 1.0e-9
#: the pore-free silica block of bench_quasistatic's gap study (BULK there), at the size named
BULK = ['pores.arrangement="none"', 'boundary.sides="periodic"', "pores.diameter_nm=400.0", "pores.spacing_nm=400.0",
        "pores.layers=1", "bonds.smooth=false", 'bonds.breaking="musen"', "compression.snapshot_strains=[]",
        'compression.loading="glued"', 'compression.method="quasistatic"']
#: the paper's sample at d = 45 nm as bench_quasistatic's gap study runs it (FCC45 there: AMG re-solves, bonds within
#: 5 % of the next limit break in one event), glued
OPAL45 = ["compression.method=quasistatic", "compression.drop_loose=true", "bonds.smooth=false",
          "packing.diameter_nm=45", "packing.tile_nm=380", "compression.resolver=amg",
          "compression.event_tolerance=0.05",
          "compression.resolve_rtol=1e-5", 'bonds.breaking="musen"', "compression.snapshot_strains=[]",
          'compression.loading="glued"']
#: opalflow's breaking rule -> MUSEN's ``CONSIDER_BREAKAGE`` (``musen_2020``: the check of 655e066, built in)
CRITERION = {"musen": 1, "musen_crit2": 2, "musen_2020": 1}
#: case -> (workflow, settings, strain_max, opalflow's runs of it: the labels of :data:`OPALFLOW`)
CASES = {"bulk60": ("quickstart", [*BULK, "packing.diameter_nm=60.0"], 0.05,
                    ["quasistatic", "quasistatic_frictionless", "quasistatic_sticking", "dynamic_lammps_rule"]),
         "bulk40": ("quickstart", [*BULK, "packing.diameter_nm=40.0"], 0.05,
                    ["quasistatic", "quasistatic_frictionless", "quasistatic_sticking"]),
         "opal45": ("opal_fcc", OPAL45, 0.025, ["quasistatic", "quasistatic_frictionless", "quasistatic_sticking"])}


def num(v) -> str:
    """A number as MUSEN reads it (numpy 2's repr of np.float64 is not one)."""
    return repr(float(v))


def loaded(workflow: str, sets: list[str]):
    """opalflow's spec and loaded sample (the structure the static, quasi-static and dynamic runs share)."""
    from opalflow.bpm.deck import loaded_sample
    from opalflow.bpm.scene import scene_of
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    spec = load_spec(WORKFLOWS / f"{workflow}.toml", sets)
    s = scene_of(spec).structure(spec, lambda m: None)
    return spec, loaded_sample(spec, s)


def scene_text(spec, sample, speed_m_s: float, plate: bool = False, legacy: bool = False) -> str:
    """The MUSEN text scene of ``sample`` (module docstring): glued (the top layer driven, the rest on the affine
    field) or, with ``plate``, at rest under a plate wall.  ``legacy`` (a MUSEN before 1.70.0): the simulation
    domain two diameters wider than the periodic box on every side (655e066's Verlet grid, ContactAnalyzers/VerletList.cpp
    RecalcParticlesPositions, spans the domain alone
    and writes the periodic images of particles near a side out of its bounds: a segfault at the first step)."""
    from opalflow.bpm.deck import particle_material
    from opalflow.materials import contact_properties, material

    data = sample.structure
    names = {particle_material(n, spec.material) for n in data.type_names}
    if len(names) != 1:
        raise SystemExit(f"one particle material only (the bulk and the uncoated opal), not {sorted(names)}")
    mat = names.pop()
    m = material(mat, spec.materials)
    c = contact_properties(mat)
    rho = m.density_kg_m3
    E_c, nu_c = c.youngs_modulus_MPa * 1e6, c.poisson_ratio
    sigma = m.bond_strength_MPa * 1e6
    lines = []
    for key, density in (("particle", rho), ("held", HEAVY * rho), ("driven", HEAVY * rho)):
        lines.append(f"32 {key} {key} 0 {num(density)} 7 {num(E_c)} 10 {num(nu_c)}")
    lines.append(f"32 bond bond 0 {num(rho)} 7 {num(m.bond_youngs_modulus_GPa * 1e9)} "
                 f"10 {num(m.bond_poisson_ratio)} "
                 f"8 {num(sigma)} 9 {num(sigma)}")
    keys = ("particle", "held", "driven")
    for a in keys:
        for b in keys:
            lines.append(f"33 {a} {b} 200 {num(c.restitution)} 201 {num(c.friction)} 202 0")
    if plate:
        d = contact_properties("diamond")
        lines.append(f"32 plate plate 0 {num(material('diamond', {}).density_kg_m3)} 7 "
                     f"{num(d.youngs_modulus_MPa * 1e6)} 10 {num(d.poisson_ratio)}")
        for a in keys:
            lines.append(f"33 {a} plate 200 {num(d.restitution)} 201 {num(d.friction)} 202 0")
    lo, hi = data.box_lo * NM, data.box_hi * NM
    # the simulation domain holds the plate too (MUSEN leaves what lies outside it out of the contact search)
    top = max(float(hi[2]), (sample.plate_z0_nm + 2 * float(np.max(data.diameters))) * NM) if plate else float(hi[2])
    margin = 2 * float(np.max(data.diameters)) * NM if legacy else 0.0
    lines.append("22 " + " ".join(num(v) for v in (*(lo - margin), *(hi[:2] + margin), top + margin)))
    p = [bool(v) for v in data.periodic]
    if any(p):
        lines.append(f"28 1 {int(p[0])} {int(p[1])} {int(p[2])} " + " ".join(num(v) for v in (*lo, *hi)))
    held, driven = data.groups["substrate"], sample.top_layer
    x, r = (data.positions * NM).tolist(), (data.diameters / 2 * NM).tolist()      # Python floats: repr is a number
    # the affine start (opalflow's dynamic decks' too): every free particle at the velocity of its height in the
    # uniform strain rate, so the run starts without the shock of a layer set moving against a sample at rest
    # (undamped, that shock rings through the whole run: the opal at d = 45 nm swung between -5.7 and +2.6 MPa)
    rise = np.clip((data.positions[:, 2] - sample.base_nm) / sample.height_nm, 0.0, 1.0)
    if plate:                              # the paper's test: the sample at rest, nothing driven but the plate
        driven, rise = np.zeros_like(driven), np.zeros_like(rise)
    for i in range(data.n_particles):
        key = "held" if held[i] else "driven" if driven[i] else "particle"
        vz = -speed_m_s if driven[i] else 0.0 if held[i] else -speed_m_s * float(rise[i])
        lines.append(f"0 {i} 1 1 5 {num(r[i])} {num(r[i])} 23 {key} 24 0 1e300 "
                     f"2 0 12 {num(x[i][0])} {num(x[i][1])} {num(x[i][2])} "
                     f"15 0 0 {num(vz)}")
    d_b = [2 * spec.bonds.radius_factor * v for v in r]
    for k, ((i, j), L0) in enumerate(zip(data.bonds.tolist(), (sample.bond_lengths * NM).tolist())):
        lines.append(f"0 {data.n_particles + k} 1 9 5 {i} {j} {num(min(d_b[i], d_b[j]))} {num(L0)} "
                     "23 bond 24 0 1e300 2 0")
    if plate:
        lines += plate_lines(data.n_particles + data.n_bonds, lo, hi, sample.plate_z0_nm * NM, speed_m_s)
    return "\n".join(lines) + "\n"


def plate_lines(first_id: int, lo, hi, z: float, speed_m_s: float) -> list[str]:
    """The plate: two triangular walls (MUSEN object type 14, vertices by ``44``) over the box's x-y extent at height
    ``z`` and the geometry that moves them down at ``speed_m_s`` from t = 0 (``25`` name key mass free-motion
    rotate-about-centre, ``27`` its walls, ``26`` a time-dependent motion: one interval of velocity, rotation centre
    and rotation velocity; Modules/SimResultsStorage/ImportFromText.cpp, Modules/Geometries/GeometryMotion.h)."""
    (x0, y0), (x1, y1) = lo[:2], hi[:2]
    corners = [((x0, y0), (x1, y1), (x1, y0)), ((x0, y0), (x0, y1), (x1, y1))]     # normals down, to the sample
    out = []
    for k, tri in enumerate(corners):
        xyz = " ".join(f"{num(a)} {num(b)} {num(z)}" for a, b in tri)
        out.append(f"0 {first_id + k} 1 14 5 23 plate 24 0 1e300 2 0 44 {xyz}")
    out += ["25 plate plate 0 0 0 0 0", f"27 2 {first_id} {first_id + 1}",
            f"26 1 1 0 1e300 0 0 {num(-speed_m_s)} 0 0 0 0 0 0"]
    return out


def musen_version(cmusen: str) -> tuple[int, ...]:
    """The version CMUSEN reports (``cmusen -v``: "Version: 1.63.4" for 655e066, the first public commit)."""
    out = subprocess.run([cmusen, "-v"], capture_output=True, text=True).stdout
    words = next((line.split()[1] for line in out.splitlines() if line.startswith("Version:")), "0")
    return tuple(int(v) for v in words.split(".") if v.isdigit())


#: the most bonds whose activity a legacy MUSEN exports here (bulk d = 40 nm: 27 798 bonds, 111 MB of text; the opal
#: at d = 45 nm passed 20 GB and was stopped)
LEGACY_BOND_EXPORT = 50_000
#: MUSEN before Release 1.70.0 (1547403): the text export's older script keys (ScriptAnalyzer.cpp of 655e066)
#: and one breaking rule only (``CONSIDER_BREAKAGE 1`` is 2020's check: opalflow's ``musen_2020``)
LEGACY = (1, 70)


def script_text(folder: Path, dt: float, end_time: float, saving: float, criterion: int = 1,
                plate: bool = False, legacy: bool = False, bond_export: bool = True) -> str:
    """CMUSEN's script: import the scene, simulate on the CPU (saving the particles' forces alone: all of the
    state of the opal at d = 45 nm, 200 times, is 7.3 GB), export every bond's activity interval (once: at every
    saved time the bonds' lines were 2 GB) and the particles' forces.  ``legacy``: a MUSEN older than
    :data:`LEGACY` (its export keys: objects p/sb/lb/walls, constants id/type/geometry/material/activity, one
    ``TEXT_EXPORT_TD`` of eleven flags, force the fifth; no time interval, no wall coordinates); ``bond_export``
    False: no bonds.txt (the broken bonds are then not counted)."""
    sim = f"""JOB
COMPONENT IMPORT_FROM_TEXT
SOURCE_FILE {folder / 'scene.txt'}
RESULT_FILE {folder / 'scene.mdem'}
JOB
COMPONENT SIMULATOR
SOURCE_FILE {folder / 'scene.mdem'}
RESULT_FILE {folder / 'run.mdem'}
SIMULATOR_TYPE CPU
EXT_ACCEL 0 0 0
SELECTIVE_SAVING_P 0 0 1 0 0 0 0
SELECTIVE_SAVING_SB 0 0 0
MODEL_PP ModelPPHertzMindlin
MODEL_SB ModelSBElastic
MODEL_SB_PARAMS CONSIDER_BREAKAGE {criterion}
""" + ("MODEL_PW ModelPWHertzMindlin\n" if plate else "") + f"""SIMULATION_STEP {num(dt)}
SAVING_STEP {num(saving)}
END_TIME {num(end_time)}
"""
    if legacy:          # (its bonds' export writes every saved time on every bond's line: 20 GB for the opal)
        off = ["TEXT_EXPORT_GEOMETRIES 0 0 0"]
        bonds = _export(folder, "bonds.txt", ["TEXT_EXPORT_OBJECTS 0 1 0 0", "TEXT_EXPORT_CONST 1 1 0 0 1",
                                              "TEXT_EXPORT_TD 0 0 0 0 0 0 0 0 0 0 0", *off]) if bond_export else ""
        return sim + bonds + _export(folder, "export.txt", ["TEXT_EXPORT_OBJECTS 1 0 0 0", "TEXT_EXPORT_CONST 1 1 0 0 0",
                                                            "TEXT_EXPORT_TD 0 0 0 0 1 0 0 0 0 0 0", *off])
    off = ["TEXT_EXPORT_TD_BOND 0 0 0 0 0 0 0", "TEXT_EXPORT_GEOMETRIES 0 0 0 0", "TEXT_EXPORT_GENERATORS 0 0"]
    return sim + _export(folder, "bonds.txt", ["TEXT_EXPORT_OBJECTS 0 1 0", "TEXT_EXPORT_CONST 1 1 0 0 1",
                                               "TEXT_EXPORT_TD_PART 0 0 0 0 0 0 0 0 0", "TIME_INTERVAL 0 0", *off]) \
        + _export(folder, "export.txt", [f"TEXT_EXPORT_OBJECTS {'0 0 1' if plate else '1 0 0'}",
                                         "TEXT_EXPORT_CONST 1 1 0 0 0", "TEXT_EXPORT_TD_PART 0 0 1 0 0 0 0 0 0",
                                         "TEXT_EXPORT_TD_WALL 1 1 0 0", *off])


def _export(folder: Path, name: str, keys: list[str]) -> str:
    """One EXPORT_TO_TEXT job of run.mdem: the objects, constant and time-dependent properties ``keys`` choose,
    nothing else (what is not named is off; today's keys and a legacy MUSEN's, :func:`script_text`)."""
    lines = ["JOB", "COMPONENT EXPORT_TO_TEXT", f"SOURCE_FILE {folder / 'run.mdem'}", f"RESULT_FILE {folder / name}",
             *keys, "TEXT_EXPORT_SCENE 0 0 0 0", "TEXT_EXPORT_MATERIALS 0 0 0", "TEXT_EXPORT_PRECISION 12"]
    return "\n".join(lines) + "\n"


#: values after each time-dependent identifier of MUSEN's text export (ETXTCommands)
TD_WIDTH = {12: 3, 15: 3, 16: 3, 18: 1, 20: 3, 31: 4, 36: 9, 37: 1, 42: 3, 43: 1, 45: 3}


def read_export(path: Path) -> tuple[dict, dict, dict]:
    """(per particle or wall id {time: force (3,)}, per bond id its activity end time, per wall id {time: height of
    its first vertex}) from MUSEN's text export (read a line at a time: a big scene's export is gigabytes)."""
    forces, ends, heights = {}, {}, {}
    for line in open(path):
        t = line.split()
        if not t or t[0] != "0":
            continue
        oid, kind = int(t[1]), int(t[3])
        k, here, z, now = 4, {}, {}, None
        while k < len(t):
            ident = int(t[k])
            if ident == 24:
                if kind == 9:
                    ends[oid] = float(t[k + 2])
                k += 3
            elif ident == 2:
                now = float(t[k + 1])
                k += 2
            elif ident == 20 and now is not None:
                here[now] = np.array([float(v) for v in t[k + 1:k + 4]])
                k += 4
            elif ident == 44 and now is not None:
                z[now] = float(t[k + 3])
                k += 10
            elif ident in TD_WIDTH:
                k += 1 + TD_WIDTH[ident]
            else:
                k += 1
        if kind in (1, 14):                  # spheres, triangular walls
            forces[oid] = here
        if z:
            heights[oid] = z
    return forces, ends, heights


def run_musen(cmusen: str, spec, sample, folder: Path, strain_max: float, speed_m_s: float, dt: float,
              points: int, threads: int, criterion: int = 1, plate: bool = False, legacy: bool = False) -> dict:
    """Write the scene and script, run CMUSEN, read back the stress-strain curve and the broken bonds."""
    folder.mkdir(parents=True, exist_ok=True)
    height = sample.height_nm * NM
    end = strain_max * height / speed_m_s
    (folder / "scene.txt").write_text(scene_text(spec, sample, speed_m_s, plate, legacy))
    # a legacy MUSEN's bond export grows with bonds x saved times: only up to LEGACY_BOND_EXPORT bonds
    bond_export = not legacy or sample.structure.n_bonds <= LEGACY_BOND_EXPORT
    (folder / "script.txt").write_text(script_text(folder, dt, end, end / points, criterion, plate, legacy,
                                                   bond_export))
    t0 = time.perf_counter()
    with open(folder / "cmusen.log", "w") as log:
        subprocess.run([cmusen, f"-s={folder / 'script.txt'}", f"-t={threads}"], stdout=log, stderr=subprocess.STDOUT,
                       check=True, cwd=folder)
    wall = time.perf_counter() - t0
    forces, _, heights = read_export(folder / "export.txt")
    _, ends, _ = read_export(folder / "bonds.txt") if bond_export else ({}, None, {})
    n = sample.structure.n_particles
    top = [k for k in forces if k >= n + sample.structure.n_bonds] if plate else np.flatnonzero(sample.top_layer)
    times = sorted(forces[int(top[0])])
    fz = np.array([sum(forces[int(i)][tt][2] for i in top) for tt in times])
    if plate:                              # the plate's own travel (MUSEN moves a wall twice in its first step)
        z = heights[int(top[0])]
        strain = (z[times[0]] - np.array([z[tt] for tt in times])) / height
    else:
        strain = np.array(times) * speed_m_s / height
    stress = fz / (sample.area_nm2 * NM * NM) / 1e6          # the layer (plate) is pushed up by the sample: F_z > 0
    broke = np.array([ends[k] for k in sorted(ends)]) if ends else np.zeros(0)
    broken = int(np.sum((broke > 0) & (broke < 1e299))) if ends is not None else None
    return {"strain": strain.tolist(), "stress_MPa": stress.tolist(), "wall_s": round(wall, 1),
            "broken_bonds": broken, "n_bonds": sample.structure.n_bonds, "n_particles": n, "time_step_s": dt,
            "speed_m_s": speed_m_s, "end_time_s": end, "height_m": height,
            "bond_end_s": sorted(float(t) for t in broke if 0 < t < 1e299)}


#: a curve's first peak: its running maximum where the stress first falls below this fraction of it, once the
#: stress has passed :data:`FIRST_FROM` of the run's maximum (before that an undamped start rings)
FIRST_DROP, FIRST_FROM = 0.9, 0.25


def first_peak(strain, stress) -> tuple[float, float]:
    """(stress, strain) of a curve's first peak: the running maximum at the first point whose stress is below
    :data:`FIRST_DROP` of it (the first load drop of 10 %: an undamped run rings by a few per cent), counted from
    where the stress first passes :data:`FIRST_FROM` of the run's maximum; the maximum where it never drops so far."""
    e, s = np.asarray(strain, float), np.asarray(stress, float)
    start = int(np.argmax(s >= FIRST_FROM * s.max()))
    top = np.maximum.accumulate(s[start:])
    drop = np.flatnonzero(s[start:] < FIRST_DROP * top)
    k = start + (int(np.argmax(s[start:start + drop[0]])) if len(drop) else int(np.argmax(s[start:])))
    return float(s[k]), float(e[k])


def figures(curve: dict, fit_max: float, plate: bool) -> dict:
    """E (a line through the origin fitted to the curve below ``fit_max`` strain), strength (the maximum over the
    run), strain at peak, the bonds broken before it, and with the ``plate`` the first peak (:func:`first_peak`;
    a glued start rings, so its first drop is no peak)."""
    e, s = np.array(curve["strain"]), np.array(curve["stress_MPa"])
    sel = (e > 0) & (e <= fit_max)
    E = float(np.sum(e[sel] * s[sel]) / np.sum(e[sel] ** 2)) / 1e3 if sel.any() else float("nan")
    p = int(np.argmax(s))
    ends = np.array(curve.get("bond_end_s", []))
    got = {"youngs_modulus_GPa": E, "strength_MPa": float(s[p]), "strain_at_peak": float(e[p]),
           "broken_bonds_at_peak": (int(np.sum(ends * curve["speed_m_s"] / curve["height_m"] < e[p]))
                                    if curve["broken_bonds"] is not None else None)}
    if plate:
        got["first_peak_MPa"], got["strain_at_first_peak"] = first_peak(e, s)
    return got


#: opalflow's runs of the same spec: label -> settings added
OPALFLOW = {"quasistatic": [],
            "quasistatic_frictionless": ['contacts.quasistatic="frictionless"'],
            "quasistatic_sticking": ['contacts.quasistatic="sticking"'],
            "dynamic_lammps_rule": ['compression.method="dynamic"', 'bonds.breaking="lammps"'],
            "quasistatic_lammps_rule": ['bonds.breaking="lammps"'],
            # the paper's loading on LAMMPS: the plate on the sample at rest, no damping (its rule, the only one)
            "dynamic_plate_lammps_rule": ['compression.method="dynamic"', 'bonds.breaking="lammps"',
                                          "compression.global_damping=0.0", "bonds.damping_ratio=0.0"]}
#: a plate row's strain (the plate's travel over the height): the plate seats on the rough top through Hertz contacts
#: far softer than the pore-free block (at 10 m/s its stress still rose at strain 0.08, no bond broken before 0.06)
PLATE_STRAIN = {"bulk60": 0.25, "bulk40": 0.25, "opal45": 0.06}
#: opalflow's runs of a plate row (``--loading plate``)
PLATE_RUNS = ["quasistatic", "quasistatic_lammps_rule", "dynamic_plate_lammps_rule"]


def run_opalflow(workflow: str, sets: list[str], folder: Path, strain_max: float, speed_m_s: float) -> dict:
    """opalflow's run of the same spec (a finished one in ``folder`` is read, not re-run)."""
    import opalflow

    from opalflow.lammps.engine import EngineError

    if (folder / "summary.json").exists():
        s = json.loads((folder / "summary.json").read_text())
    else:
        extra = [f"compression.strain_max={strain_max!r}", f"compression.plate_speed_m_s={speed_m_s!r}"]
        try:
            s = opalflow.run(workflow, folder, set=[*sets, *extra], quiet=True)
        except EngineError as exc:         # (the undamped plate run can lose a particle: a result, recorded)
            return {"failed": str(exc).splitlines()[0]}
    keys = ("youngs_modulus_GPa", "strength_MPa", "strain_at_peak", "broken_bonds", "broken_bonds_at_peak",
            "broken_bonds_by_check_at_peak", "wall_s")
    got = {k: s[k] for k in keys if k in s}
    if s.get("method", "dynamic") == "dynamic" and (folder / "results.h5").exists():
        import h5py

        with h5py.File(folder / "results.h5") as h:
            got["first_peak_MPa"], got["strain_at_first_peak"] = first_peak(h["curve/strain"][:],
                                                                            h["curve/stress_MPa"][:])
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cmusen", default=os.environ.get("MUSEN_CMUSEN"), help="the CMUSEN binary")
    ap.add_argument("--case", default="bulk60", choices=sorted(CASES))
    ap.add_argument("--out", type=Path, default=Path("/tmp/musen_peer"))
    ap.add_argument("--speed", type=float, default=1.0, help="plate speed, m/s")
    ap.add_argument("--dt-fraction", type=float, default=0.1, help="time step over sqrt(m / k_n) of one bond")
    ap.add_argument("--points", type=int, default=200)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--strain-max", type=float, default=None, help="a shorter run (not recorded in bench/results)")
    ap.add_argument("--again", action="store_true", help="run MUSEN again where a row is stored in --out")
    ap.add_argument("--musen-only", action="store_true", help="MUSEN alone, not opalflow's runs")
    ap.add_argument("--rule", default="musen", choices=sorted(CRITERION),
                    help="opalflow's breaking rule compared (MUSEN's CONSIDER_BREAKAGE from it; musen_2020 needs a "
                         "CMUSEN with 655e066's check)")
    ap.add_argument("--loading", default="glued", choices=["glued", "plate"], help="module docstring")
    ap.add_argument("--runs", nargs="*", choices=sorted(OPALFLOW), help="opalflow's runs (default: the case's)")
    ap.add_argument("--musen-commit", default=os.environ.get("MUSEN_COMMIT"),
                    help="the MUSEN source the binary was built from (recorded with every row)")
    args = ap.parse_args()
    if not args.cmusen:
        raise SystemExit("give --cmusen PATH (or MUSEN_CMUSEN): a CMUSEN binary built from a MUSEN checkout")
    if not args.musen_commit:
        raise SystemExit("give --musen-commit TEXT (or MUSEN_COMMIT): which MUSEN source built the binary")
    from opalflow.bpm.deck import particle_material
    from opalflow.materials import material

    workflow, sets, strain_max, runs = CASES[args.case]
    plate = args.loading == "plate"
    version = musen_version(args.cmusen)
    legacy = version < LEGACY
    if legacy and (args.rule != "musen_2020" or plate):
        raise SystemExit(f"CMUSEN {'.'.join(map(str, version))} (before 1.70.0) breaks bonds by 2020's check only "
                         "(--rule musen_2020) and exports no wall coordinates (--loading glued)")
    sets = [*sets, f'bonds.breaking="{args.rule}"', f'compression.loading="{args.loading}"']
    runs = args.runs or (PLATE_RUNS if plate else runs)
    strain_max = args.strain_max or (PLATE_STRAIN[args.case] if plate else strain_max)
    spec, sample = loaded(workflow, sets)
    data = sample.structure
    k_n = sample.coefficients[0].kr / float(np.mean(sample.bond_lengths))       # pN/nm = 1e-3 N/m
    rho = material(particle_material(data.type_names[0], spec.material), spec.materials)["density_kg_m3"]
    mass = float(np.mean(rho * np.pi / 6 * (data.diameters * NM) ** 3))
    dt = args.dt_fraction * float(np.sqrt(mass / (k_n * 1e-3)))
    key = (f"{args.case}_v{args.speed:g}" + ("" if args.rule == "musen" else f"_{args.rule}") + ("_plate" if plate else "")
           + (f"_musen{'.'.join(map(str, version))}" if legacy else ""))
    folder = args.out / key
    row_path = folder / "row.json"
    if row_path.exists() and not args.again:
        musen = json.loads(row_path.read_text())["musen"]
    else:
        musen = run_musen(args.cmusen, spec, sample, folder, strain_max, args.speed, dt, args.points, args.threads,
                          CRITERION[args.rule], plate, legacy)
        musen = {**figures(musen, 0.002, plate), **musen, "commit": args.musen_commit,
                 "version": ".".join(map(str, version)), "consider_breakage": CRITERION[args.rule]}
    row = {"case": args.case, "workflow": workflow, "set": sets, "rule": args.rule, "loading": args.loading,
           "strain_max": strain_max, "speed_m_s": args.speed,
           "n_particles": data.n_particles, "n_bonds": data.n_bonds,
           "height_nm": sample.height_nm, "area_nm2": sample.area_nm2, "musen": musen}
    row_path.write_text(json.dumps(row, indent=1))
    print(f"MUSEN ({args.musen_commit}): E {musen['youngs_modulus_GPa']:.4g} GPa, {musen['strength_MPa']:.4g} MPa at "
          f"strain {musen['strain_at_peak']:.4f}" + (f" (first peak {musen['first_peak_MPa']:.4g} MPa at "
          f"{musen['strain_at_first_peak']:.4f})" if plate else "") + f", {musen['broken_bonds_at_peak']} bonds "
          "broken before the peak, "
          f"{musen['broken_bonds']} in all ({musen['wall_s']} s)")
    for label in ([] if args.musen_only else runs):
        extra = OPALFLOW[label]
        got = run_opalflow(workflow, [*sets, *extra], folder / f"opalflow_{label}", strain_max, args.speed)
        row[f"opalflow_{label}"] = got
        if "failed" in got:
            print(f"opalflow {label}: {got['failed']}")
            continue
        dE = got["youngs_modulus_GPa"] / musen["youngs_modulus_GPa"] - 1
        print(f"opalflow {label}: E {got['youngs_modulus_GPa']:.4g} GPa ({dE:+.1%}), "
              f"{got['strength_MPa']:.4g} MPa ({got['strength_MPa'] / musen['strength_MPa'] - 1:+.1%}) at strain "
              f"{got['strain_at_peak']:.4f}" + (f", first peak {got['first_peak_MPa']:.4g} MPa at "
                                                  f"{got['strain_at_first_peak']:.4f}" if "first_peak_MPa" in got else ""))
    row["machine"] = f"{platform.node()}, {os.cpu_count()} cores; CMUSEN on {args.threads} threads"
    if args.strain_max is not None:          # (a shortened run is a try, not a result)
        return
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / "musen_peer.json"
    rows = json.loads(path.read_text()) if path.exists() else {}
    kept = {k: v for k, v in rows.get(key, {}).items() if k.startswith("opalflow_")}     # runs not repeated now
    rows[key] = {**kept, **row}
    rows[key]["musen"] = {k: v for k, v in musen.items() if k not in ("strain", "stress_MPa", "bond_end_s")}
    rows[key]["musen"]["curve"] = {"strain": [round(v, 6) for v in musen["strain"]],
                                   "stress_MPa": [round(v, 4) for v in musen["stress_MPa"]]}
    path.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
