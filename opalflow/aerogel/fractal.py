"""Fractal dimension of an aggregate, four ways, each with its fitted range and 95 % interval: the two below,
the pair correlation g(r) (:func:`pair_correlation`) and the structure factor S(q) (:func:`structure_factor`).

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
from dataclasses import dataclass

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


@dataclass
class MassRadiusCurve:
    r_nm: np.ndarray
    count: np.ndarray                   # sphere centres within r of a centre
    background: np.ndarray              # the homogeneous n 4/3 pi r^3


@dataclass
class GyrationCurve:
    N: np.ndarray                       # every merger's new cluster: its size and radius of gyration
    rg_nm: np.ndarray
    used: np.ndarray                    # the clusters fitted
    crossover_mass: float
    bin_N: np.ndarray | None = None     # the bin means the fit runs through (None: none fitted)
    bin_rg_nm: np.ndarray | None = None


@dataclass
class PairCurve:
    r_nm: np.ndarray
    g: np.ndarray
    xi_nm: float                        # the cut-off length (nan: its fit failed)
    beta: float


@dataclass
class StructureCurve:
    q_per_nm: np.ndarray
    S: np.ndarray


@dataclass
class FractalEstimates:
    """Every estimate of D_f of an aggregate, each with the curve it was fitted to."""

    mass_radius: tuple[FractalFit, MassRadiusCurve]
    rg: tuple[FractalFit, GyrationCurve]
    gr: tuple[FractalFit, PairCurve]
    sq: tuple[FractalFit, StructureCurve]

    def fits(self) -> list[FractalFit]:
        return [self.mass_radius[0], self.rg[0], self.gr[0], self.sq[0]]


def estimates(agg: Aggregate, seed: int) -> FractalEstimates:
    """The four estimates of D_f of an aggregate (S(q) over the window that g(r)'s cut-off length sets)."""
    gr = pair_correlation(agg, seed=seed)
    return FractalEstimates(mass_radius(agg, seed=seed), radius_of_gyration(agg), gr,
                            structure_factor(agg, gr[1].xi_nm))


def _linear_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope and the half-width of its 95 % interval."""
    res = stats.linregress(x, y)
    return float(res.slope), float(stats.t.ppf(0.975, len(x) - 2) * res.stderr)


def mass_radius(agg: Aggregate, *, centres: int = 4000, seed: int = 0) -> tuple[FractalFit, MassRadiusCurve]:
    """D from the excess mass-radius relation of the network (method 1), and the curve for the plot."""
    x, L, n = agg.positions, agg.box, len(agg.positions)
    d = float(np.mean(agg.diameters))
    r = np.geomspace(0.8 * d, L / 2, 48)
    pick = np.random.default_rng(seed).choice(n, min(n, centres), replace=False)
    count = cKDTree(x[pick], boxsize=L).count_neighbors(cKDTree(x, boxsize=L), r) / len(pick) - 1.0
    background = (n - 1) / L**3 * 4 / 3 * np.pi * r**3
    curve = MassRadiusCurve(r, count, background)
    above = np.flatnonzero((r >= 2 * d) & (count < DENSER * background))
    r_hi = float(r[above[0] - 1]) if len(above) and above[0] > 0 else float(r[-1])
    sel = (r >= 2 * d) & (r <= r_hi) & (count > background)
    if r_hi < 1.5 * 2 * d or sel.sum() < 4:
        return FractalFit("mass-radius", math.nan, (math.nan, math.nan), (2 * d, r_hi), int(sel.sum()),
                          f"no fractal range: the network is less than {DENSER}x denser than the mean beyond "
                          f"r = {r_hi:.3g} nm (< 3 d)"), curve
    slope, half = _linear_fit(np.log(r[sel]), np.log(count[sel] - background[sel]))
    return FractalFit("mass-radius", slope, (slope - half, slope + half), (2 * d, r_hi), int(sel.sum())), curve


def _bin_means(x: np.ndarray, y: np.ndarray, width: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Means of x and y in bins of x ``width`` wide from its smallest value (empty bins left out): ln R_g
    against ln N in bins of a quarter of an e-fold."""
    which = np.floor((x - x.min()) / width).astype(int)
    counts = np.bincount(which)
    bins = np.flatnonzero(counts)
    return np.bincount(which, x)[bins] / counts[bins], np.bincount(which, y)[bins] / counts[bins]


def crossover_mass(N: np.ndarray, rg: np.ndarray, diameters: np.ndarray, solid_fraction: float) -> float:
    """The crossover mass N_c: the cluster size at which a cluster's diameter 2 sqrt(5/3) R_g (the sphere of
    the same R_g) equals the spacing of the cluster centres, nu^(-1/3) with nu = phi / (N v) clusters per
    volume: beyond it the clusters crowd and grow towards the gel's percolation-like structure instead of as
    dilute clusters (Rottereau et al., Eur. Phys. J. E 15, 133, 2004).  From bin means of ln R_g against
    ln N (a quarter of an e-fold); inf if no cluster reached it."""
    keep = (N >= 2) & (rg > 0)
    if keep.sum() < 2:
        return math.inf
    bN, brg = map(np.exp, _bin_means(np.log(N[keep]), np.log(rg[keep])))
    v = float(np.mean(np.pi / 6 * diameters**3))
    nu = solid_fraction / (bN * v)
    reach = 2 * math.sqrt(5 / 3) * brg * nu ** (1 / 3)
    above = np.flatnonzero(reach >= 1.0)
    if not len(above):
        return math.inf
    k = int(above[0])
    if k == 0:
        return float(bN[0])
    # log-linear interpolation between the bins that straddle it
    f = math.log(reach[k - 1]) / math.log(reach[k - 1] / reach[k])
    return float(math.exp(math.log(bN[k - 1]) + f * math.log(bN[k] / bN[k - 1])))


#: the R_g(N) fit: from this cluster size (smaller clusters' local slope wanders)
RG_N_MIN = 20
#: ... to this fraction of the crossover mass (Rottereau et al. 2004: the dilute regime ends well before it)
RG_CROSSOVER_FRACTION = 1 / 3


def radius_of_gyration(agg: Aggregate, *, n_min: int = RG_N_MIN) -> tuple[FractalFit, GyrationCurve]:
    """D from R_g ~ N^(1/D) of the clusters made during aggregation (method 2), and the points.

    The ensemble is every merger's new cluster; the fit runs from ``n_min`` to a third of the crossover mass
    (:func:`crossover_mass`) and below R_g = L/4, in bins of ln N (a quarter of an e-fold), so that it sees
    the dilute regime where the references measure D_f (Jullien, Kolb and Botet 1984: 1.78 +- 0.05).  A
    range of less than a factor 3 in N is reported as none (the gel is too dense for dilute clusters)."""
    N, rg = agg.merger_size.astype(float), agg.merger_rg
    n_c = crossover_mass(N, rg, agg.diameters, agg.solid_fraction)
    n_hi = n_c * RG_CROSSOVER_FRACTION
    keep = (N >= n_min) & (N <= n_hi) & (rg < agg.box / 4) & (rg > 0)
    curve = GyrationCurve(N, rg, keep, n_c)
    rng = (float(n_min), float(min(n_hi, N.max())))
    if rng[1] < 3 * n_min or keep.sum() < 10:
        return FractalFit("R_g(N)", math.nan, (math.nan, math.nan), rng, int(keep.sum()),
                          f"no dilute range: crossover mass {n_c:.4g}, a third of it is less than 3 x {n_min} "
                          "(too dense: measure D_f by g(r) or S(q), or dilute the aggregate)"), curve
    bx, by = _bin_means(np.log(N[keep]), np.log(rg[keep]))
    curve.bin_N, curve.bin_rg_nm = np.exp(bx), np.exp(by)
    if len(bx) < 4:
        return FractalFit("R_g(N)", math.nan, (math.nan, math.nan), rng, len(bx), "fewer than 4 bins of ln N"), curve
    slope, half = _linear_fit(bx, by)
    lo, hi = 1 / (slope + half), (1 / (slope - half) if slope > half else math.inf)
    return FractalFit("R_g(N)", 1 / slope, (lo, hi), rng, len(bx),
                      f"{int(keep.sum())} clusters; crossover mass {n_c:.4g}"), curve


def _cutoff(r: np.ndarray, excess: np.ndarray, d: float) -> tuple[float, float]:
    """The correlation length xi and exponent beta of g(r) - 1 = A r^(D - 3) exp(-(r / xi)^beta) (the fractal
    times its cut-off function, as for clusters: Sorensen and Roberts, J. Colloid Interface Sci. 186, 447,
    1997), fitted over r from 2 d to where g - 1 first falls below 0.05, with beta >= 1 (a cut-off at least as
    sharp as an exponential; they find ~2 for DLCA clusters: below 1 the fit trades the power law for a
    stretched exponential and drifts to D = 3); nan if the fit fails."""
    from scipy.optimize import curve_fit

    low = np.flatnonzero((r > 2 * d) & (excess < 0.05))
    end = r[low[0]] if len(low) else r[-1]
    sel = (r >= 2 * d) & (r < end) & (excess > 0)
    if sel.sum() < 6:
        return math.nan, math.nan

    def model(lr, ln_a, dim, ln_xi, beta):
        return ln_a + (dim - 3) * lr - np.exp(beta * (lr - ln_xi))

    try:
        p, _ = curve_fit(model, np.log(r[sel]), np.log(excess[sel]), p0=[0.0, 1.8, math.log(end / 2), 2.0],
                         bounds=([-50, 0.5, math.log(d), 1.0], [50, 3.0, math.log(10 * end), 6.0]), maxfev=20000)
    except (RuntimeError, ValueError):
        return math.nan, math.nan
    return float(math.exp(p[2])), float(p[3])


def pair_correlation(agg: Aggregate, *, centres: int = 4000, seed: int = 0) -> tuple[FractalFit, PairCurve]:
    """D from the gel's pair correlation: g(r) - 1 ~ r^(D - 3) between 4 radii (2 d: past the contact spike
    at d and the jump at 2 d, Hasmy et al., Phys. Rev. B 50, 6006, 1994) and half the correlation length xi,
    with the cut-off function exp(-(r / xi)^beta) that :func:`_cutoff` fits divided out (without it the
    slope over that window reads ~0.3 low: the cut-off already bends g at xi / 4).  g(r) from the centres
    within shells of log-spaced radii around up to ``centres`` random centres (periodic cube)."""
    x, L, n = agg.positions, agg.box, len(agg.positions)
    d = float(np.mean(agg.diameters))
    edges = np.geomspace(0.8 * d, L / 2, 64)
    pick = np.random.default_rng(seed).choice(n, min(n, centres), replace=False)
    cum = cKDTree(x[pick], boxsize=L).count_neighbors(cKDTree(x, boxsize=L), edges) / len(pick)
    shell = 4 / 3 * np.pi * np.diff(edges**3)
    g = np.diff(cum) / (shell * (n - 1) / L**3)
    r = np.sqrt(edges[1:] * edges[:-1])
    xi, beta = _cutoff(r, g - 1.0, d)
    curve = PairCurve(r, g, xi, beta)
    if not math.isfinite(xi):
        return FractalFit("g(r)", math.nan, (math.nan, math.nan), (2 * d, L / 2), 0,
                          "no correlation length: the cut-off fit of g(r) failed"), curve
    sel = (r >= 2 * d) & (r <= xi / 2) & (g > 1.0)
    if xi / 2 < 1.5 * 2 * d or sel.sum() < 4:
        return FractalFit("g(r)", math.nan, (math.nan, math.nan), (2 * d, xi / 2), int(sel.sum()),
                          f"no fractal range: correlation length {xi:.3g} nm < 6 d"), curve
    slope, half = _linear_fit(np.log(r[sel]), np.log(g[sel] - 1.0) + (r[sel] / xi) ** beta)
    return FractalFit("g(r)", 3 + slope, (3 + slope - half, 3 + slope + half), (2 * d, xi / 2), int(sel.sum()),
                      f"correlation length xi = {xi:.4g} nm, cut-off exponent beta = {beta:.2f}"), curve


def structure_factor(agg: Aggregate, xi: float, *, grid: int = 0) -> tuple[FractalFit, StructureCurve]:
    """D from the structure factor of the sphere centres, S(q) = |sum_j exp(-i q x_j)|^2 / N ~ q^-D (what a
    small-angle scattering experiment sees, less the sphere form factor; Heinson, Chakrabarti and Sorensen
    2010 measure off-lattice DLCA both ways), over q = pi / r for r from 2 d to xi / 2 (the window of
    :func:`pair_correlation`, mapped by q r = pi: the centre of the first oscillation of sin(q r) / (q r), the
    transform that takes g(r) to S(q)).  S(q) on the box's reciprocal lattice by an FFT of the centres assigned to a
    grid (cloud in cell, its window divided out), averaged in log-spaced shells of |q|."""
    x, L, n = agg.positions, agg.box, len(agg.positions)
    d = float(np.mean(agg.diameters))
    m = grid or int(min(256, 2 ** math.ceil(math.log2(4 * L / d))))
    h = L / m
    rho = np.zeros((m, m, m))
    s = x / h - 0.5
    i0 = np.floor(s).astype(int)
    f = s - i0
    for corner in range(8):
        o = np.array([(corner >> k) & 1 for k in range(3)])
        wgt = np.prod(np.where(o, f, 1 - f), axis=1)
        idx = np.mod(i0 + o, m)
        np.add.at(rho, (idx[:, 0], idx[:, 1], idx[:, 2]), wgt)
    amp = np.fft.rfftn(rho)
    k = np.fft.fftfreq(m, 1 / m)
    kz = np.fft.rfftfreq(m, 1 / m)
    qx, qy, qz = np.meshgrid(k, k, kz, indexing="ij")
    window = (np.sinc(qx / m) * np.sinc(qy / m) * np.sinc(qz / m)) ** 2     # CIC: sinc^2 per axis
    power = np.abs(amp) ** 2 / window**2 / n
    q = 2 * np.pi / L * np.sqrt(qx**2 + qy**2 + qz**2)
    ok = (q > 0) & (q <= np.pi / h)       # below the grid's Nyquist wavenumber
    edges = np.geomspace(2 * np.pi / L, np.pi / h, 60)
    which = np.digitize(q[ok], edges)
    cnt = np.bincount(which, minlength=len(edges) + 1)[1:len(edges)]
    sq = np.bincount(which, power[ok], minlength=len(edges) + 1)[1:len(edges)]
    qs = np.bincount(which, q[ok], minlength=len(edges) + 1)[1:len(edges)]
    has = cnt > 0
    curve = StructureCurve(qs[has] / cnt[has], sq[has] / cnt[has])
    if not math.isfinite(xi):
        return FractalFit("S(q)", math.nan, (math.nan, math.nan), (math.nan, math.nan), 0,
                          "no correlation length (see g(r)): no window to fit"), curve
    q_lo, q_hi = np.pi / (xi / 2), np.pi / (2 * d)
    qq, S = curve.q_per_nm, curve.S
    sel = (qq >= q_lo) & (qq <= q_hi)
    if sel.sum() < 4 or q_hi < 1.5 * q_lo:
        return FractalFit("S(q)", math.nan, (math.nan, math.nan), (q_lo, q_hi), int(sel.sum()),
                          "fewer than 4 shells of q in the window"), curve
    slope, half = _linear_fit(np.log(qq[sel]), np.log(S[sel]))
    return FractalFit("S(q)", -slope, (-slope - half, -slope + half), (q_lo, q_hi), int(sel.sum()),
                      f"q from pi / (xi / 2) to pi / (2 d), grid {m}^3"), curve


def _fit_line(ax, fit: FractalFit, x, y, power) -> None:
    """The fitted power law through the points of its window (exponent ``power(D)``)."""
    if not math.isfinite(fit.D):
        return
    sel = (x >= fit.range[0]) & (x <= fit.range[1]) & (y > 0)
    if not sel.any():
        return
    p = power(fit.D)
    k = np.exp(np.mean(np.log(y[sel]) - p * np.log(x[sel])))
    g = np.geomspace(*fit.range, 10)
    ax.loglog(g, k * g**p, "r-", lw=2, label=f"D = {fit.D:.2f} [{fit.ci95[0]:.2f}, {fit.ci95[1]:.2f}]")


def plot_fractal(fits: FractalEstimates, path) -> None:
    """The estimates side by side: excess count against r, R_g against N (crossover mass marked), g(r) - 1
    and S(q), each with its fit."""
    fig, axes = new_figure(2, 2, figsize=(10, 8))
    a, b, cg, cs = axes.ravel()
    fit, c = fits.mass_radius
    excess = c.count - c.background
    a.loglog(c.r_nm, c.count, "o", ms=3, label="C(r): centres within r")
    a.loglog(c.r_nm, c.background, "k:", label="homogeneous n 4/3 pi r^3")
    a.loglog(c.r_nm[excess > 0], excess[excess > 0], "s", ms=3, mfc="none", label="C - background")
    _fit_line(a, fit, c.r_nm, excess, lambda D: D)
    a.set_xlabel("r (nm)")
    a.set_ylabel("spheres within r")
    a.set_title("mass-radius of the network" + ("" if math.isfinite(fit.D) else " (no fractal range)"))
    a.legend(fontsize=7)
    fit, c = fits.rg
    b.loglog(c.N, c.rg_nm, ".", ms=2, alpha=0.2, color="0.5", label="mergers")
    b.loglog(c.N[c.used], c.rg_nm[c.used], ".", ms=2, alpha=0.3, label="mergers fitted")
    if c.bin_N is not None:
        b.loglog(c.bin_N, c.bin_rg_nm, "ko", ms=4, label="bin means")
        _fit_line(b, fit, c.bin_N, c.bin_rg_nm, lambda D: 1 / D)
    if math.isfinite(c.crossover_mass):
        b.axvline(c.crossover_mass, color="k", ls="--", lw=1, label=f"crossover mass {c.crossover_mass:.3g}")
    b.set_xlabel("cluster size N")
    b.set_ylabel("R_g (nm)")
    b.set_title("radius of gyration during aggregation" + ("" if math.isfinite(fit.D) else " (no dilute range)"))
    b.legend(fontsize=7)
    fit, c = fits.gr
    ex = c.g - 1.0
    cg.loglog(c.r_nm[ex > 0], ex[ex > 0], "o", ms=3, label="g(r) - 1")
    if math.isfinite(fit.D):             # the fit: the power law times the cut-off, through the window's points
        r, xi, beta = c.r_nm, c.xi_nm, c.beta
        sel = (r >= fit.range[0]) & (r <= fit.range[1]) & (ex > 0)
        k = np.exp(np.mean(np.log(ex[sel]) + (r[sel] / xi) ** beta - (fit.D - 3) * np.log(r[sel])))
        g = np.geomspace(fit.range[0], xi, 30)
        cg.loglog(g, k * g ** (fit.D - 3) * np.exp(-(g / xi) ** beta), "r-", lw=2,
                  label=f"D = {fit.D:.2f} [{fit.ci95[0]:.2f}, {fit.ci95[1]:.2f}], cut-off beta = {beta:.2f}")
        cg.axvline(fit.range[1], color="r", ls=":", lw=1, label="xi / 2: end of the fitted window")
    if math.isfinite(c.xi_nm):
        cg.axvline(c.xi_nm, color="k", ls="--", lw=1, label=f"xi = {c.xi_nm:.3g} nm (cut-off length)")
    cg.set_xlabel("r (nm)")
    cg.set_ylabel("g(r) - 1")
    cg.set_title("pair correlation of the gel")
    cg.legend(fontsize=7)
    fit, c = fits.sq
    cs.loglog(c.q_per_nm, c.S, "o", ms=3, label="S(q) of the centres")
    _fit_line(cs, fit, c.q_per_nm, c.S, lambda D: -D)
    cs.set_xlabel("q (1/nm)")
    cs.set_ylabel("S(q)")
    cs.set_title("structure factor")
    cs.legend(fontsize=7)
    save_figure(fig, path)
