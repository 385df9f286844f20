"""The only ways values enter LAMMPS text: checked numbers and checked names."""
from __future__ import annotations

import math
import numbers
import re

_NAME = re.compile(r"[A-Za-z0-9_]+")


def num(value) -> str:
    """A finite real number as LAMMPS text (shortest repr that round-trips)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ValueError(f"expected a finite number for LAMMPS, got {value!r}")
    if isinstance(value, numbers.Integral):
        return str(int(value))
    return repr(float(value))


def name(value: str) -> str:
    """An identifier as LAMMPS text; only [A-Za-z0-9_]+ passes."""
    if not isinstance(value, str) or not _NAME.fullmatch(value):
        raise ValueError(f"expected a name of [A-Za-z0-9_]+ for LAMMPS, got {value!r}")
    return value
