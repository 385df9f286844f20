"""Decks: LAMMPS input scripts assembled from the blocks in ``templates/``.

A block is a text file with ``${name}`` placeholders.  Every value is passed through
:func:`opalflow.lammps.syntax.num` or :func:`~opalflow.lammps.syntax.name` (or is
one of the fixed keyword strings below), so nothing unchecked reaches LAMMPS.
A deck holds only the blocks its scene needs.
"""
from __future__ import annotations

import string

from opalflow import __version__
from opalflow.lammps.syntax import name, num
from opalflow.resources import TEMPLATES, resource
from opalflow.structure import Structure

def render(block: str, **values) -> str:
    """Fill ``templates/<block>.lmp``; every placeholder must be given."""
    text = resource(TEMPLATES, f"{block}.lmp").read_text()
    return string.Template(text).substitute(values)


def boundary_of(s: Structure) -> str:
    """LAMMPS boundary string for a structure: periodic sides or fixed, z fixed."""
    return "p p f" if s.periodic[0] and s.periodic[1] else "f f f"


def check_deck(s: Structure, title: str, data_file: str = "data.lmp") -> str:
    """in.lmp that reads the structure and runs 0 steps (``opalflow build``)."""
    header = f"# opalflow {__version__}: {name(title)} - reads the structure and runs 0 steps\n"
    return header + "\n".join([
        render("system", boundary=boundary_of(s), data_file=name_file(data_file)),
        render("check_run0", pair_cutoff=num(float(s.diameters.max()))),
    ])


def name_file(filename: str) -> str:
    """A data/restart file name: a name plus an optional extension of [A-Za-z0-9_]."""
    stem, _, ext = filename.partition(".")
    return name(stem) + (("." + name(ext)) if ext else "")
