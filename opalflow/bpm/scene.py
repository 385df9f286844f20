"""The scene interface: what a bonded-particle scene gives the compression pipeline."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
