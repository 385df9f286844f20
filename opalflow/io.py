"""Readers of a run folder for the tools users script with: results, ASE, MDAnalysis.

- :func:`load_results`: ``summary.json`` and every dataset of ``results.h5`` with its units and columns;
- :func:`read_ase`: an :class:`ase.Atoms` of the structure (``data.lmp``) or of a snapshot;
- :func:`read_mdanalysis`: an MDAnalysis Universe with the bonds and every snapshot as a frame.

ASE and MDAnalysis measure length in Angstrom: positions, cell and radii are converted from the nm of
LAMMPS ``units nano`` (x 10), masses from attograms to atomic mass units.  ASE cannot read
``atom_style bpm/sphere`` data files itself (``Style "bpm/sphere" not supported``); MDAnalysis can when
told the columns: ``mda.Universe("data.lmp", format="DATA", atom_style="id resid type diameter density
x y z")`` (lengths then stay in nm).  OVITO opens ``data.lmp`` (with bonds) and the dumps as they are.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from opalflow.analysis import compression as mech
from opalflow.lammps.datafile import read_data
from opalflow import registry
from opalflow.runs.record import RunRecord
from opalflow.runs.result import Result
from opalflow.spec import SpecError
from opalflow.store import RESULTS, SUMMARY, read_json
from opalflow.structure import Structure

ANGSTROM_PER_NM = 10.0
AMU_PER_AG = 1e-21 / 1.66053906660e-27     # attogram in unified atomic mass units (CODATA 2018)


@dataclass
class Results:
    """What a run wrote: ``summary`` (summary.json), ``data`` (every dataset of results.h5 by its path)
    and ``attrs`` (the attributes of each dataset and group by path: ``units``, ``columns``, ...).
    :attr:`result`: the summary as the run's kind's result class (``res.result.youngs_modulus_GPa``)."""

    folder: Path
    summary: dict
    data: dict[str, np.ndarray] = field(default_factory=dict)
    attrs: dict[str, dict] = field(default_factory=dict)

    @property
    def result(self) -> Result:
        """The summary read back as its kind's result class (:attr:`opalflow.registry.Kind.result`; the generic
        :class:`opalflow.runs.result.Result` where the folder has no readable run record)."""
        record = RunRecord.read_or_none(self.folder)
        kind = registry.get(record.kind).result_class() if record is not None else Result
        return kind.from_summary(self.summary)

    def __getitem__(self, path: str):
        """A dataset of results.h5 by its path (``"curve/stress_MPa"``), else a key of summary.json
        (``"youngs_modulus_GPa"``)."""
        if path in self.data:
            return self.data[path]
        if path in self.summary:
            return self.summary[path]
        raise KeyError(f"{path!r} is neither a dataset of {RESULTS} nor a key of {SUMMARY} (datasets: "
                       f"{', '.join(sorted({k.split('/')[0] + '/...' for k in self.data})) or 'none'})")

    def __contains__(self, path: str) -> bool:
        return path in self.data or path in self.summary

    def snapshot_steps(self) -> list[int]:
        """The steps of the snapshots (``snapshots/STEP/...``), in order."""
        return sorted({int(k.split("/")[1]) for k in self.data if k.startswith("snapshots/") and
                       k.split("/")[1].isdigit()})

    def keys(self) -> list[str]:
        return list(self.data)

    def units(self, path: str) -> str:
        """The unit of a dataset ("1": a count or a ratio)."""
        return self.attrs[path]["units"]

    def columns(self, path: str) -> list[str] | None:
        """The names of a table's columns, None for a dataset that is not a table."""
        cols = self.attrs[path].get("columns")
        return None if cols is None else [str(c) for c in cols]

    def table(self, path: str) -> dict[str, np.ndarray]:
        """A table as {column name: column}."""
        cols = self.columns(path)
        if cols is None:
            raise KeyError(f"{path} is not a table (no columns attribute)")
        return {c: self.data[path][:, k] for k, c in enumerate(cols)}


def _attr(value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.dtype.kind in "OS":
        return [v.decode() if isinstance(v, bytes) else v for v in value]
    return value.item() if isinstance(value, np.generic) else value


def load_results(folder: str | Path) -> Results:
    """The results of a finished run folder (any kind): summary.json and results.h5 (where there is one)."""
    folder = Path(folder)
    path = folder / SUMMARY
    if not path.exists():
        raise SpecError("folder", str(folder), f"has no {SUMMARY}: not a finished run folder")
    res = Results(folder, read_json(path, "the run's summary", "run `python -m opalflow analyze` on the folder "
                                    "to write it again"))
    if (folder / RESULTS).exists():
        import h5py

        def visit(name, obj):
            res.attrs[name] = {k: _attr(v) for k, v in obj.attrs.items()}
            if isinstance(obj, h5py.Dataset):
                res.data[name] = obj[()]

        with h5py.File(folder / RESULTS, "r") as h:
            res.attrs[""] = {k: _attr(v) for k, v in h.attrs.items()}
            h.visititems(visit)
    return res


def _structure(folder: Path) -> Structure:
    """The folder's data file, its sides periodic as the run's deck facts say (no record: x and y periodic)."""
    deck = RunRecord.read(folder).deck if RunRecord.exists(folder) else {}
    data = next((p for p in (folder / "data.lmp", folder / "aggregate.lmp") if p.exists()), None)
    if data is None:
        raise SpecError("folder", str(folder), "has no data.lmp: not a bonded-particle run folder")
    return read_data(data, periodic=tuple(deck.get("periodic", (True, True, False))))


def _snapshot(folder: Path, step: int | None, s: Structure, files: dict[int, Path]) -> tuple[dict | None, int | None]:
    """The particle dump at ``step`` (None: the structure as built) of ``files`` (by step) sorted by id, and its step."""
    if step is None:
        return None, None
    if step == -1 and files:
        step = max(files)
    if step not in files:
        raise SpecError("step", step, f"no snapshot at that step in {folder}/snapshots; there are "
                        f"{', '.join(map(str, files)) or 'none'} (-1: the last)")
    dump = mech.read_dump_custom(files[step])
    order = np.argsort(dump["id"])
    dump = {k: v[order] for k, v in dump.items()}
    if len(dump["id"]) != s.n_particles:
        raise SpecError("step", step, f"the snapshot has {len(dump['id'])} particles, the data file {s.n_particles}")
    return dump, step


def read_ase(folder: str | Path, step: int | None = None):
    """An :class:`ase.Atoms` of a run folder: the structure of ``data.lmp`` (``step`` None) or the snapshot
    ``snapshots/particles.STEP.dump`` (``step = -1``: the last).

    Positions and cell in Angstrom, ``pbc`` as the deck's boundary; per-atom arrays ``radius`` (Angstrom),
    ``type`` (LAMMPS atom type; ``info["type_names"]`` names them) and, for a snapshot, ``sigma_MPa``
    (xx yy zz xy xz yz) and ``broken_bonds``; masses in amu.  Bonds (those of data.lmp, as built) as ASE's
    LAMMPS reader stores them, ``arrays["bonds"]`` ("j(type),k(type)" per first atom), and as numbers:
    ``info["bonds"]`` (M, 2) 0-based indices, ``info["bond_types"]`` (M,).
    """
    from ase import Atoms

    folder = Path(folder)
    s = _structure(folder)
    dump, step = _snapshot(folder, step, s, mech.snapshot_files(folder, "particles", "dump"))
    positions = s.positions if dump is None else np.column_stack([dump["x"], dump["y"], dump["z"]])
    atoms = Atoms(positions=(positions - s.box_lo) * ANGSTROM_PER_NM, cell=np.diag(s.box_lengths * ANGSTROM_PER_NM),
                  pbc=s.periodic, masses=s.densities * s.particle_volumes() * AMU_PER_AG)
    atoms.set_array("radius", s.diameters / 2 * ANGSTROM_PER_NM)
    atoms.set_array("type", s.types.astype(int))
    first = [""] * s.n_particles
    for (i, j), t in zip(s.bonds, s.bond_types):
        first[i] += ("," if first[i] else "") + f"{j}({t})"
    atoms.set_array("bonds", np.array(first, dtype=object))
    atoms.info.update({"bonds": s.bonds.copy(), "bond_types": s.bond_types.copy(), "type_names": s.type_names,
                       "origin_nm": s.box_lo.tolist(), "step": step})
    if dump is not None:
        atoms.set_array("sigma_MPa", np.column_stack([dump[f"sigma_{c}"] for c in mech.STRESS_COLUMNS]))
        atoms.set_array("broken_bonds", dump["broken_bonds"].astype(int))
    return atoms


def read_mdanalysis(folder: str | Path):
    """An MDAnalysis Universe of a run folder: atoms (types, radii and masses), the bonds of ``data.lmp``,
    and one frame per snapshot dump (the structure as built when there is none), positions and box in
    Angstrom (``u.trajectory[k]``; ``u.trajectory.steps`` gives the LAMMPS step of each frame)."""
    import MDAnalysis as mda
    from MDAnalysis.coordinates.memory import MemoryReader

    folder = Path(folder)
    s = _structure(folder)
    files = mech.snapshot_files(folder, "particles", "dump")
    frames, steps = [], []
    for step in files:
        dump, _ = _snapshot(folder, step, s, files)
        frames.append(np.column_stack([dump["x"], dump["y"], dump["z"]]))
        steps.append(step)
    if not frames:
        frames, steps = [s.positions], [0]
    u = mda.Universe.empty(s.n_particles, trajectory=False)
    u.add_TopologyAttr("types", [str(t) for t in s.types])
    u.add_TopologyAttr("radii", s.diameters / 2 * ANGSTROM_PER_NM)
    u.add_TopologyAttr("masses", s.densities * s.particle_volumes() * AMU_PER_AG)
    u.add_bonds([tuple(b) for b in s.bonds.tolist()], types=[str(t) for t in s.bond_types])
    coords = ((np.array(frames) - s.box_lo) * ANGSTROM_PER_NM).astype(np.float32)
    box = np.array([*(s.box_lengths * ANGSTROM_PER_NM), 90.0, 90.0, 90.0])
    u.load_new(coords, format=MemoryReader, dimensions=np.tile(box, (len(frames), 1)))
    u.trajectory.steps = steps
    return u
