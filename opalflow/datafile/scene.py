"""A user's ``atom_style bpm/sphere`` data file as a scene.

``datafile.materials`` names each atom type in type order: the matrix material
(``material``), ``substrate`` for the fixed particles, and at most one other material
(a coating).  Bonds are typed by material as the opal's are: the other material's type
wherever one of its particles takes part.
"""
from __future__ import annotations

import numpy as np

from opalflow.bpm.bonds import bond_types_by_material
from opalflow.bpm.scene import Scene
from opalflow.datafile.spec import DatafileWorkflow
from opalflow.lammps.datafile import read_data
from opalflow.spec import SpecError
from opalflow.structure import Structure


def read_scene(spec: DatafileWorkflow, progress=None) -> Structure:
    d = spec.datafile
    s = read_data(d.path, periodic=(d.periodic_sides, d.periodic_sides, False))
    if s.n_bonds == 0:
        raise SpecError("datafile.path", d.path, "has no bonds: a bonded-particle scene needs a Bonds section")
    n_types = int(s.types.max())
    if len(d.materials) != n_types:
        raise SpecError("datafile.materials", d.materials, f"must name all {n_types} atom types of {d.path}")
    s.type_names = list(d.materials)
    s.groups["substrate"] = np.isin(s.types, [k + 1 for k, m in enumerate(d.materials) if m == "substrate"])
    coat = np.isin(s.types, [k + 1 for k, m in enumerate(d.materials) if m not in (spec.material, "substrate")])
    others = sorted({m for m in d.materials if m not in (spec.material, "substrate")})
    if len(others) > 1:
        raise SpecError("datafile.materials", d.materials, "at most one material besides the matrix")
    s.bond_types = bond_types_by_material(s.bonds, coat)
    s.bond_type_names = [spec.material] + others
    s.meta["solid_fraction"] = float(np.sum(s.particle_volumes()) / np.prod(s.box_lengths))
    return s


SCENE = Scene(build=read_scene)
