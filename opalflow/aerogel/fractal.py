"""Fractal dimension of an aggregate, two ways, each with its fitted range and 95 % interval.

1. Mass-radius of the network: C(r), the mean number of sphere centres within r of a sphere centre
   (periodic cube, up to 4000 random centres), less the homogeneous background H(r) = n 4/3 pi r^3,
   grows as r^D inside the fractal range (the pair correlation g(r) - 1 ~ r^(D-3) integrated; Hasmy et
   al., Phys. Rev. B 50, 6006, 1994).  The range is [2 d, r_x] with d the mean diameter (above the
   contact shell) and r_x the radius at which C = 2.5 H (the network still 2.5 times denser than the
   mean: the crossover to homogeneity at the correlation length has barely set in).  A range shorter
   than a factor 1.5 is reported as none: dense gels are fractal over less than a diameter.
2. Radius of gyration against mass during aggregation: R_g ~ N^(1/D) over every merger's new cluster
   with N >= 30 (smaller clusters are too few spheres for the power law: their local slope wanders by
   0.3) and R_g < L/4 (smaller than the box, before they span it), averaged in bins of ln N (a quarter
   of an e-fold), slope by least squares.

Intervals are the regression's 95 % (Student t) intervals; the points are correlated, so these are
lower bounds of the uncertainty: seeds give the spread.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats
from scipy.spatial import cKDTree

from opalflow.aerogel.aggregation import Aggregate
from opalflow.store import new_figure, save_figure


#: the mass-radius fit ends where the network is this many times denser than the mean
DENSER = 2.5


@dataclass
class FractalFit:
    """One estimate of D: value, 95 % interval, the fitted range and the points it used."""

    method: str
    D: float
    ci95: tuple[float, float]
    range: tuple[float, float]          # nm (mass-radius) or N (R_g(N))
    points: int
    note: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def _linear_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope and the half-width of its 95 % interval."""
    res = stats.linregress(x, y)
    return float(res.slope), float(stats.t.ppf(0.975, len(x) - 2) * res.stderr)


def mass_radius(agg: Aggregate, *, centres: int = 4000, seed: int = 0) -> tuple[FractalFit, dict]:
    """D from the excess mass-radius relation of the network (method 1), and the curve for the plot."""
    x, L, n = agg.positions, agg.box, len(agg.positions)
    d = float(np.mean(agg.diameters))
    r = np.geomspace(0.8 * d, L / 2, 48)
    pick = np.random.default_rng(seed).choice(n, min(n, centres), replace=False)
    count = cKDTree(x[pick], boxsize=L).count_neighbors(cKDTree(x, boxsize=L), r) / len(pick) - 1.0
    background = (n - 1) / L**3 * 4 / 3 * np.pi * r**3
    curve = {"r_nm": r, "count": count, "background": background}
    above = np.flatnonzero((r >= 2 * d) & (count < DENSER * background))
    r_hi = float(r[above[0] - 1]) if len(above) and above[0] > 0 else float(r[-1])
    sel = (r >= 2 * d) & (r <= r_hi) & (count > background)
    if r_hi < 1.5 * 2 * d or sel.sum() < 4:
        return FractalFit("mass-radius", math.nan, (math.nan, math.nan), (2 * d, r_hi), int(sel.sum()),
                          f"no fractal range: the network is less than {DENSER}x denser than the mean beyond "
                          f"r = {r_hi:.3g} nm (< 3 d)"), curve
    slope, half = _linear_fit(np.log(r[sel]), np.log(count[sel] - background[sel]))
    return FractalFit("mass-radius", slope, (slope - half, slope + half), (2 * d, r_hi), int(sel.sum())), curve


def radius_of_gyration(agg: Aggregate, *, n_min: int = 30) -> tuple[FractalFit, dict]:
    """D from R_g ~ N^(1/D) of the clusters made during aggregation (method 2), and the points."""
    N, rg = agg.merger_size.astype(float), agg.merger_rg
    keep = (N >= n_min) & (rg < agg.box / 4) & (rg > 0)
    curve = {"N": N, "rg_nm": rg, "used": keep}
    if keep.sum() < 10:
        return FractalFit("R_g(N)", math.nan, (math.nan, math.nan), (n_min, n_min), int(keep.sum()),
                          "too few clusters smaller than a quarter of the box"), curve
    lnN, lnrg = np.log(N[keep]), np.log(rg[keep])
    edges = np.arange(lnN.min(), lnN.max() + 0.25, 0.25)
    which = np.digitize(lnN, edges)
    bx = np.array([lnN[which == b].mean() for b in np.unique(which)])
    by = np.array([lnrg[which == b].mean() for b in np.unique(which)])
    curve.update(bin_N=np.exp(bx), bin_rg_nm=np.exp(by))
    if len(bx) < 4:
        return FractalFit("R_g(N)", math.nan, (math.nan, math.nan), (float(N[keep].min()), float(N[keep].max())),
                          len(bx), "fewer than 4 bins of ln N"), curve
    slope, half = _linear_fit(bx, by)
    lo, hi = 1 / (slope + half), (1 / (slope - half) if slope > half else math.inf)
    return FractalFit("R_g(N)", 1 / slope, (lo, hi), (float(N[keep].min()), float(N[keep].max())), len(bx)), curve


def plot_fractal(mr: tuple[FractalFit, dict], rg: tuple[FractalFit, dict], path) -> None:
    """Both estimates side by side: excess count against r, R_g against N, each with its fit."""
    fig, (a, b) = new_figure(1, 2, figsize=(10, 4))
    fit, c = mr
    excess = c["count"] - c["background"]
    a.loglog(c["r_nm"], c["count"], "o", ms=3, label="C(r): centres within r")
    a.loglog(c["r_nm"], c["background"], "k:", label="homogeneous n 4/3 pi r^3")
    a.loglog(c["r_nm"][excess > 0], excess[excess > 0], "s", ms=3, mfc="none", label="C - background")
    if math.isfinite(fit.D):
        r = np.geomspace(*fit.range, 10)
        sel = (c["r_nm"] >= fit.range[0]) & (c["r_nm"] <= fit.range[1])
        k = np.exp(np.mean(np.log(excess[sel]) - fit.D * np.log(c["r_nm"][sel])))
        a.loglog(r, k * r**fit.D, "r-", lw=2, label=f"D = {fit.D:.2f} [{fit.ci95[0]:.2f}, {fit.ci95[1]:.2f}]")
    a.set_xlabel("r (nm)")
    a.set_ylabel("spheres within r")
    a.set_title("mass-radius of the network" + ("" if math.isfinite(fit.D) else " (no fractal range)"))
    a.legend(fontsize=7)
    fit, c = rg
    b.loglog(c["N"][c["used"]], c["rg_nm"][c["used"]], ".", ms=2, alpha=0.3, label="mergers")
    if "bin_N" in c:
        b.loglog(c["bin_N"], c["bin_rg_nm"], "ko", ms=4, label="bin means")
    if math.isfinite(fit.D):
        N = np.geomspace(*fit.range, 10)
        k = np.exp(np.mean(np.log(c["bin_rg_nm"]) - np.log(c["bin_N"]) / fit.D))
        b.loglog(N, k * N ** (1 / fit.D), "r-", lw=2, label=f"D = {fit.D:.2f} [{fit.ci95[0]:.2f}, {fit.ci95[1]:.2f}]")
    b.set_xlabel("cluster size N")
    b.set_ylabel("R_g (nm)")
    b.set_title("radius of gyration during aggregation")
    b.legend(fontsize=7)
    save_figure(fig, path)
