"""Porosity correlations of Dosta et al. section 4, fitted with 95 % confidence intervals.

    E(eps) = E0 exp(-b eps)        (22)       E(eps) = E0 (1 - eps)^m     (23)
    sigma(eps) = sigma0 exp(-b eps)     (26)

Each is fitted as a straight line in log space (ln E = ln E0 - b eps, ln E = ln E0 + m ln(1 - eps)),
the usual way for these laws; the 95 % intervals come from the Student t quantile with n - 2
degrees of freedom and the slope's standard error.  R^2 is computed on the original values so
that the two E laws can be compared on the same footing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass
class Fit:
    law: str
    prefactor: float
    prefactor_ci: tuple[float, float]
    exponent: float
    exponent_ci: tuple[float, float]
    r2: float               # on the values, not their logarithms
    rmse_log: float         # residual of ln(value)
    n: int


def _line_fit(x: np.ndarray, y_log: np.ndarray, values: np.ndarray, law: str, sign: float, model) -> Fit:
    res = stats.linregress(x, y_log)
    n = len(x)
    t = stats.t.ppf(0.975, n - 2) if n > 2 else np.inf
    slope_ci = (res.slope - t * res.stderr, res.slope + t * res.stderr)
    icpt_ci = (res.intercept - t * res.intercept_stderr, res.intercept + t * res.intercept_stderr)
    prefactor = float(np.exp(res.intercept))
    exponent = sign * res.slope
    pred = model(prefactor, exponent)
    ss_res = float(np.sum((values - pred) ** 2))
    ss_tot = float(np.sum((values - values.mean()) ** 2))
    return Fit(law=law, prefactor=prefactor, prefactor_ci=(float(np.exp(icpt_ci[0])), float(np.exp(icpt_ci[1]))),
               exponent=float(exponent), exponent_ci=tuple(sorted(float(sign * s) for s in slope_ci)),
               r2=1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
               rmse_log=float(np.sqrt(np.mean((y_log - (res.intercept + res.slope * x)) ** 2))), n=n)


def fit_exponential(porosity, values) -> Fit:
    """Eq. 22 / 26: value = V0 exp(-b eps); exponent = b."""
    eps, v = np.asarray(porosity, float), np.asarray(values, float)
    return _line_fit(eps, np.log(v), v, "exponential", -1.0, lambda v0, b: v0 * np.exp(-b * eps))


def fit_power(porosity, values) -> Fit:
    """Eq. 23: value = V0 (1 - eps)^m; exponent = m."""
    eps, v = np.asarray(porosity, float), np.asarray(values, float)
    return _line_fit(np.log1p(-eps), np.log(v), v, "power", 1.0, lambda v0, m: v0 * (1.0 - eps) ** m)


def fit_power_law(x, y) -> Fit:
    """y = a x^k (cost laws): exponent = k."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return _line_fit(np.log(x), np.log(y), y, "power law", 1.0, lambda a, k: a * x ** k)
