"""The scene interface: what a bonded-particle scene gives the compression pipeline."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from opalflow import registry
from opalflow.structure import Structure


@dataclass(frozen=True)
class Scene:
    """What a bonded-particle scene gives the pipeline.

    build : ``build(spec, progress) -> Structure`` with ``type_names`` (``substrate`` = fixed),
        ``bond_type_names`` by material and ``groups["substrate"]``.
    statistics : ``statistics(structure) -> dict`` of numbers about the structure for the build
        summary (``n_particles`` and ``n_bonds`` when not given).
    run_keys : the keys of ``statistics`` that every run summary carries as well.
    describe : one line about the structure from its statistics, said by ``build``.
    """

    build: Callable[..., Structure]
    statistics: Callable[[Structure], dict] | None = None
    run_keys: tuple[str, ...] = ()
    describe: Callable[[dict], str] | None = None


def scene_of(spec) -> Scene:
    """The scene registered for the spec's kind."""
    return registry.resolve(registry.get(spec.kind).scene)


def solid_fraction(s: Structure) -> float:
    """The packing's solid fraction (before pores), 1 where the scene does not say."""
    return float(s.meta.get("packing_solid_fraction", s.meta.get("solid_fraction", 1.0)))
