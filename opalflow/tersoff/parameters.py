"""Tersoff parameter sets in LAMMPS ``pair_style tersoff`` form, and ``.tersoff`` files.

The potential (Tersoff 1988; seed 003, eqs. after (12)):

    E = 1/2 sum_i sum_j!=i f_C(r_ij) [f_R(r_ij) + b_ij f_A(r_ij)],
    f_R = A exp(-lambda1 r),  f_A = -B exp(-lambda2 r),
    b_ij = (1 + beta^n zeta_ij^n)^(-1/(2n)),
    zeta_ij = sum_k!=i,j f_C(r_ik) g(theta_ijk) exp(lambda3^m (r_ij - r_ik)^m),
    g = gamma (1 + c^2/d^2 - c^2 / (d^2 + (cos theta - cos theta0)^2)),
    f_C = 1/2 (1 - sin(pi/2 (r - R)/D)) for |r - R| < D, 1 inside, 0 outside.

A file entry is ``element1 element2 element3`` followed by the 14 numbers in
:data:`COLUMNS` order (LAMMPS doc of pair_style tersoff); an entry may run over
several lines and ``#`` starts a comment, as LAMMPS reads them.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opalflow.resources import DATA
from opalflow.spec import SpecError, check_name
from opalflow.store import write_text_atomic

POTENTIALS = DATA / "potentials"
REFERENCE_POTENTIAL = POTENTIALS / "Si_zhuravlev2021.tersoff"
COLUMNS = ("m", "gamma", "lambda3", "c", "d", "costheta0", "n", "beta", "lambda2", "B", "R", "D",
           "lambda1", "A")
POSITIVE = ("gamma", "c", "d", "n", "beta", "lambda2", "B", "R", "D", "lambda1", "A")


@dataclass(frozen=True)
class TersoffParameters:
    """One single-element Tersoff entry, fields in LAMMPS column order (metal units: eV, Angstrom)."""

    m: float
    gamma: float
    lambda3: float
    c: float
    d: float
    costheta0: float
    n: float
    beta: float
    lambda2: float
    B: float
    R: float
    D: float
    lambda1: float
    A: float
    element: str = "Si"

    def values(self) -> np.ndarray:
        """The 14 numbers in :data:`COLUMNS` order."""
        return np.array([getattr(self, k) for k in COLUMNS], dtype=float)

    @classmethod
    def from_values(cls, values, element: str = "Si") -> "TersoffParameters":
        return cls(*(float(v) for v in values), element=element)

    def replace(self, **changes) -> "TersoffParameters":
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in COLUMNS}

    def cutoff(self) -> float:
        """Outer cutoff R + D (Angstrom)."""
        return self.R + self.D

    def validate(self, where: str = "tersoff") -> "TersoffParameters":
        """Raise SpecError on a set LAMMPS would refuse or that has no physical meaning.

        LAMMPS requires m in {1, 3} and positive c, d, n, beta, lambda2, B, R, D (pair_tersoff.cpp);
        gamma, lambda1 and A must be positive for a repulsive core and a non-negative angular term.
        cos(theta0) outside [-1, 1] is allowed (some published sets have it) but warned about.
        """
        check_name(f"{where}.element", self.element)
        for k in COLUMNS:
            v = getattr(self, k)
            if isinstance(v, bool) or not math.isfinite(v):
                raise SpecError(f"{where}.{k}", v, "must be a finite number")
        if self.m not in (1.0, 3.0):
            raise SpecError(f"{where}.m", self.m, "must be 1 or 3 (LAMMPS pair_style tersoff)")
        for k in POSITIVE:
            if getattr(self, k) <= 0:
                raise SpecError(f"{where}.{k}", getattr(self, k), "must be > 0")
        if self.D >= self.R:
            raise SpecError(f"{where}.D", self.D, f"must be < R = {self.R:g} (cutoff region R +- D)")
        if not -1.0 <= self.costheta0 <= 1.0:
            warnings.warn(f"{where}.costheta0 = {self.costheta0:g} lies outside [-1, 1]: "
                          "the angular term has no minimum at a real angle", stacklevel=2)
        return self


def _entries(text: str) -> list[list[str]]:
    """Word lists of 17 (3 elements + 14 numbers) per entry, comments removed, lines joined."""
    words = []
    for line in text.splitlines():
        words += line.split("#", 1)[0].split()
    if len(words) % 17:
        raise ValueError(f"{len(words)} words: a Tersoff file holds entries of 17 words "
                         "(3 elements, 14 numbers)")
    return [words[i:i + 17] for i in range(0, len(words), 17)]


def read_tersoff(path: str | Path, element: str = "Si") -> TersoffParameters:
    """The ``element element element`` entry of a LAMMPS ``.tersoff`` file (validated)."""
    path = Path(path)
    where = f"tersoff file {path}"
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SpecError("tersoff.potential", str(path), "file not found") from None
    try:
        entries = _entries(text)
    except ValueError as exc:
        raise SpecError("tersoff.potential", str(path), str(exc)) from None
    found = [e for e in entries if e[:3] == [element] * 3]
    if not found:
        have = sorted({" ".join(e[:3]) for e in entries})
        raise SpecError("tersoff.element", element, f"no '{element} {element} {element}' entry in {path} "
                        f"(entries: {', '.join(have) or 'none'})")
    try:
        values = [float(w) for w in found[-1][3:]]   # LAMMPS keeps the last of duplicate entries
    except ValueError as exc:
        raise SpecError("tersoff.potential", str(path), f"entry {element}: {exc}") from None
    return TersoffParameters.from_values(values, element).validate(where)


def format_tersoff(p: TersoffParameters, comment: str = "") -> str:
    """File text of one entry; numbers in their shortest exact form, so the file reads back bit for bit."""
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    head += "# " + " ".join(("element1", "element2", "element3") + COLUMNS) + "\n"
    e = p.element
    nums = " ".join(repr(float(v)) for v in p.values())
    return f"{head}{e} {e} {e} {nums}\n"


def write_tersoff(path: str | Path, p: TersoffParameters, comment: str = "") -> Path:
    """Write one entry atomically (temporary name, then rename)."""
    p.validate()
    write_text_atomic(path, format_tersoff(p, comment))
    return Path(path)


def potential_path(name: str) -> Path:
    """A path to a ``.tersoff`` file, or the name of one in data/potentials/."""
    path = Path(name)
    if path.is_file():
        return path
    if (POTENTIALS / name).is_file():
        return POTENTIALS / name
    have = ", ".join(sorted(p.name for p in POTENTIALS.glob("*.tersoff")))
    raise SpecError("tersoff.potential", name, f"no such file, nor a potential in data/potentials ({have})")


def load_parameters(potential: str, element: str) -> TersoffParameters:
    """The ``element`` entry of a potential given by path or by name in data/potentials/."""
    return read_tersoff(potential_path(potential), element)


@dataclass(frozen=True)
class Properties:
    """Table 1's properties of a parameter set: a0 (A), E_c (eV), B, C', C11, C12, C44^0 and C44 (GPa)."""

    a0_A: float
    Ec_eV: float
    B_GPa: float
    Cprime_GPa: float
    C11_GPa: float
    C12_GPa: float
    C44_0_GPa: float
    C44_GPa: float

    def of(self, name: str) -> float:
        """The property named ``name`` (a Table 1 key)."""
        return getattr(self, name)
