"""The scene interface: what a bonded-particle scene gives the compression pipeline, and the structure
cache that spares a rerun the build."""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from opalflow import registry
from opalflow.store import atomic_path
from opalflow.structure import Structure

#: sections of a workflow that no scene's build reads (the deck's and the run's): a new value reuses the
#: cached structure
NOT_BUILT_FROM = ("name", "description", "compression", "contacts")
#: the cache's size bound (GiB): the least recently used structures go first
CACHE_MAX_GIB = float(os.environ.get("OPALFLOW_CACHE_MAX_GIB", "4"))
#: a built structure of this many particles or more is put in cell order (:meth:`Scene.structure`): the bond
#: operator's product over the paper's sample (1.6 M particles, 17.5 M bonds) 260 -> 173 ms on two threads
#: (bench/results/paper_scale.json ``kernels``; 522 -> 277 ms in a probe with another run beside it); smaller ones
#: keep the builder's order, their particles' arrays (48 bytes a particle) within this CPU's 4 MiB L2 cache
ORDER_MIN_PARTICLES = 80_000


@dataclass(frozen=True)
class Scene:
    """What a bonded-particle scene gives the pipeline.

    build : ``build(spec, progress) -> Structure`` with ``type_names`` (``substrate`` = fixed),
        ``bond_type_names`` by material and ``groups["substrate"]``.
    statistics : ``statistics(structure)`` -> a dataclass of numbers about the structure, the build summary's keys
        (``n_particles`` and ``n_bonds`` when not given; :func:`opalflow.runs.result.table_of` makes the table).
    run_keys : its fields that every run summary carries as well.
    describe : one line about the structure from its statistics, said by ``build``.
    cached : whether :meth:`structure` keeps what ``build`` made (not for a scene that only reads a file).
    ordered : whether :meth:`structure` puts the particles of a large build in cell order (not for a scene that
        reads the user's file: its particles keep their ids).
    """

    build: Callable[..., Structure]
    statistics: Callable[[Structure], Any] | None = None
    run_keys: tuple[str, ...] = ()
    describe: Callable[[Any], str] | None = None
    cached: bool = True
    ordered: bool = True

    def statistics_of(self, s: Structure):
        """``statistics(s)``, kept in ``s.meta`` with the cached structure (a neighbour search and the slab
        counts: 0.3 s of a one-second static run at d = 60 nm that a rerun from the cache no longer pays); None for
        a scene without statistics."""
        if self.statistics is None:
            return None
        if "statistics" not in s.meta:
            s.meta["statistics"] = self.statistics(s)
        return s.meta["statistics"]

    def structure(self, spec, progress=None) -> Structure:
        """``build(spec, progress)``, or the structure it made before for the same build inputs (the spec
        without NOT_BUILT_FROM, and opalflow's source: a changed generator never reuses an old structure),
        from the cache folder (``$OPALFLOW_CACHE``, default ``~/.cache/opalflow``; ``OPALFLOW_CACHE=off``:
        none).  A rerun with a new compression setting, or a study's second method on the same sample,
        does not rebuild the packing."""
        folder = cache_folder()
        if not self.cached or folder is None:
            return self._built(spec, progress)
        path = folder / f"{build_key(spec)}.pkl"
        try:
            with open(path, "rb") as f:
                s = pickle.load(f)
            os.utime(path)                       # recently used
            s.meta["cache"] = str(path)          # (this process's: where the structure came from)
            if progress:
                progress(f"structure: {s.n_particles} particles, {s.n_bonds} bonds from the cache ({path}; "
                         f"built in {s.meta.get('build_s', 0.0):.1f} s); OPALFLOW_CACHE=off rebuilds")
            return s
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ValueError):
            pass
        t = time.perf_counter()
        s = self._built(spec, progress)
        s.meta["build_s"] = time.perf_counter() - t
        self.statistics_of(s)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(path, f"{path.name}.{os.getpid()}.tmp") as tmp, open(tmp, "wb") as f:
                pickle.dump(s, f, protocol=pickle.HIGHEST_PROTOCOL)
            _evict(folder)
        except OSError:         # a read-only or full disk costs the next run a build, nothing else
            pass
        return s


    def _built(self, spec, progress) -> Structure:
        """``build(spec, progress)``, its particles in cell order (:meth:`opalflow.structure.Structure.cell_order`,
        cells of two mean diameters) from :data:`ORDER_MIN_PARTICLES` where the scene is ``ordered``."""
        s = self.build(spec, progress)
        if self.ordered and s.n_particles >= ORDER_MIN_PARTICLES:
            s = s.reordered(s.cell_order(2.0 * float(np.mean(s.diameters))))
        return s


def cache_folder() -> Path | None:
    where = os.environ.get("OPALFLOW_CACHE", "")
    if where.lower() in ("off", "0", "no", "none"):
        return None
    if where:
        return Path(where)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "opalflow" / "structures"


@lru_cache(maxsize=1)
def _source_hash() -> str:
    """A hash of opalflow's Python source and data (materials): what a structure is built by."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")) + sorted((root.parent / "data").glob("*.toml")):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def build_key(spec) -> str:
    """The cache key of ``spec``'s structure: its build inputs and opalflow's source."""
    inputs = {k: v for k, v in spec.to_dict().items() if k not in NOT_BUILT_FROM}
    text = json.dumps(inputs, sort_keys=True, default=str) + _source_hash()
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _evict(folder: Path) -> None:
    """Remove the least recently used structures beyond CACHE_MAX_GIB."""
    files = sorted(folder.glob("*.pkl"), key=lambda p: p.stat().st_mtime, reverse=True)
    total = 0
    for p in files:
        total += p.stat().st_size
        if total > CACHE_MAX_GIB * 2**30:
            p.unlink(missing_ok=True)


def scene_of(spec) -> Scene:
    """The scene registered for the spec's kind."""
    return registry.resolve(registry.get(spec.kind).scene)


def solid_fraction(s: Structure) -> float:
    """The packing's solid fraction (before pores), 1 where the scene does not say."""
    return float(s.meta.get("packing_solid_fraction", s.meta.get("solid_fraction", 1.0)))
