"""An aerogel's result: every bonded-particle method's keys (:class:`opalflow.bpm.result.CompressionResult`) and
the numbers of its network that each run summary carries (the density study fits against them)."""
from __future__ import annotations

from dataclasses import dataclass

from opalflow.bpm.result import EVERY_CASE, LOADED, CompressionResult
from opalflow.runs.result import key


@dataclass(eq=False)
class AerogelResult(CompressionResult):
    """An aerogel run's result; the network's numbers as :func:`opalflow.aerogel.scene.statistics` defines them."""

    solid_fraction: float = key(*LOADED)                            # the aggregate's, over the method's
    density_kg_m3: float | None = key(*EVERY_CASE, optional=True)          # the slab's mass over the aggregate's cube
    mean_coordination: float | None = key(*EVERY_CASE, optional=True)      # bonds per sphere, x 2
    loops_per_10k: float | None = key(*EVERY_CASE, optional=True)          # independent loops per 10 000 spheres
    dropped_unattached: int | None = key(*EVERY_CASE, optional=True)       # spheres with no bond path to the bottom
