"""Kind ``aggregation``: one aggregate, its fractal dimension two ways, pictures, its bonded data file.

Writes ``aggregate.lmp`` (atom_style bpm/sphere, periodic in x, y and z, bonds at contacts: LAMMPS reads
it as it is), ``results.h5`` (spheres, the contacts the aggregation made, every merger's N and R_g, the
mass-radius curve), ``fractal.png``, ``network.png``, ``report.md`` and ``summary.json`` (last: a folder
with a summary.json is finished), all or none.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from opalflow.aerogel.aggregation import Aggregate
from opalflow.aerogel.fractal import FractalFit, estimates, plot_fractal
from opalflow.aerogel.loops import loop_statistics
from opalflow.aerogel.scene import coordination, make_aggregate, periodic_structure
from opalflow.aerogel.spec import AggregationWorkflow
from opalflow.lammps.datafile import write_data
from opalflow.runs.record import finish
from opalflow.runs.result import Result
from opalflow.store import RESULTS, h5_bytes, new_figure, put, save_figure
from opalflow.version import __version__

#: literature values of D_f (BRIEF section 2, with sources)
LITERATURE = {"dlca": ("1.75-1.85 at low concentration, rising with it", "Hasmy et al., Phys. Rev. B 50, 6006 "
                       "(1994); Rottereau et al., Eur. Phys. J. E 15, 133 (2004)"),
              "rlca": ("2.0-2.1", "Lin et al., Nature 339, 360 (1989)")}


def plot_network(agg: Aggregate, z: np.ndarray, path) -> None:
    """The network: 3D view of an eighth of the cube coloured by arrival (the rank of the merger at which
    the sphere's cluster joined another), and a slab a fifth of the box thick seen along z, coloured by
    coordination; marker areas follow the diameters."""
    import matplotlib
    from scipy.stats import rankdata

    fig = new_figure(figsize=(11, 5))[0]
    fig.clf()
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    x = agg.positions
    rank = rankdata(agg.arrival) / len(x)
    corner = np.all(x < agg.box / 2, axis=1)
    size = (agg.diameters / agg.box * 330) ** 2
    sc = ax.scatter(x[corner, 0], x[corner, 1], x[corner, 2], c=rank[corner], s=size[corner] * 4, cmap="viridis",
                    depthshade=True, linewidths=0)
    ax.set_box_aspect((1, 1, 1))
    ax.set_title(f"an eighth of the cube ({int(corner.sum())} spheres)")
    fig.colorbar(sc, ax=ax, shrink=0.6, label="arrival (rank of its last merger)")
    b = fig.add_subplot(1, 2, 2)
    sel = x[:, 2] < agg.box / 5
    cmap = matplotlib.colormaps["plasma"].resampled(5)
    sc = b.scatter(x[sel, 0], x[sel, 1], c=np.minimum(z[sel], 4), s=size[sel] * 1.6, cmap=cmap, vmin=-0.5,
                   vmax=4.5, linewidths=0)
    b.set_aspect("equal")
    b.set_xlim(0, agg.box)
    b.set_ylim(0, agg.box)
    b.set_xlabel("x (nm)")
    b.set_ylabel("y (nm)")
    b.set_title(f"slab z < L/5 (colour: coordination; {int(sel.sum())} spheres)")
    fig.colorbar(sc, ax=b, ticks=range(5), shrink=0.8, label="bonds (4 = 4 or more)")
    save_figure(fig, path)


def _fit_line(f: FractalFit) -> str:
    unit = {"mass-radius": " nm", "g(r)": " nm", "S(q)": " 1/nm"}.get(f.method, "")
    if not math.isfinite(f.D):
        return f"| {f.method} | - | - | {f.range[0]:.4g}-{f.range[1]:.4g}{unit} | {f.points} | {f.note} |"
    return (f"| {f.method} | {f.D:.3f} | [{f.ci95[0]:.3f}, {f.ci95[1]:.3f}] | {f.range[0]:.4g}-{f.range[1]:.4g}{unit} "
            f"| {f.points} | {f.note} |")


def run_aggregation(spec: AggregationWorkflow, out: Path, say=print) -> Result:
    start = time.perf_counter()
    a = spec.aggregate
    say(f"{spec.name}: {a.algorithm.upper()} of {a.particles} spheres (d = {a.diameter_nm:g} +- {a.diameter_std_nm:g} "
        f"nm) at solid fraction {a.solid_fraction:g}, {a.stepping} stepping, loops: {a.loops}")
    agg, cutoff, done = make_aggregate(a, spec.bonds.cutoff_factor, progress=say)
    say(f"aggregated in {agg.wall_s:.1f} s: {agg.moves} moves, {agg.jumps} jumps, {agg.collisions} contacts, "
        f"{len(agg.contacts)} mergers")
    s = periodic_structure(agg, cutoff, spec.material)
    z = coordination(s.n_particles, s.bonds)
    loops = loop_statistics(s.n_particles, s.bonds)
    fits = estimates(agg, a.seed)
    lit, source = LITERATURE[a.algorithm]
    summary = {
        "workflow": spec.name, "opalflow_version": __version__, "algorithm": a.algorithm,
        "n_particles": s.n_particles, "n_bonds": s.n_bonds, "box_nm": agg.box, "solid_fraction": agg.solid_fraction,
        "placement": agg.placement, "stepping": agg.stepping, "moves": agg.moves, "jumps": agg.jumps,
        "collisions": agg.collisions, "mergers": len(agg.contacts),
        "clusters_left": agg.clusters_left, "aggregation_s": agg.wall_s, "moves_per_s": agg.moves / max(agg.wall_s, 1e-9),
        "loop_model": done, "bond_cutoff": cutoff, **dataclasses.asdict(loops),
        "crossover_mass": fits.rg[1].crossover_mass, "correlation_length_nm": fits.gr[1].xi_nm,
        "fractal_mass_radius": fits.mass_radius[0], "fractal_rg": fits.rg[0], "fractal_gr": fits.gr[0],
        "fractal_sq": fits.sq[0],
        "literature_D": {"value": lit, "source": source},
    }
    d_text = "; ".join(f"{f.D:.2f} [{f.ci95[0]:.2f}, {f.ci95[1]:.2f}] ({f.method})" for f in fits.fits()
                       if math.isfinite(f.D)) or "no fit"
    summary["headline"] = (f"D_f = {d_text}; literature {lit}; {s.n_particles} spheres, {s.n_bonds} bonds "
                           f"({loops.loops_per_10k:.0f} loops per 10 000), {agg.wall_s:.1f} s")
    rotation = ("Clusters translate only (no rotational diffusion, which lowers D_f: Jungblut et al., Phys. Rev. E "
                "2019).")
    report = [f"# {spec.name}: {a.algorithm.upper()} aggregate", "",
              f"{s.n_particles} spheres, d = {a.diameter_nm:g} +- {a.diameter_std_nm:g} nm (Gaussian), solid fraction "
              f"{agg.solid_fraction:.4f} in a periodic cube of {agg.box:.4g} nm; {agg.placement}; {agg.stepping} "
              f"stepping: {agg.moves} moves, {agg.jumps} free-distance jumps, {agg.collisions} contacts, "
              f"{len(agg.contacts)} mergers in {agg.wall_s:.1f} s. {rotation}", "",
              f"Network (loop model `{a.loops}`; bonds within {cutoff:g} x (r_i + r_j)): {s.n_bonds} bonds, mean "
              f"coordination {z.mean():.3f}, {loops.dangling_fraction:.1%} dangling spheres, {loops.loops} "
              f"independent loops ({loops.loops_per_10k:.0f} per 10 000 spheres)"
              + (f"; {done['deflected']} of {done['dangling_before']} dangling spheres deflected" if "deflected" in done
                 else "") + ".", "",
              "| method | D_f | 95 % interval | fitted range | points | note |", "|---|---|---|---|---|---|",
              *(_fit_line(f) for f in fits.fits()), "",
              f"Literature ({a.algorithm.upper()}): {lit} ({source}); dilute DLCA by R_g(N): 1.78 +- 0.05 (Jullien, "
              "Kolb and Botet 1984). R_g(N) measures the dilute clusters (up to a third of the crossover mass, "
              "where a cluster's own solid fraction falls to the box's); g(r) and S(q) the gel up to half its "
              "correlation length. The intervals are regression intervals of correlated points (lower bounds); "
              "seeds give the spread.", "",
              "![fractal dimension](fractal.png)", "", "![network](network.png)", "",
              "`aggregate.lmp`: the bonded network as an atom_style bpm/sphere data file (periodic in x, y, z)."]
    mr, gr, sq = fits.mass_radius[1], fits.gr[1], fits.sq[1]

    def fill(h):
        for key, value, unit, cols in (
                ("positions_nm", agg.positions, "nm", ["x", "y", "z"]), ("diameters_nm", agg.diameters, "nm", None),
                ("arrival", agg.arrival, "1", None), ("contacts", agg.contacts, "1", ["i", "j"]),
                ("bonds", s.bonds, "1", ["i", "j"]), ("merger_size", agg.merger_size, "1", None),
                ("merger_rg_nm", agg.merger_rg, "nm", None), ("mass_radius/r_nm", mr.r_nm, "nm", None),
                ("mass_radius/count", mr.count, "1", None), ("mass_radius/background", mr.background, "1", None),
                ("pair_correlation/r_nm", gr.r_nm, "nm", None), ("pair_correlation/g", gr.g, "1", None),
                ("structure_factor/q_per_nm", sq.q_per_nm, "1/nm", None), ("structure_factor/S", sq.S, "1", None)):
            put(h, key, value, unit, cols)
    results = h5_bytes(fill, workflow=spec.name)
    out.mkdir(parents=True, exist_ok=True)
    summary["wall_s"] = time.perf_counter() - start

    def files(stage):
        write_data(stage("aggregate.lmp"), s, title=f"opalflow {__version__} {spec.name}")
        stage(RESULTS).write_bytes(results)
        plot_fractal(fits, stage("fractal.png"))
        plot_network(agg, z, stage("network.png"))

    return finish(out, summary, "\n".join(report) + "\n", files=files)
