"""The only ways values enter LAMMPS text: checked numbers, checked names, and template blocks filled with them."""
from __future__ import annotations

import math
import numbers
import re
import string

from opalflow.resources import TEMPLATES, resource

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


def render(block: str, **values) -> str:
    """Fill ``templates/<block>.lmp``; every placeholder must be given."""
    text = resource(TEMPLATES, f"{block}.lmp").read_text()
    return string.Template(text).substitute(values)
