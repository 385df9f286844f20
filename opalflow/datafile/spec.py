"""Spec of the data-file scene: the ``[datafile]`` section."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from opalflow.bpm.spec import BpmWorkflow, check_material
from opalflow.spec import check


@dataclass
class DatafileSpec:
    """A user's bpm/sphere data file (kind = "datafile"); materials name its atom types in order."""

    path: str = ""
    materials: list[str] = field(default_factory=list)
    periodic_sides: bool = True


@dataclass
class DatafileWorkflow(BpmWorkflow):
    """A user's data file (kind = "datafile") compressed by a plate."""

    datafile: DatafileSpec = field(default_factory=DatafileSpec)

    def validate(self) -> None:
        super().validate()
        d = self.datafile
        check(bool(d.path) and Path(d.path).is_file(), "datafile.path", d.path, "must name an existing file")
        check(len(d.materials) >= 1, "datafile.materials", d.materials,
              "must name the material of each atom type, in type order ('substrate' = fixed)")
        for i, mname in enumerate(d.materials):
            check_material(f"datafile.materials[{i}]", mname, also=("substrate",))
