"""Compression output -> stress-strain curve, Young's modulus, strength, particle stresses.

Readers for the files the deck writes (``curve.txt`` from fix ave/time, the
``snapshots/particles.*.dump`` custom dumps and ``snapshots/bonds.*.txt`` local dumps)
and the mechanics computed from them.
"""
from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.store import write_text_atomic

#: order of the six stress components (LAMMPS compute stress/atom)
STRESS_COLUMNS = ["xx", "yy", "zz", "xy", "xz", "yz"]
#: units of the curve.txt columns (results.h5 writes them beside each dataset)
CURVE_UNITS = {"step": "1", "plate_dz_nm": "nm", "plate_fz_pN": "pN", "substrate_fz_pN": "pN", "intact_bonds": "1",
               "ke_zJ": "zJ", "top_z_nm": "nm"}
CURVE_COLUMNS = ["step", "plate_dz_nm", "plate_fz_pN", "substrate_fz_pN", "intact_bonds", "ke_zJ", "top_z_nm"]


@dataclass
class Curve:
    """curve.txt's columns (units in :data:`CURVE_UNITS`), one row per output interval (averages over it)."""

    step: np.ndarray
    plate_dz_nm: np.ndarray
    plate_fz_pN: np.ndarray
    substrate_fz_pN: np.ndarray
    intact_bonds: np.ndarray
    ke_zJ: np.ndarray
    top_z_nm: np.ndarray

    def columns(self) -> list[tuple[str, np.ndarray]]:
        """(name, column) in the file's order."""
        return [(name, getattr(self, name)) for name in CURVE_COLUMNS]


def read_curve(path: Path) -> Curve:
    """curve.txt as columns; rows repeated by a resumed run keep their last value."""
    with warnings.catch_warnings():           # (an empty file: said once, below, not also as numpy's warning)
        warnings.simplefilter("ignore", UserWarning)
        rows = np.loadtxt(path, comments="#", ndmin=2)
    if rows.size == 0:
        raise ValueError(f"{path} holds no data rows")
    steps = rows[:, 0]
    # the last occurrence of each step wins (a resumed run appends rows it re-computed)
    _, last = np.unique(steps[::-1], return_index=True)
    rows = rows[::-1][last]
    return Curve(*(rows[:, k] for k in range(len(CURVE_COLUMNS))))


def trim_curve(path: Path, last_step: int) -> None:
    """Keep the header and the rows up to ``last_step`` (the step of the restart file a run resumes
    from): the resumed run appends the rest, so each step is in the file once, in order."""
    if not path.exists():
        return
    lines = path.read_text().splitlines(keepends=True)
    keep = [line for line in lines if line.startswith("#") or not line.strip()
            or int(line.split()[0]) <= last_step]
    write_text_atomic(path, "".join(keep))


def tidy_curve(path: Path) -> None:
    """Drop the header lines that a resumed run's ``fix ave/time ... append`` wrote again mid-file:
    one header, then the rows."""
    if not path.exists():
        return
    lines = path.read_text().splitlines(keepends=True)
    first_row = next((k for k, line in enumerate(lines) if line.strip() and not line.startswith("#")), len(lines))
    keep = lines[:first_row] + [line for line in lines[first_row:] if not line.startswith("#")]
    if len(keep) != len(lines):
        write_text_atomic(path, "".join(keep))


@dataclass
class ElasticFit:
    """Linear fit of stress on strain over the elastic window."""

    modulus_MPa: float
    intercept_MPa: float
    window: tuple[float, float]
    r2: float
    points: int


def fit_elastic(strain: np.ndarray, stress: np.ndarray, window_fraction: float = 0.3,
                min_points: int = 6, r2_min: float = 0.995) -> ElasticFit:
    """Young's modulus from the steepest linear stretch before the peak.

    Windows spanning ``window_fraction`` of the points up to the peak slide along the
    curve; among those whose fit has R^2 >= r2_min the steepest is taken (the initial
    contact region is flatter, failure bends the curve down), else the best R^2.
    """
    peak = int(np.argmax(stress))
    n = max(peak + 1, min_points)
    x, y = strain[:n], stress[:n]
    w = max(min_points, int(round(window_fraction * n)))
    best, best_r2 = None, None
    for a in range(0, max(1, n - w + 1)):
        xs, ys = x[a:a + w], y[a:a + w]
        if len(xs) < min_points or np.ptp(xs) == 0:
            continue
        slope, icpt = np.polyfit(xs, ys, 1)
        resid = ys - (slope * xs + icpt)
        ss = np.sum((ys - ys.mean()) ** 2)
        r2 = 1 - np.sum(resid**2) / ss if ss > 0 else 0.0
        fit = ElasticFit(float(slope), float(icpt), (float(xs[0]), float(xs[-1])), float(r2), len(xs))
        if r2 >= r2_min and (best is None or best_r2 < r2_min or slope > best.modulus_MPa):
            best, best_r2 = fit, r2
        elif best is None or (best_r2 < r2_min and r2 > best_r2):
            best, best_r2 = fit, r2
    if best is None:
        raise ValueError("too few points before the peak to fit a modulus")
    return best


def read_dump_custom(path: Path) -> dict[str, np.ndarray]:
    """A LAMMPS custom dump (one snapshot) as columns keyed by the ITEM: ATOMS names."""
    text = Path(path).read_text()
    head, body = text.split("ITEM: ATOMS", 1)
    names, _, data = body.partition("\n")
    cols = names.split()
    values = np.array(data.split(), dtype=float).reshape(-1, len(cols))
    return {c: values[:, k] for k, c in enumerate(cols)}


def read_dump_local(path: Path) -> np.ndarray:
    text = Path(path).read_text()
    _, body = text.split("ITEM: ENTRIES", 1)
    names, _, data = body.partition("\n")
    return np.array(data.split(), dtype=float).reshape(-1, len(names.split()))


def snapshot_files(folder: Path, kind: str, suffix: str = "txt") -> dict[int, Path]:
    """The snapshots ``snapshots/KIND.STEP.SUFFIX`` of a run folder by step."""
    out = {}
    for p in (Path(folder) / "snapshots").glob(f"{kind}.*.{suffix}"):
        m = re.match(rf"{kind}\.(\d+)\.{suffix}$", p.name)
        if m:
            out[int(m.group(1))] = p
    return dict(sorted(out.items()))


def particle_stress(dump: dict[str, np.ndarray]) -> np.ndarray:
    """Cauchy stress per particle (MPa, tension positive), eq. 21 with V_p = 4/3 pi r^3.

    ``compute stress/atom`` gives -(1/2 sum_K l F) per atom in pressure x volume (the
    negative virial; bonds tally the full bond force along the centre-centre vector,
    contacts likewise), so sigma = stress/atom / V_p.  Columns xx yy zz xy xz yz.
    """
    if "sigma_xx" in dump:          # the snapshots' own columns (templates/snapshots.lmp)
        return np.column_stack([dump[f"sigma_{c}"] for c in STRESS_COLUMNS])
    vol = 4.0 / 3.0 * np.pi * dump["radius"] ** 3
    return np.column_stack([dump[f"c_stress[{k}]"] for k in range(1, 7)]) / vol[:, None]


def stress_by_material(sigma: np.ndarray, types: np.ndarray, type_names: list[str],
                       exclude: tuple[str, ...] = ("substrate",)) -> dict[str, dict[str, float]]:
    """Mean and std of sigma_xx and sigma_zz per material (Table 2 of Dosta et al.)."""
    out = {}
    for t, name in enumerate(type_names):
        if name in exclude:
            continue
        sel = types == t + 1
        if not sel.any():
            continue
        out[name] = {"sigma_xx_mean_MPa": float(sigma[sel, 0].mean()), "sigma_xx_std_MPa": float(sigma[sel, 0].std()),
                     "sigma_zz_mean_MPa": float(sigma[sel, 2].mean()), "sigma_zz_std_MPa": float(sigma[sel, 2].std()),
                     "particles": int(sel.sum())}
    return out


def stress_table(stress_by_strain: dict[str, dict[str, dict]], digits: int = 1) -> list[str]:
    """Report lines: the particle stresses per material at each strain (Table 2 format of Dosta et al.)."""
    if not stress_by_strain:
        return []
    lines = ["Particle stresses (eq. 21, V_p = particle volume; tension positive):", "",
             "| strain | material | sigma_xx (MPa) | sigma_zz (MPa) |", "|---|---|---|---|"]
    for strain_txt, mats in stress_by_strain.items():
        for mat, v in mats.items():
            lines.append(f"| {strain_txt} | {mat} | {v['sigma_xx_mean_MPa']:.{digits}f} +- "
                         f"{v['sigma_xx_std_MPa']:.{digits}f} | {v['sigma_zz_mean_MPa']:.{digits}f} +- "
                         f"{v['sigma_zz_std_MPa']:.{digits}f} |")
    return lines


def plot_stress_histograms(path: Path, snapshots: list[tuple[float, np.ndarray, np.ndarray]],
                           type_names: list[str]) -> None:
    """sigma_xx and sigma_zz histograms per material (substrate left out) at each snapshot (rows), with
    each material's mean +- std (the Table 2 format of Dosta et al.) in the legend, into ``path``.

    ``snapshots``: (strain, sigma (n, 6) MPa, types) per snapshot.  The range of each column is the
    middle 99.8 % of all snapshots' stresses, so one range compares the rows."""
    from opalflow.store import new_figure, save_figure

    rows = len(snapshots)
    fig, axes = new_figure(rows, 2, figsize=(8.5, 2.3 * rows + 0.6), squeeze=False, sharex="col")
    for col, (k, label) in enumerate(((0, "sigma_xx"), (2, "sigma_zz"))):
        every = np.concatenate([sig[:, k] for _, sig, _ in snapshots])
        lo, hi = np.percentile(every, [0.1, 99.9]) if len(every) else (-1.0, 1.0)
        bins = np.linspace(lo, hi if hi > lo else lo + 1.0, 61)
        for row, (strain, sigma, types) in enumerate(snapshots):
            ax = axes[row, col]
            for t, name in enumerate(type_names):
                sel = types == t + 1
                if name == "substrate" or not sel.any():
                    continue
                v = sigma[sel, k]
                ax.hist(np.clip(v, bins[0], bins[-1]), bins=bins, histtype="step", weights=np.full(sel.sum(), 1 / sel.sum()),
                        label=f"{name}: {v.mean():.1f} +- {v.std():.1f} MPa")
            ax.axvline(0, color="0.8", lw=0.6)
            ax.set_ylabel(f"fraction\nstrain {100 * strain:.2f} %", fontsize=8)
            ax.legend(fontsize=7, loc="upper right")
        axes[-1, col].set_xlabel(f"{label} (MPa, tension +)")
    save_figure(fig, path)


def bond_strains(local: np.ndarray) -> np.ndarray:
    """Strain r / r0 - 1 of each intact bond of a ``snapshots/bonds.*.txt`` dump (columns dist, r0)."""
    return local[:, 0] / local[:, 1] - 1.0


def strain_bins(samples: list[np.ndarray], n: int = 80) -> np.ndarray:
    """Bin edges for bond-strain histograms set by the data: the middle 99.8 % of all samples together
    (values beyond fall into the end bins), so the bins resolve where the bonds are."""
    every = np.concatenate(samples) if samples else np.zeros(0)
    lo, hi = np.percentile(every, [0.1, 99.9]) if len(every) else (-0.01, 0.01)
    if hi <= lo:
        lo, hi = lo - 1e-6, hi + 1e-6
    return np.linspace(lo, hi, n + 1)


def histogram_fraction(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Fraction of ``values`` per bin of ``edges`` (those outside counted in the end bins; Fig. 7 format)."""
    counts, _ = np.histogram(np.clip(values, edges[0], edges[-1]), bins=edges)
    return counts / max(1, len(values))


def plot_bond_strains(path: Path, edges: np.ndarray, fractions: dict[str, np.ndarray]) -> None:
    """Bond-strain histograms (Dosta et al. Fig. 7), one line per label, on a log axis so the tails that
    break show beside the peak."""
    from opalflow.store import new_figure, save_figure

    fig, ax = new_figure(figsize=(5, 3.4))
    mids = 0.5 * (edges[1:] + edges[:-1])
    for label, frac in fractions.items():
        ax.step(100 * mids, np.where(frac > 0, frac, np.nan), where="mid", label=label)
    ax.set_yscale("log")
    ax.set_xlabel("bond strain r/r0 - 1 (%)")
    ax.set_ylabel("fraction of bonds")
    ax.legend(fontsize=8)
    save_figure(fig, path)
