"""Fracture pictures: a slice through a bonded-particle sample, particles coloured by broken bonds or stress.

Dosta et al. (section 3.1.3, the fracture patterns with periodic and with open side boundaries) show where
bonds break in a compressed opal.  Here a :class:`Snapshot` (as the dynamic and quasi-static runs make it and
``results.h5/snapshots/STEP`` holds it: strain, positions, radii, broken bonds, stresses) is cut to a slab normal
to y and
drawn in x-z with each particle at its true size.  The slab is a third of the box thick (at least one
diameter) and centred where the bonds broke, so that the crack shows even in a coarse, very porous sample.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.store import RESULTS, new_figure, save_figure


@dataclass
class Snapshot:
    """The particles of a compression run at one strain: centres (nm, (N, 3)), radii (nm), the bonds of each that
    broke so far, the Cauchy stress of eq. 21 (MPa, (N, 6) in Voigt order, tension positive); a run's own snapshot
    also its ids, types and the stress's mean by material."""

    strain: float
    position_nm: np.ndarray
    radius_nm: np.ndarray
    broken_bonds: np.ndarray
    sigma_MPa: np.ndarray
    id: np.ndarray | None = None
    type: np.ndarray | None = None
    by_material: dict | None = None


Frame = tuple[str, Snapshot]                       # a labelled snapshot


def frames_at_peak_and_after(snapshots: list[Snapshot], strain_at_peak: float) -> list[Frame]:
    """The snapshot nearest the peak stress and the last one after it, labelled; [] when no bond broke."""
    if not snapshots or not any(int(s.broken_bonds.max(initial=0)) > 0 for s in snapshots):
        return []
    near = min(snapshots, key=lambda s: abs(s.strain - strain_at_peak))
    frames = [(f"near the peak (strain {100 * near.strain:.2f} %)", near)]
    last = max(snapshots, key=lambda s: s.strain)
    if last is not near and last.strain > strain_at_peak:
        frames.append((f"after the peak (strain {100 * last.strain:.2f} %)", last))
    return frames


def slab_centre(frames: list[Frame], box_nm) -> float:
    """y of the slab to draw: the (periodic) mean y of the particles with broken bonds in the last frame,
    the middle of the box if none."""
    snap = frames[-1][1]
    w = snap.broken_bonds.astype(float)
    if not w.sum():
        return 0.5 * box_nm[1]
    angle = 2 * np.pi * snap.position_nm[:, 1] / box_nm[1]
    mean = np.arctan2(np.sum(w * np.sin(angle)), np.sum(w * np.cos(angle)))
    return float((mean / (2 * np.pi)) % 1.0 * box_nm[1])


def _slab(snap: Snapshot, box_nm, diameter_nm: float, centre: float) -> np.ndarray:
    """Particles whose centre lies within max(d, L_y / 3) / 2 of the plane y = ``centre`` (periodic in y)."""
    dy = snap.position_nm[:, 1] - centre
    dy -= box_nm[1] * np.round(dy / box_nm[1])
    return np.abs(dy) <= 0.5 * max(diameter_nm, box_nm[1] / 3)


def _draw(ax, snap: Snapshot, box_nm, diameter_nm: float, colour: str, vmax: float, centre: float):
    from matplotlib.collections import EllipseCollection

    sel = np.flatnonzero(_slab(snap, box_nm, diameter_nm, centre))
    if colour == "broken_bonds":
        values, cmap, vmin = snap.broken_bonds[sel].astype(float), "inferno_r", 0.0
        order = np.argsort(values, kind="stable")          # broken ones drawn last, on top
    else:
        values, cmap, vmin = snap.sigma_MPa[sel, 2], "coolwarm", -vmax
        order = np.argsort(np.abs(values), kind="stable")
    sel, values = sel[order], values[order]
    xz = snap.position_nm[sel][:, [0, 2]] / 1e3
    size = 2 * snap.radius_nm[sel] / 1e3
    circles = EllipseCollection(size, size, np.zeros(len(size)), units="xy", offsets=xz,
                                offset_transform=ax.transData, cmap=cmap, edgecolors="none")
    circles.set_array(values)
    circles.set_clim(vmin, vmax)
    ax.add_collection(circles)
    ax.set_xlim(0, box_nm[0] / 1e3)
    ax.set_ylim(float(xz[:, 1].min(initial=0)) - 0.05, float(xz[:, 1].max(initial=1)) + 0.05)
    ax.set_aspect("equal")
    ax.set_xlabel("x (um)")
    ax.set_ylabel("z (um)")
    return circles


def _limits(frames: list[Frame]) -> tuple[float, float]:
    broken = max(float(s.broken_bonds.max(initial=0)) for _, s in frames)
    stress = max(float(np.percentile(np.abs(s.sigma_MPa[:, 2]), 99)) for _, s in frames)
    return max(broken, 1.0), max(stress, 1e-9)


def plot_fracture(path: Path, frames: list[Frame], box_nm, diameter_nm: float, title: str = "") -> None:
    """One run: columns = ``frames`` (label, snapshot); top row broken bonds per particle, bottom row
    sigma_zz (compression negative), on the slab through the middle of the box."""
    broken_max, stress_max = _limits(frames)
    centre = slab_centre(frames, box_nm)
    fig, axes = new_figure(2, len(frames), figsize=(3.4 * len(frames) + 1.2, 7.4), squeeze=False,
                           layout="constrained")
    for col, (label, snap) in enumerate(frames):
        a = _draw(axes[0, col], snap, box_nm, diameter_nm, "broken_bonds", broken_max, centre)
        b = _draw(axes[1, col], snap, box_nm, diameter_nm, "sigma_zz", stress_max, centre)
        axes[0, col].set_title(label, fontsize=9)
    fig.colorbar(a, ax=axes[0, :].tolist(), label="broken bonds per particle")
    fig.colorbar(b, ax=axes[1, :].tolist(), label="sigma_zz (MPa)")
    fig.suptitle(f"{title}: slab y = {centre:.0f} +- {0.5 * max(diameter_nm, box_nm[1] / 3):.0f} nm", fontsize=10)
    save_figure(fig, path, tight=False)


def plot_sides(path: Path, runs: dict[str, tuple[list[Frame], list, float]]) -> None:
    """Several runs side by side (the paper's periodic vs open side boundaries): one row per run
    (label -> (frames, box_nm, diameter_nm)), particles coloured by broken bonds on one scale."""
    every = [f for frames, _, _ in runs.values() for f in frames]
    broken_max, _ = _limits(every)
    cols = max(len(frames) for frames, _, _ in runs.values())
    fig, axes = new_figure(len(runs), cols, figsize=(3.4 * cols + 1.2, 3.9 * len(runs)), squeeze=False,
                           layout="constrained")
    artist = None
    for row, (name, (frames, box, d)) in enumerate(runs.items()):
        centre = slab_centre(frames, box)
        for col in range(cols):
            ax = axes[row, col]
            if col >= len(frames):
                ax.set_axis_off()
                continue
            label, snap = frames[col]
            artist = _draw(ax, snap, box, d, "broken_bonds", broken_max, centre)
            ax.set_title(f"{name}: {label}", fontsize=9)
    if artist is not None:
        fig.colorbar(artist, ax=axes.ravel().tolist(), label="broken bonds per particle")
    save_figure(fig, path, tight=False)


def load_frames(folder: Path, strain_at_peak: float) -> list[Frame]:
    """The fracture frames of a finished compression run folder (its results.h5's snapshots) about the strain of
    its peak stress."""
    import h5py

    snapshots = []
    with h5py.File(Path(folder) / RESULTS, "r") as h:
        for step in sorted(h.get("snapshots", {}), key=int):
            g = h[f"snapshots/{step}"]
            snapshots.append(Snapshot(float(g.attrs["strain"]), *(g[k][()] for k in (
                "position_nm", "radius_nm", "broken_bonds", "sigma_MPa"))))
    return frames_at_peak_and_after(snapshots, strain_at_peak)
