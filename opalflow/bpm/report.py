"""report.md of a compression run: what went in, what came out against its reference and why, what it cost.

A reader should not need the code: the inputs (scene, materials, bond coefficients, contacts, loading, time
step), each result with its reference and error, a reason where the error is large and known (with the
figures of the convergence study, ``data/reference/resolution.toml``), the particle stresses in the
format of Dosta et al. Table 2, the files written and the run's cost.
"""
from __future__ import annotations

import json
import subprocess
import tomllib
from dataclasses import dataclass
from functools import lru_cache

from opalflow.analysis import compression as mech
from opalflow.bpm.facts import RunFacts, SampleFacts
from opalflow.bpm.loading import LOADINGS
from opalflow.resources import DATA, ROOT
from opalflow.runs.record import Session
from opalflow.runs.result import table_of
from opalflow.store import RECORD, RESULTS, SUMMARY


def reference_errors(summary: dict, references: dict) -> dict:
    """``summary["reference"]``: each reference value ({key: (value, source)}) with its source and the
    summary's relative error against it (keys the summary lacks are left out)."""
    return {k: {"value": v, "source": src, "error": (summary[k] - v) / v}
            for k, (v, src) in references.items() if summary.get(k) is not None}

def headline(result, references: dict, breakable: bool) -> str:
    """The one line ``run`` prints of a dynamic run's ``result``: the modulus the scene's reference is about (the
    top layer's where only that one has a reference: the lattice's analytic E excludes the plate's Hertz
    settling) and, with breakable bonds, the strength and its strain."""
    specimen = "youngs_modulus_specimen_GPa" in references and "youngs_modulus_GPa" not in references
    E = result.youngs_modulus_specimen_GPa if specimen else result.youngs_modulus_GPa
    line = f"E{' (top-layer strain)' if specimen else ''} = {E:.4g} GPa"
    if not breakable:
        return f"{line} (bonds unbreakable: no strength)"
    strain = result.strain_at_peak_specimen if specimen else result.strain_at_peak
    return f"{line}, strength = {result.strength_MPa:.4g} MPa (strain at peak {strain:.4f})"


#: an error beyond this (relative) gets its reason said where one is known
LARGE_ERROR = 0.10

SECTIONS = ("## Inputs", "## Results", "## Particle stresses", "## Files", "## Cost")


@dataclass(frozen=True)
class Resolution:
    """data/reference/resolution.toml: the paper's particle diameter (nm) and the convergence study's E and strength
    by particle diameter (the diameter in nm as text -> GPa or MPa)."""

    paper_diameter_nm: float
    static_youngs_modulus_GPa: dict[str, float]
    dynamic_youngs_modulus_GPa: dict[str, float]
    dynamic_strength_MPa: dict[str, float]


@lru_cache(maxsize=1)
def _resolution() -> Resolution:
    raw = tomllib.loads((DATA / "reference" / "resolution.toml").read_text())
    return Resolution(raw.pop("paper").pop("particle_diameter_nm"), **raw)


def _series(table: dict, unit: str) -> str:
    return ", ".join(f"{v:g} {unit} (d = {d} nm)" for d, v in sorted(table.items(), key=lambda kv: -float(kv[0])))


def why(key: str, error: float, diameter_nm: float) -> str:
    """One line on why a result misses its reference by ``error``, where the reason is known; "" if not."""
    if abs(error) <= LARGE_ERROR:
        return ""
    res = _resolution()
    paper_d = res.paper_diameter_nm
    if diameter_nm > 1.5 * paper_d and key in ("youngs_modulus_GPa", "youngs_modulus_specimen_GPa", "strength_MPa"):
        head = (f"resolution: d = {diameter_nm:.3g} nm is {diameter_nm / paper_d:.1f} x the paper's {paper_d:g} nm, "
                "so the struts between the pores are one or two particles thick and carry far less")
        if key == "strength_MPa":
            return (f"{head}; the convergence study's strength: {_series(res.dynamic_strength_MPa, 'MPa')} "
                    "(data/reference/resolution.toml)")
        return (f"{head}; E of the convergence study: {_series(res.dynamic_youngs_modulus_GPa, 'GPa')}; static "
                f"solve: {_series(res.static_youngs_modulus_GPa, 'GPa')}, the last the paper's sample "
                "(data/reference/resolution.toml)")
    if key == "youngs_modulus_GPa":
        return ("the plate-strain modulus holds the Hertz settling of the plate on the rough top and the loading "
                "rate (docs/validation/static.md)")
    return ""


def stress_area(sample: SampleFacts) -> str:
    """The area the stress is taken on, and which: the box across periodic sides, the footprint across open."""
    return (f"{sample.area_nm2:.4g} nm^2 ("
            f"{'the box' if sample.periodic[0] else 'the particles footprint: open sides'})")


def sample_lines(sample: SampleFacts) -> list[str]:
    """What the static and quasi-static reports say of the sample: the data file read (where one was) and the
    area the stress is taken on."""
    lines = [f"Data file: {sample.source}.", ""] if sample.source else []
    return lines + [f"Stress on {stress_area(sample)}.", ""]


def _scene_rows(run: RunFacts, box) -> list[tuple[str, str]]:
    """The Inputs table's first rows, every method's: the scene and the sample's size and stressed area."""
    spec, sample = run.spec, run.sample
    return [("scene", f"{spec.kind}: {spec.description or spec.name}"),
            ("sample", f"{box[0]:.0f} x {box[1]:.0f} nm (x, y; sides {sample.sides}), {sample.height_nm:.0f} nm high "
                       f"above the fixed substrate; stress on {stress_area(sample)}")]


def _inputs(run: RunFacts, result) -> list[str]:
    spec, sample = run.spec, run.sample
    c, b = spec.compression, spec.bonds
    box = sample.box_nm
    structure = sample.structure or {}
    n, bonds = sample.n_particles, sample.n_bonds
    rows = [*_scene_rows(run, box),
            ("particles", f"{n}, mean diameter d = {sample.mean_diameter_nm:.3g} nm"),
            ("bonds", f"{bonds} ({bonds / max(1, n):.1f} per particle, the paper's measure; coordination "
                      f"{2 * bonds / max(1, n):.1f}), "
                      + ("from the data file, " if sample.source else f"cutoff {b.cutoff_factor:g} d, ")
                      + f"model {b.model}, {'breakable' if b.breakable else 'unbreakable'}"),
            *fraction_rows(sample)]
    if sample.source:
        rows.insert(1, ("data file", sample.source))
    if "porosity" in structure:
        rows.append(("porosity", f"{structure['porosity']:.4f} (macro-pores; with the packing's voids "
                                 f"{structure['total_porosity']:.4f})"))
    if "density_kg_m3" in structure:
        rows.append(("density", f"{structure['density_kg_m3']:.0f} kg/m^3"))
    for name, m in sample.materials.items():
        rows.append((f"material {name}", f"bond E_b {m.bond_youngs_modulus_GPa:g} GPa, nu "
                     f"{m.bond_poisson_ratio:g}, strength {m.bond_strength_MPa:g} MPa, density "
                     f"{m.density_kg_m3:g} kg/m^3 ({m.source})"))
    types = sample.bond_types
    if types and types[0].kr_pN is not None:
        rows.append(("bond coefficients", f"{len(types)} types (material x length bin, bpm/rotational normalize yes): "
                     f"L0 {min(t.length_nm for t in types):.3g}-{max(t.length_nm for t in types):.3g} nm, "
                     f"kr {min(t.kr_pN for t in types):.4g}-{max(t.kr_pN for t in types):.4g} pN, "
                     f"kb {min(t.kb_pN_nm for t in types):.4g}-{max(t.kb_pN_nm for t in types):.4g} pN nm, "
                     f"critical normal force {min(t.fr_c_pN for t in types):.4g}-"
                     f"{max(t.fr_c_pN for t in types):.4g} pN (all in {RECORD})"))
    contacts = spec.contacts
    rows.append(("contacts", f"{'Hertz-Mindlin (hertz/material, mindlin)' if contacts.model == 'hertz' else 'linear'}"
                 f" between unbonded particles" if contacts.enabled else "none (bonds only)"))
    rows.append(("loading", f"{c.loading} at {sample.plate_speed_m_s:g} m/s to strain {c.strain_max:g}; "
                 f"snapshots at {', '.join(f'{e:g}' for e in c.snapshot_strains) or 'none'}"))
    ran = (f"{sample.steps} steps, the curve's last row at step {result.steps}" if result.complete else
           f"stopped at step {result.steps} of {sample.steps}")
    estimate = sample.timestep_estimate_s
    rows.append(("time step", f"{sample.timestep_s:.3g} s ({ran}; stability limit {estimate['limit']:.3g} s, "
                 f"stiffest: {estimate['stiffest_mode']}); global damping {c.global_damping:g}"))
    return ["## Inputs", "", "| input | value |", "|---|---|", *[f"| {k} | {v} |" for k, v in rows], ""]


def fraction_rows(sample: SampleFacts) -> list[tuple[str, str]]:
    """The packing fraction (the spheres' packing before pores, what the deck's ``solid_fraction`` holds) and,
    where pores were cut, the sample's own solid fraction (1 - total porosity): two numbers, each named."""
    rows = [("packing fraction", f"{sample.solid_fraction:.4f} (the spheres' packing before pores)")]
    structure = sample.structure or {}
    if "total_porosity" in structure:
        rows.append(("solid fraction", f"{1 - structure['total_porosity']:.4f} of the sample volume (after pores)"))
    return rows


def _session_row(k: int, x: Session) -> str:
    last = "?" if x.last_step is None else x.last_step
    wall = "-" if x.wall_s is None else f"{x.wall_s:.1f}"
    return (f"| {k} | {x.started} | {x.launcher} | {x.restart or 'start'} | {x.first_step}-{last} | "
            f"{wall} | {x.ended or 'running'} |")


def compression_report(run: RunFacts, summary: dict, result, fit, fracture: bool, plots: bool = True) -> str:
    """The text of report.md (sections :data:`SECTIONS`) of a dynamic run: ``result`` its
    :class:`opalflow.bpm.result.CompressionResult`, ``summary`` as written (its wall time, set as the files are
    written); ``plots``: the figures were drawn (``compression.plots``)."""
    spec, sample = run.spec, run.sample
    lines = [f"# {run.workflow}: {LOADINGS[result.loading].title}", ""]
    if not result.complete:
        c = spec.compression
        lines += [f"**Incomplete run**: the output stops at step {result.steps} of {sample.steps} "
                  f"(strain {result.steps / sample.steps * c.strain_max:.4f} of {c.strain_max:g}); the "
                  "figures below cover only that part. `python -m opalflow run --out DIR --resume` continues it "
                  "from its newest restart file.", ""]
    lines += _inputs(run, result)
    lines += ["## Results", "", *result.results_table(sample.mean_diameter_nm)]
    lines += ["", f"Elastic window: strain {fit.window[0]:.4f} - {fit.window[1]:.4f}, R^2 = {fit.r2:.5f} "
              f"({fit.points} points). Bond stiffness error from {spec.bonds.length_bins} length bins: max "
              f"{100 * result.bond_stiffness_error_max:.2f} %."]
    if result.rate_check is not None:
        rc = result.rate_check
        strength = "" if rc.strength_change is None else f", strength by {100 * rc.strength_change:+.2f} %"
        lines += ["", f"Rate check (half plate speed): E changes by {100 * rc.youngs_modulus_change:+.2f} %"
                  f"{strength} (limits 2 % and 5 %)."]
    lines += ["", *figure(plots, "stress-strain", "stress_strain.png")]
    if not plots:
        lines += [plots_line(False, "stress_strain.png, stress_hist.png, bond_strain.png, fracture.png",
                             spec.compression.plots), ""]
    lines += ["## Particle stresses", ""]
    table = mech.stress_table(result.stress_by_material)
    lines += (table + [""] + (["Histograms at every snapshot (rows), mean +- std per material in the legends:", "",
                               *figure(True, "particle stresses", "stress_hist.png"),
                               "Bond strains (Fig. 7 format; bins from the data):", "",
                               *figure(True, "bond strains", "bond_strain.png")] if plots else [])
              ) if table else ["No snapshots were asked for.", ""]
    if fracture and plots:
        lines += ["Fracture: a slab a third of the box thick (normal y) through where the bonds broke, particles "
                  "coloured by their broken bonds (top) and sigma_zz (bottom), near the peak and after it:", "",
                  *figure(True, "fracture", "fracture.png")]
    lines += ["## Files", "",
              f"- `{SUMMARY}`: the numbers above (keys with units); `{RESULTS}`: curves, snapshots and histograms, "
              "every dataset with `units` (tables with `columns`); `opalflow.load_results(folder)` reads both.",
              "- `data.lmp` (bonds, image flags), `in.lmp`, `resume.lmp`, `run.sh`: the deck, runnable without opalflow.",
              "- `snapshots/particles.STEP.dump`: LAMMPS dumps (id, type, x y z, image flags, radius, sigma_xx ... "
              "sigma_yz in MPa, broken_bonds) that OVITO opens as they are; `snapshots/bonds.STEP.txt`: bond lengths.",
              ""]
    sessions = result.sessions or []
    if summary.get("wall_s") is None:
        cost = "run outside opalflow (analyze only)"
    else:
        first = sessions[-1].first_step if sessions else 0
        cost = (f"this session: wall {summary['wall_s']:.1f} s, of which LAMMPS {result.lammps_s:.1f} s, steps "
                f"{first}-{result.steps} ({result.steps - first} steps)")
    lines += ["## Cost", "", f"{cost}; {result.steps} steps in all of {sample.timestep_s:.3g} s for "
              f"{sample.n_particles} particles and {sample.n_bonds} bonds; structure built in "
              f"{sample.build_s:.1f} s.", ""]
    if len(sessions) > 1 or result.requeues:
        lines += [f"Sessions ({len(sessions)}; SLURM requeues: {result.requeues or 0}):", "",
                  "| # | started | launcher | continued from | steps | wall (s) | ended |", "|---|---|---|---|---|---|---|"]
        lines += [_session_row(k, x) for k, x in enumerate(sessions, 1)]
        lines.append("")
    return "\n".join(lines)


def git_commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                              text=True, timeout=5).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance_group(h, run: RunFacts) -> None:
    """results.h5's ``provenance`` group, every method's: the spec, LAMMPS's version, opalflow's commit, the
    seeds and the run's facts (:class:`opalflow.bpm.facts.RunFacts`: the spec apart; the workflow, the references
    and the sample's facts as JSON)."""
    from opalflow.lammps.engine import lammps_version

    spec = run.spec.to_dict()
    facts = {"workflow": run.workflow, "references": run.references, **table_of(run.sample)}
    p = h.create_group("provenance")
    p.attrs["spec"] = json.dumps(spec)
    p.attrs["lammps_version"] = lammps_version()
    p.attrs["git_commit"] = git_commit()
    p.attrs["seeds"] = json.dumps({name: section["seed"] for name, section in spec.items()
                                   if isinstance(section, dict) and "seed" in section})
    p.attrs["run"] = json.dumps(facts, default=float)


def plots_line(drawn: bool, names: str, setting: str) -> str:
    """The report's line naming its plots, or saying why there are none (``compression.plots``)."""
    if drawn:
        return f"Plots: {names}."
    return f"Plots: none drawn (compression.plots = \"{setting}\"; \"all\" draws {names})."


def figure(drawn: bool, alt: str, name: str) -> list[str]:
    """A figure of report.md: its image line, or nothing where the plots were not drawn."""
    return [f"![{alt}]({name})", ""] if drawn else []


def structure_cost(sample: SampleFacts) -> str:
    """How the structure came: built, or read from the cache (and what its first build cost)."""
    if sample.structure_cache:
        return (f"structure read from the cache in {sample.build_s:.1f} s (first built in "
                f"{sample.structure_first_build_s:.1f} s)")
    return f"structure built in {sample.build_s:.1f} s"


def network_inputs(run: RunFacts, loaded) -> list[str]:
    """The Inputs table of the static and quasi-static reports: scene, sample, particles, bonds, materials,
    contacts, loading, breaking rule and re-solves (from the run's spec and facts and the loaded sample,
    :class:`opalflow.bpm.deck.LoadedSample`)."""
    from opalflow.bpm.spec import BREAKING_RULES
    from opalflow.materials import material

    spec, sample = run.spec, run.sample
    c, b = spec.compression, spec.bonds
    data = loaded.structure
    box = data.box_lengths
    d = float(data.diameters.mean())
    structure = sample.structure or {}
    n, bonds = sample.n_particles, sample.n_bonds
    rows = [*_scene_rows(run, box),
            ("particles", f"{n}, mean diameter d = {d:.3g} nm; top layer {sample.top_layer_particles}"),
            ("bonds", f"{bonds} ({bonds / max(1, n):.1f} per particle), "
                      + ("from the data file, " if sample.source else f"cutoff {b.cutoff_factor:g} d, ")
                      + f"model {b.model}, {len(loaded.bins.lengths)} length bins"),
            *fraction_rows(sample)]
    if sample.source:
        rows.insert(1, ("data file", sample.source))
    if "porosity" in structure:
        rows.append(("porosity", f"{structure['porosity']:.4f} (macro-pores)"))
    for name in sorted(set(loaded.bins.materials)):
        m = material(name, spec.materials)
        rows.append((f"material {name}", f"bond E_b {m.bond_youngs_modulus_GPa:g} GPa, nu "
                     f"{m.bond_poisson_ratio:g}, strength {m.bond_strength_MPa:g} MPa ({m.source})"))
    rows.append(("loading", f"{c.loading}, to strain {c.strain_max:g} ({c.method})"))
    if c.method == "quasistatic":
        rows.append(("breaking rule", f"`{b.breaking}`: {BREAKING_RULES[b.breaking]}"))
        rows.append(("contacts", f"`contacts.quasistatic = \"{spec.contacts.quasistatic}\"`"))
        rows.append(("re-solves", f"`compression.resolver = \"{c.resolver}\"`, event tolerance "
                     f"{c.event_tolerance:g}, local_rtol {c.local_rtol:g}"))
    else:
        rows.append(("solver", f"`compression.solver = \"{c.solver}\"`"))
    cell = [(k, v.replace("|", "\\|")) for k, v in rows]           # (|F_s| in a table cell)
    return ["## Inputs", "", "| input | value |", "|---|---|", *[f"| {k} | {v} |" for k, v in cell], ""]
