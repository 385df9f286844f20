"""An inverse opal's result: every bonded-particle method's keys (:class:`opalflow.bpm.result.CompressionResult`)
and the numbers of its structure that each run summary carries (the porosity studies fit against them)."""
from __future__ import annotations

from dataclasses import dataclass

from opalflow.bpm.result import EVERY_CASE, CompressionResult
from opalflow.runs.result import key


@dataclass(eq=False)
class OpalResult(CompressionResult):
    """An opal run's result; the structure's numbers as :func:`opalflow.opal.scene.structure_statistics` defines
    them (Dosta et al. sections 2.1 and 4)."""

    porosity: float | None = key(*EVERY_CASE, optional=True)          # macro-porosity: 1 - particles kept / packed
    total_porosity: float | None = key(*EVERY_CASE, optional=True)    # the packing's own voids counted too
    density_kg_m3: float | None = key(*EVERY_CASE, optional=True)     # each particle's solid, V_p / phi
