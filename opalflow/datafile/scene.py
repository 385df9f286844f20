"""A user's data file (``atom_style`` bpm/sphere, sphere, or hybrid with one of them) as a scene.

``datafile.materials`` names each atom type in type order (empty: every type is the workflow's
``material``): the matrix material, at most one other (a coating; bonds are typed by material as the
opal's are: the other material's type wherever one of its particles takes part) and ``substrate``.
``datafile.substrate`` chooses the fixed particles explicitly ("type N", "z < Z", "none": the bottom particle
layer glued to the fixed base); they become the atom type ``substrate``.  Lengths are scaled to nm
(``units = "lj"`` with ``length_unit_nm``); densities come from the file, checked against the material,
or from the material (``datafile.density``).  What was read and chosen is said in ``meta["source"]``, which
the report prints.
"""
from __future__ import annotations

import numpy as np

from opalflow.bpm.bonds import bond_types_by_material
from opalflow.bpm.deck import particle_material
from opalflow.bpm.scene import Scene
from opalflow.datafile.spec import SUBSTRATE, DatafileWorkflow
from opalflow.lammps.datafile import read_data
from opalflow.materials import material
from opalflow.spec import SpecError
from opalflow.structure import Structure

#: nano units: attogram / nm^3 in kg / m^3
KG_M3_PER_AG_NM3 = 1e6
#: a file density further than this factor from the material's is refused (datafile.density = "material")
DENSITY_FACTOR = 2.0


def _substrate(spec: DatafileWorkflow, s: Structure, names: list[str]) -> np.ndarray:
    """The fixed particles that ``datafile.substrate`` selects (file units already scaled to nm)."""
    d = spec.datafile
    m = SUBSTRATE.match(d.substrate)
    if d.substrate == "":
        mask = np.isin(s.types, [k + 1 for k, n in enumerate(names) if n == "substrate"])
        if not mask.any():
            raise SpecError("datafile.substrate", d.substrate, "no atom type is named \"substrate\" in "
                            "datafile.materials: choose the fixed particles (\"type N\", \"z < Z\" or \"none\" to glue "
                            "the bottom layer)")
    elif m.group("type"):
        t = int(m.group("type"))
        mask = s.types == t
        if not mask.any():
            raise SpecError("datafile.substrate", d.substrate, f"{d.path} has no atom of type {t}")
    elif m.group("z"):
        mask = s.positions[:, 2] < float(m.group("z")) * d.length_scale()
    else:                        # "none": the bottom layer (centres within 3/4 of a mean diameter) is glued
        mask = s.positions[:, 2] < s.positions[:, 2].min() + 0.75 * float(np.mean(s.diameters))
    if not mask.any() or mask.all():
        raise SpecError("datafile.substrate", d.substrate, f"selects {int(mask.sum())} of {s.n_particles} particles: "
                        "the substrate must be some but not all of them")
    return mask


def read_scene(spec: DatafileWorkflow, progress=None) -> Structure:
    d = spec.datafile
    s = read_data(d.path, periodic=(d.periodic_sides, d.periodic_sides, False), atom_style=d.atom_style)
    if s.n_bonds == 0:
        raise SpecError("datafile.path", d.path, "has no bonds: a bonded-particle scene needs a Bonds section")
    n_types = int(s.types.max())
    names = list(d.materials) or [spec.material] * n_types
    if len(names) != n_types:
        raise SpecError("datafile.materials", d.materials, f"must name all {n_types} atom types of {d.path}")
    scale = d.length_scale()
    s.positions, s.diameters = s.positions * scale, s.diameters * scale
    s.box_lo, s.box_hi = s.box_lo * scale, s.box_hi * scale
    fixed = _substrate(spec, s, names)
    # the file's types, then "substrate" for the fixed particles (types left without particles dropped)
    kept = sorted({names[t - 1] for t in np.unique(s.types[~fixed])} - {"substrate"}, key=names.index)
    if spec.material not in kept:
        raise SpecError("datafile.materials", d.materials, f"no free particle is of the workflow's material "
                        f"{spec.material!r}")
    type_names = kept + ["substrate"]
    per_file_type = np.array([type_names.index(n) + 1 if n in kept else len(type_names) for n in names], np.int32)
    s.types = np.where(fixed, len(type_names), per_file_type[s.types - 1]).astype(np.int32)
    s.type_names = type_names
    s.groups["substrate"] = fixed
    others = [m for m in kept if m != spec.material]
    if len(others) > 1:
        raise SpecError("datafile.materials", d.materials, "at most one material besides the matrix")
    source = d.density_source()
    want = np.array([material(particle_material(n, spec.material), spec.materials).density_kg_m3
                     for n in type_names])
    if source == "material":
        s.densities = want[s.types - 1] / KG_M3_PER_AG_NM3
    else:
        for t, n in enumerate(type_names, 1):
            got = float(np.median(s.densities[s.types == t])) * KG_M3_PER_AG_NM3
            if not want[t - 1] / DENSITY_FACTOR <= got <= want[t - 1] * DENSITY_FACTOR:
                raise SpecError("datafile.density", d.density, f"the file's densities of type {n} ({got:.4g} kg/m^3 in "
                                f"nano units) are not within {DENSITY_FACTOR:g}x of {n}'s {want[t - 1]:g} kg/m^3: use "
                                "\"material\" to take the material's")
    coat = np.isin(s.types, [type_names.index(m) + 1 for m in others])
    s.bond_types = bond_types_by_material(s.bonds, coat)
    s.bond_type_names = [spec.material] + others
    s.meta["solid_fraction"] = float(np.sum(s.particle_volumes()) / np.prod(s.box_lengths))
    s.meta["source"] = (f"{d.path} (atom style {d.atom_style}, units {d.units}"
                        + (f", 1 length unit = {scale:g} nm" if d.units != "nano" else "")
                        + f"; densities from the {'file' if source == 'file' else 'materials'}); substrate: "
                        + (d.substrate or "types named substrate") + f" ({int(fixed.sum())} particles); bonds: the "
                        f"file's {s.n_bonds}, typed by material ({', '.join(s.bond_type_names)})")
    return s


SCENE = Scene(build=read_scene, cached=False, ordered=False)     # reading the file is the build; its ids kept
