"""The ``[executor]`` section of any workflow file (and ``--executor`` on the command line): where the runs
go.  Light (dataclass and checks only): every workflow file is read through it.

========== ============================================================================================
type       what runs the jobs
========== ============================================================================================
local      a pool of ``workers`` processes on this machine (default; 0: cores / ranks per job)
dask       a ``distributed`` cluster: ``address`` of its scheduler, or an embedded LocalCluster of
           ``workers`` processes where none is given
slurm      SLURM job arrays (``sbatch --array``): per job ``cpus_per_rank`` x ranks cores, ``mem_gb``,
           ``time_min``, ``partition``, ``account``; at most ``workers`` tasks at once (0: no limit).
           A job that reaches its time limit is signalled ``signal_s`` seconds before, writes a restart
           and is requeued to continue from it.
========== ============================================================================================
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from opalflow.spec import SpecError, check, check_name, convert

EXECUTOR_TYPES = ("local", "dask", "slurm")
ADDRESS_RE = re.compile(r"(tcp|tls|inproc|ucx)://[A-Za-z0-9_.\-\[\]:]+")


@dataclass
class ExecutorSpec:
    """Where the runs of a workflow go (see the module's table)."""

    type: str = "local"          # local (a pool on this machine), dask or slurm
    workers: int = 0             # jobs at once (local, dask: 0 = cores / ranks per job; slurm: 0 = no limit)
    address: str = ""            # dask: the scheduler's address (tcp://host:8786); "": an embedded LocalCluster
    cpus_per_rank: int = 1       # slurm: cores per MPI rank of a job (--cpus-per-task)
    mem_gb: float = 2.0          # slurm: memory per job (--mem; `plan` says what a job needs)
    #: slurm: time limit of each job (--time); a job reaching it is requeued from its restart
    time_min: int = 60
    partition: str = ""          # slurm: --partition ("": the cluster's default)
    account: str = ""            # slurm: --account ("": none)
    signal_s: int = 45           # slurm: the job is signalled this long before its limit, to write a restart (--signal)
    poll_s: float = 2.0          # slurm: seconds between looks at the queue (squeue)

    def validate(self) -> None:
        check(self.type in EXECUTOR_TYPES, "executor.type", self.type, f"must be one of {', '.join(EXECUTOR_TYPES)}")
        check(self.workers >= 0, "executor.workers", self.workers, "must be >= 0 (jobs at once; 0: as many as fit)")
        check(self.address == "" or bool(ADDRESS_RE.fullmatch(self.address)), "executor.address", self.address,
              "must be a Dask scheduler address such as 'tcp://10.0.0.5:8786' (or '' for a LocalCluster)")
        check(self.address == "" or self.type == "dask", "executor.address", self.address,
              "is for executor.type = 'dask'")
        check(1 <= self.cpus_per_rank <= 256, "executor.cpus_per_rank", self.cpus_per_rank, "must be in [1, 256]")
        check(0.1 <= self.mem_gb <= 4096, "executor.mem_gb", self.mem_gb, "must be in [0.1, 4096] (GB per job)")
        check(1 <= self.time_min <= 60 * 24 * 14, "executor.time_min", self.time_min,
              "must be in [1, 20160] minutes (the SLURM time limit of each job)")
        for where, name in (("executor.partition", self.partition), ("executor.account", self.account)):
            if name:
                check_name(where, name)
        check(5 <= self.signal_s <= 3600, "executor.signal_s", self.signal_s,
              "must be in [5, 3600] seconds (how long before the time limit SLURM signals the job)")
        check(self.signal_s < 60 * self.time_min, "executor.signal_s", self.signal_s,
              "must be shorter than the time limit (executor.time_min)")
        check(0.2 <= self.poll_s <= 600, "executor.poll_s", self.poll_s, "must be in [0.2, 600] seconds")


def executor_from_raw(raw: dict, override: str | None = None) -> ExecutorSpec:
    """The validated ``[executor]`` of a raw workflow table (removed from it), ``override`` its type
    (``--executor``)."""
    table = raw.pop("executor", {})
    if not isinstance(table, dict):
        raise SpecError("executor", table, "must be a table ([executor] with type = 'local', 'dask' or 'slurm')")
    ex = convert(ExecutorSpec, table, "executor.")
    if override is not None:
        ex.type = override
    ex.validate()
    return ex
