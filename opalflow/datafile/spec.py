"""Spec of the data-file scene: the ``[datafile]`` section."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from opalflow.bpm.spec import BpmWorkflow, check_material
from opalflow.lammps.datafile import atom_fields
from opalflow.spec import InputError, SpecError, check, is_number

#: ``datafile.substrate``: the fixed particles
SUBSTRATE = re.compile(r"^(?:|none|type (?P<type>[0-9]+)|z < (?P<z>[-+0-9.eE]+))$")
UNITS = ("nano", "lj")
DENSITIES = ("auto", "file", "material")


@dataclass
class DatafileSpec:
    """A user's data file (kind = "datafile").

    path: the file; atom_style: its style, as LAMMPS's ``atom_style`` before ``read_data`` ("bpm/sphere",
    "sphere", or "hybrid SUB ..." with bpm/sphere or sphere among the sub-styles); units: "nano" (nm) or "lj"
    with length_unit_nm, what one length unit of the file is in nm; materials: the material of each atom type
    in type order (empty: all the workflow's ``material``); substrate: the fixed particles, "type N", "z < Z"
    (centres below Z in the file's length unit), "none" (the bottom particle layer is glued to the fixed
    base) or "" (the atom types that ``materials`` names "substrate"); density: "file" (the file's column,
    checked against the material), "material" (the material's), "auto" (file for nano, material for lj,
    whose densities have no unit).
    """

    path: str = ""                   # the LAMMPS data file
    atom_style: str = "bpm/sphere"   # its atom style, as LAMMPS's atom_style before read_data
    units: str = "nano"              # nano (lengths in nm) or lj (length_unit_nm says what one unit is)
    length_unit_nm: float = 0.0      # lj: one length unit of the file in nm
    #: the material of each atom type, in type order (empty: the workflow's material)
    materials: list[str] = field(default_factory=list)
    #: the fixed particles: "type N", "z < Z", "none" or "" (the types materials names substrate)
    substrate: str = ""
    density: str = "auto"            # file, material, or auto (file for nano, material for lj)
    periodic_sides: bool = True      # x and y periodic (as the file's box), else open sides

    def density_source(self) -> str:
        return ("file" if self.units == "nano" else "material") if self.density == "auto" else self.density

    def length_scale(self) -> float:
        """nm per length unit of the file."""
        return 1.0 if self.units == "nano" else self.length_unit_nm


@dataclass
class DatafileWorkflow(BpmWorkflow):
    """A user's data file (kind = "datafile") compressed by a plate."""

    datafile: DatafileSpec = field(default_factory=DatafileSpec)

    def validate(self) -> None:
        super().validate()
        d = self.datafile
        check(bool(d.path) and Path(d.path).is_file(), "datafile.path", d.path, "must name an existing file")
        try:
            atom_fields(d.atom_style)
        except InputError as exc:
            raise SpecError("datafile.atom_style", d.atom_style, str(exc).split(": ", 1)[1]) from None
        check(d.units in UNITS, "datafile.units", d.units, f"must be one of {', '.join(UNITS)}")
        check(is_number(d.length_unit_nm) and 0 <= d.length_unit_nm <= 1e7, "datafile.length_unit_nm",
              d.length_unit_nm, "must be in [0, 1e7] nm")
        check(d.units != "lj" or d.length_unit_nm > 0, "datafile.length_unit_nm", d.length_unit_nm,
              "must be > 0 with units = \"lj\": what one length unit of the file is in nm")
        check(d.density in DENSITIES, "datafile.density", d.density, f"must be one of {', '.join(DENSITIES)}")
        check(not (d.units == "lj" and d.density == "file"), "datafile.density", d.density,
              "lj densities have no unit: use \"material\" (or \"auto\")")
        m = SUBSTRATE.match(d.substrate)
        check(m is not None and (m.group("z") is None or is_number(_float(m.group("z")))), "datafile.substrate",
              d.substrate, "must be \"type N\", \"z < Z\" (file length units), \"none\" (glue the bottom layer) or \"\" "
              "(the types that datafile.materials names \"substrate\")")
        for i, mname in enumerate(d.materials):
            check_material(f"datafile.materials[{i}]", mname, also=("substrate",))


def _float(text: str):
    try:
        return float(text)
    except ValueError:
        return None
